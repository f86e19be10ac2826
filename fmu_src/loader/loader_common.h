/*
 * What the FMI 2.0 loader (fmi2_loader.c, fmi2_states.c) and the FMI 3.0 loader (fmi3_loader.c,
 * fmi3_states.c) share (loader_common.c): opening the Python wrapper behind the Python runtime, the
 * states of the Co-Simulation state machines with the masks where both versions agree, the slave's
 * hand-off, the transitions of a call, and the log categories.
 */
#ifndef RRR_DK_LOADER_COMMON_H
#define RRR_DK_LOADER_COMMON_H

#include <stddef.h>

#define EXPORT __attribute__((visibility("default")))

/* The states, one bit each, one numbering for both versions.  FMI 3.0 Co-Simulation without Event Mode
 * and without structural parameters (this FMU) has Instantiated, InitializationMode, StepMode and
 * Terminated: FMI 3.0's StepMode is FMI 2.0's stepComplete (the same bit).  stepFailed exists in FMI
 * 2.0 only (FMI 3.0: a doStep that returns fmi3Discard leaves the FMU "in the same state as before the
 * call", StepMode).  S_ERROR: FMI 2.0's error; in FMI 3.0 "a function that returns fmi3Error puts the
 * FMU in Terminated": the loaders enter it when the slave refuses fmi?ExitInitializationMode or a
 * doStep fails with an error, and keep the reason (FMI 3.0 allows there what Terminated allows).
 * S_FATAL after a fatal status: only freeInstance.  The slaves never return fmi2Pending (no
 * stepInProgress/stepCanceled) and the FMI 3.0 FMU has no Event, Configuration or Intermediate Update
 * Mode. */
enum {
    S_INSTANTIATED = 1, S_INITIALIZATION_MODE = 2, S_STEP_COMPLETE = 4, S_STEP_FAILED = 8,
    S_TERMINATED = 16, S_ERROR = 32, S_FATAL = 64
};
#define N_STATES 7
#define S_STEP_MODE S_STEP_COMPLETE
/* both versions: every state but fatal (reset, get/set of the FMU state) */
#define S_ANY (S_INSTANTIATED | S_INITIALIZATION_MODE | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)
/* both versions: set a variable (which variables: the slave's table, per state) */
#define S_SET (S_INSTANTIATED | S_INITIALIZATION_MODE | S_STEP_COMPLETE)

/* the state a call leads to when it succeeds and the slave reports none (call_settle) */
typedef enum { T_NONE, T_ENTER, T_EXIT, T_STEP, T_TERMINATE, T_RESET } Transition;

/* the logger category of the slave's hand-off: "<state> <status>[ <reason>]" (fmu_src/fmi_states.py) */
#define STATUS_CATEGORY "rrrdkCallStatus"

/* the state machine of one instance, and what the slave reported during the current call */
typedef struct {
    unsigned state;              /* one of the S_* bits */
    unsigned reported;           /* the state the slave reported during the current call; 0: none */
    int call_status;             /* the worst status the slave reported for the current call */
    char reason[2048];           /* why the instance is in state S_ERROR (the slave's reason) */
} CallState;

/* How one FMI version names things in its messages */
typedef struct {
    const char* fmi;                     /* "FMI 2.0" */
    const char* error;                   /* "fmi2Error" */
    const char* names[N_STATES];         /* the name of each state bit */
    unsigned discard_state;              /* the state after a doStep that returned Discard; 0: unchanged */
} Dialect;

/* Bring in the Python runtime (python_runtime.c: start_python) and open the wrapper ``wrapper_name``
 * beside this library RTLD_LOCAL | RTLD_NODELETE; pin this library; register the exit fix (the
 * wrapper's finalizePythonInterpreter at exit, see fmi2_loader.c "The exit crash").  Returns the
 * wrapper's handle, NULL with the reason in ``error``.  ``model``: this library's file name without
 * ".so"; ``note``: which interpreter was chosen when not the recorded one. */
void* loader_open(const char* wrapper_name, char* model, size_t model_size, char* error, size_t error_size,
                  char* note, size_t note_size);

/* the states of ``allowed`` by name, ", "-separated ("" when none) */
void states_text(const Dialect* d, unsigned allowed, char* out, size_t size);
/* the name of a state bit */
const char* state_text(const Dialect* d, unsigned state);
/* before a forwarded call: forget what the slave reported for the last one */
void call_begin(CallState* cs);
/* after a forwarded call that returned ``status``: the new state; the status for the host */
int call_settle(CallState* cs, const Dialect* d, Transition t, int status);
/* the slave's hand-off "<state> <status>[ <reason>]" (FMI 2.0 state names, the core's); ``map``
 * turns the reported bit into this version's state (NULL: unchanged).  0, or -1 for an unknown state */
int take_hand_off(CallState* cs, const char* text, unsigned (*map)(unsigned));

/* the log categories of pythonfmu's and pythonfmu3's modelDescription (bits of a log mask) */
#define N_CATEGORIES 5
#define ALL_CATEGORIES ((1u << N_CATEGORIES) - 1u)
/* the log mask of an instantiation's loggingOn */
unsigned log_mask_of(int on);
/* the bit of a category, -1 if it is not one of the FMU's */
int category_bit(const char* name);
/* the category a loader message of ``status`` goes out in (logStatusError, ...) */
const char* category_of(int status);
/* setDebugLogging: the new mask in ``mask``; 0, or -1 with ``*unknown`` the category the FMU lacks */
int debug_logging(unsigned* mask, int on, size_t n, const char* const categories[], const char** unknown);

#endif
