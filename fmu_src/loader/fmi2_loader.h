/*
 * Shared by the FMU's loader (fmi2_loader.c) and its FMI 2.0 state table (fmi2_states.c): the FMI
 * 2.0 types ("default" platform), the FMI 2.0 masks and the loader's instance (the states and what
 * FMI 3.0 shares: loader_common.h).
 */
#ifndef RRR_DK_FMI2_LOADER_H
#define RRR_DK_FMI2_LOADER_H

#include <stddef.h>

#include "fast_lane.h"
#include "loader_common.h"

/* FMI 2.0 types (fmi2TypesPlatform.h, fmi2FunctionTypes.h), "default" platform */
typedef void* fmi2Component;
typedef void* fmi2ComponentEnvironment;
typedef void* fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char* fmi2String;
typedef char fmi2Byte;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef enum { fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated } fmi2StatusKind;
typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
typedef struct {
    fmi2CallbackLogger logger;
    void* (*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void*);
    void (*stepFinished)(fmi2ComponentEnvironment, fmi2Status);
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

/* FMI 2.0.5 Co-Simulation states (section 4.2.4): the bits of loader_common.h (S_ANY and S_SET are
 * shared with FMI 3.0).  Get differs between the versions: FMI 2.0 allows it in stepFailed and error,
 * not in instantiated (FMI 3.0 reads start values there). */
#define S_GET (S_INITIALIZATION_MODE | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)

typedef struct {
    fmi2Component real;          /* the wrapper's component */
    CallState cs;                /* the state, what the slave reported in the current call, the reason of error */
    unsigned log_mask;           /* the log categories the host enabled (bits, fmi2_states.c) */
    fmi2CallbackFunctions host;  /* the host's callbacks */
    fmi2CallbackFunctions mine;  /* given to the wrapper: logger fmi2_relay, environment this Instance */
    char name[256];              /* the instance name */
    const char* model;           /* the modelIdentifier (this library's file name) */
    Lane* lane;                  /* the slave's fast lane (fast_lane.h); NULL: every call goes to Python */
} Instance;

/* 1 if ``call`` is allowed in the instance's state (``allowed``: S_* bits); else log why, return 0 */
int fmi2_admit(Instance* in, const char* call, unsigned allowed);
/* before a forwarded call: forget what the slave reported for the last one */
void fmi2_begin(Instance* in);
/* after a forwarded call that returned ``status``: the instance's new state, and the status for the host */
fmi2Status fmi2_settle(Instance* in, Transition t, fmi2Status status);
/* the logger given to the wrapper: consumes the slave's hand-off, relays the rest as the host asked */
void fmi2_relay(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                fmi2String message, ...);
/* stop using the instance's fast lane (logged with ``why``): every call goes to Python from now on */
void lane_drop(Instance* in, const char* why);
/* a message of the loader itself to the host's logger (always: they explain a refused call) */
void fmi2_say(Instance* in, fmi2Status status, const char* fmt, ...);
/* fmi2SetDebugLogging, answered by the loader (the wrapper keeps logging everything to fmi2_relay) */
fmi2Status fmi2_debug_logging(Instance* in, fmi2Boolean on, size_t n, const fmi2String categories[]);
/* the initial log mask of fmi2Instantiate's loggingOn */
unsigned fmi2_log_mask(fmi2Boolean on);

#endif
