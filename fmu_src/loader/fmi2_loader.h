/*
 * Shared by the FMU's loader (fmi2_loader.c) and its FMI 2.0 state table (fmi2_states.c): the FMI
 * 2.0 types ("default" platform), the states and the loader's instance.
 */
#ifndef RRR_DK_FMI2_LOADER_H
#define RRR_DK_FMI2_LOADER_H

#include <stddef.h>

#define EXPORT __attribute__((visibility("default")))

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

/* FMI 2.0.5 Co-Simulation states (section 4.2.4), one bit each; "fatal" after an fmi2Fatal.
 * The slaves never return fmi2Pending: stepInProgress and stepCanceled never occur. */
enum {
    S_INSTANTIATED = 1, S_INITIALIZATION_MODE = 2, S_STEP_COMPLETE = 4, S_STEP_FAILED = 8,
    S_TERMINATED = 16, S_ERROR = 32, S_FATAL = 64
};
#define S_ANY (S_INSTANTIATED | S_INITIALIZATION_MODE | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)
#define S_GET (S_INITIALIZATION_MODE | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)
#define S_SET (S_INSTANTIATED | S_INITIALIZATION_MODE | S_STEP_COMPLETE)

/* the state a call leads to when the slave reports none (fmi2_settle) */
typedef enum { T_NONE, T_ENTER, T_EXIT, T_STEP, T_TERMINATE, T_RESET } Transition;

/* the logger category of the slave's hand-off: "<state> <status>[ <reason>]" (fmu_src/fmi_states.py) */
#define STATUS_CATEGORY "rrrdkCallStatus"

typedef struct {
    fmi2Component real;          /* the wrapper's component */
    unsigned state;              /* one of the S_* bits */
    unsigned reported;           /* the state the slave reported during the current call; 0: none */
    fmi2Status call_status;      /* the worst status the slave reported for the current call */
    char reason[2048];           /* why the instance is in state error (the slave's reason) */
    unsigned log_mask;           /* the log categories the host enabled (bits, fmi2_states.c) */
    fmi2CallbackFunctions host;  /* the host's callbacks */
    fmi2CallbackFunctions mine;  /* given to the wrapper: logger fmi2_relay, environment this Instance */
    char name[256];              /* the instance name */
    const char* model;           /* the modelIdentifier (this library's file name) */
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
/* a message of the loader itself to the host's logger (always: they explain a refused call) */
void fmi2_say(Instance* in, fmi2Status status, const char* fmt, ...);
/* fmi2SetDebugLogging, answered by the loader (the wrapper keeps logging everything to fmi2_relay) */
fmi2Status fmi2_debug_logging(Instance* in, fmi2Boolean on, size_t n, const fmi2String categories[]);
/* the initial log mask of fmi2Instantiate's loggingOn */
unsigned fmi2_log_mask(fmi2Boolean on);

#endif
