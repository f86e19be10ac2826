/*
 * Shared by the FMI 3.0 loader (fmi3_loader.c) and its state table (fmi3_states.c): the FMI 3.0
 * types (fmi3PlatformTypes.h, fmi3FunctionTypes.h), the FMI 3.0 masks and the loader's instance (the
 * states and what FMI 2.0 shares: loader_common.h).
 */
#ifndef RRR_DK_FMI3_LOADER_H
#define RRR_DK_FMI3_LOADER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fast_lane.h"
#include "loader_common.h"

/* FMI 3.0 types */
typedef void* fmi3Instance;
typedef void* fmi3InstanceEnvironment;
typedef void* fmi3FMUState;
typedef uint32_t fmi3ValueReference;
typedef float fmi3Float32;
typedef double fmi3Float64;
typedef int8_t fmi3Int8;
typedef uint8_t fmi3UInt8;
typedef int16_t fmi3Int16;
typedef uint16_t fmi3UInt16;
typedef int32_t fmi3Int32;
typedef uint32_t fmi3UInt32;
typedef int64_t fmi3Int64;
typedef uint64_t fmi3UInt64;
typedef bool fmi3Boolean;
typedef char fmi3Char;
typedef const fmi3Char* fmi3String;
typedef uint8_t fmi3Byte;
typedef const fmi3Byte* fmi3Binary;
typedef bool fmi3Clock;
typedef enum { fmi3OK, fmi3Warning, fmi3Discard, fmi3Error, fmi3Fatal } fmi3Status;
typedef enum { fmi3Independent, fmi3Constant, fmi3Fixed, fmi3Tunable, fmi3Discrete, fmi3Dependent } fmi3DependencyKind;
typedef enum { fmi3IntervalNotYetKnown, fmi3IntervalUnchanged, fmi3IntervalChanged } fmi3IntervalQualifier;
typedef void (*fmi3LogMessageCallback)(fmi3InstanceEnvironment, fmi3Status, fmi3String, fmi3String);
typedef void (*fmi3IntermediateUpdateCallback)(fmi3InstanceEnvironment, fmi3Float64, fmi3Boolean, fmi3Boolean,
                                               fmi3Boolean, fmi3Boolean, fmi3Boolean*, fmi3Float64*);
typedef void (*fmi3ClockUpdateCallback)(fmi3InstanceEnvironment);
typedef void (*fmi3LockPreemptionCallback)(void);
typedef void (*fmi3UnlockPreemptionCallback)(void);

/* FMI 3.0 Co-Simulation masks that differ from FMI 2.0's (the shared ones: loader_common.h).  Get:
 * FMI 3.0 reads start values in Instantiated, and has no stepFailed; error is FMI 3.0's Terminated
 * entered by an fmi3Error, where get is allowed.  Terminate: StepMode only (FMI 2.0: stepComplete and
 * stepFailed). */
#define S3_GET (S_INSTANTIATED | S_INITIALIZATION_MODE | S_STEP_MODE | S_TERMINATED | S_ERROR)
#define S3_TERMINATE S_STEP_MODE

typedef struct {
    fmi3Instance real;                 /* the wrapper's instance */
    CallState cs;                      /* the state, what the slave reported in the current call, the reason */
    unsigned log_mask;                 /* the log categories the host enabled (loader_common.h) */
    fmi3InstanceEnvironment env;       /* the host's environment and logger */
    fmi3LogMessageCallback logger;
    char name[256];                    /* the instance name */
    const char* model;                 /* the modelIdentifier (this library's file name) */
    Lane* lane;                        /* the slave's fast lane (fast_lane.h); NULL: every call goes to Python */
} Instance3;

/* 1 if ``call`` is allowed in the instance's state (``allowed``: S_* bits); else log why, return 0.
 * ``note``: why no state of this FMU allows it (``allowed`` 0), else NULL */
int fmi3_admit(Instance3* in, const char* call, unsigned allowed, const char* note);
/* after a forwarded call that returned ``status``: the instance's new state, and the status for the host */
fmi3Status fmi3_settle(Instance3* in, Transition t, fmi3Status status);
/* the logger given to the wrapper: consumes the slave's hand-off, relays the rest as the host asked */
void fmi3_relay(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message);
/* a message of the loader itself to the host's logger (always: it explains a refused call) */
void fmi3_say(Instance3* in, fmi3Status status, const char* fmt, ...) __attribute__((format(printf, 3, 4)));
/* stop using the instance's fast lane (logged with ``why``): every call goes to Python from now on */
void lane3_drop(Instance3* in, const char* why);
/* fmi3SetDebugLogging, answered by the loader (the wrapper keeps logging everything to fmi3_relay) */
fmi3Status fmi3_debug_logging(Instance3* in, fmi3Boolean on, size_t n, const fmi3String categories[]);

#endif
