/*
 * The FMU's binary: a loader that brings the Python runtime into a host process without Python,
 * keeps FMI 2.0's state table per instance, and forwards the FMI 2.0 Co-Simulation functions it
 * allows to pythonfmu's wrapper.
 *
 * Why.  pythonfmu's wrapper (shipped beside this file as libpythonfmu-export.so) calls the Python
 * C API but is not linked against libpython: it works only in a process that already has Python
 * (fmpy, libcosimpy, ecospy).  A C host (OMSimulator's command line, OpenModelica, Dymola, ...)
 * fails with "undefined symbol: _Py_NoneStruct".  And pythonfmu 0.7 cannot return fmi2Error: a
 * normal Python return is fmi2OK, do_step returning False is fmi2Discard, an exception fmi2Fatal.
 *
 * Loading, once per process, in the first fmi2Instantiate (serialized by a mutex; loader_common.c,
 * shared with the FMI 3.0 loader fmi3_loader.c):
 *  1. start_python (python_runtime.c): the process's Python if it has one, else the first
 *     interpreter that fits the FMU ($RRR_DK_PYTHON, the recorded one, python3 on PATH), started
 *     from its shared libpython and never finalized;
 *  2. pythonfmu's wrapper is opened RTLD_LOCAL | RTLD_NODELETE (its symbols do not clash with
 *     ours; never unmapped under a live interpreter) and its fmi2* functions resolved; this library
 *     pins itself (RTLD_NODELETE), so a host that unloads it (fmpy's freeInstance) and loads it
 *     again finds the same loaded state.
 * Errors never crash the host: fmi2Instantiate returns NULL after logging, through the host's
 * logger (and stderr), what is missing and how to fix it.
 *
 * The state table.  Each instance is a loader Instance around the wrapper's component.  A call FMI
 * 2.0 forbids in the instance's state (fmi2_states: the same table as fmu_src/fmi_states.py's
 * ALLOWED; the states and the masks FMI 3.0 shares: loader_common.h) returns fmi2Error and logs why, without reaching Python.  The slave (TableSlave) hands
 * its state and the status of the current call to the loader through the logger the loader gives
 * the wrapper: a message of category STATUS_CATEGORY, "<state> <status>[ <reason>]", which the
 * loader consumes (never shown to the host).  So an fmi2ExitInitializationMode that the slave
 * refuses (invalid parameter or start value) returns fmi2Error and leaves the instance in state
 * error, and an fmi2Set* of a variable not settable in the state returns fmi2Error.  A slave that
 * reports nothing (another pythonfmu slave) gets the standard transitions of the returned status.
 *
 * The exit crash ("corrupted double-linked list" at process exit; the fix is in loader_common.c).  The wrapper keeps a static
 * std::shared_ptr<PyState> and resets it in a __attribute__((destructor)) function.  When the
 * wrapper is still loaded at exit, exit() runs the static's destructor first (__cxa_atexit, before
 * _dl_fini) and the destructor function then resets the destroyed shared_ptr: it decrements the
 * use count inside the freed control block and glibc aborts later on the corrupted free list.  So
 * after opening the wrapper the loader registers an atexit handler (run before the wrapper's static
 * destructor, LIFO) that calls the wrapper's finalizePythonInterpreter: the shared_ptr is then
 * empty before either destructor runs.  It never finalizes Python (the wrapper did not start it).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_loader.h"
#include "python_runtime.h"

#define WRAPPER_NAME "libpythonfmu-export.so"

/* ---- the wrapper's functions: name, the states that allow it, the transition, parameters, arguments ---- */

/* the hot calls of a step: the fast lane answers them when it can (fast_lane.h) */
#define FMI2_HOT(X) \
    X(fmi2GetReal, S_GET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]), \
      (c, vr, n, v)) \
    X(fmi2GetInteger, S_GET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]), \
      (c, vr, n, v)) \
    X(fmi2GetBoolean, S_GET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]), \
      (c, vr, n, v)) \
    X(fmi2SetReal, S_SET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]), \
      (c, vr, n, v)) \
    X(fmi2DoStep, S_STEP_COMPLETE, T_STEP, (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noPrior), \
      (c, t, h, noPrior))

#define FMI2_FUNCTIONS(X) FMI2_HOT(X) FMI2_OTHER(X)

#define FMI2_OTHER(X) \
    X(fmi2SetupExperiment, S_INSTANTIATED, T_NONE, (fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, \
      fmi2Real t0, fmi2Boolean stopDef, fmi2Real t1), (c, tolDef, tol, t0, stopDef, t1)) \
    X(fmi2EnterInitializationMode, S_INSTANTIATED, T_ENTER, (fmi2Component c), (c)) \
    X(fmi2ExitInitializationMode, S_INITIALIZATION_MODE, T_EXIT, (fmi2Component c), (c)) \
    X(fmi2Terminate, S_STEP_COMPLETE | S_STEP_FAILED, T_TERMINATE, (fmi2Component c), (c)) \
    X(fmi2Reset, S_ANY, T_RESET, (fmi2Component c), (c)) \
    X(fmi2GetString, S_GET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]), \
      (c, vr, n, v)) \
    X(fmi2SetInteger, S_SET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Integer v[]), (c, vr, n, v)) \
    X(fmi2SetBoolean, S_SET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Boolean v[]), (c, vr, n, v)) \
    X(fmi2SetString, S_SET, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2String v[]), (c, vr, n, v)) \
    X(fmi2GetFMUstate, S_ANY, T_NONE, (fmi2Component c, fmi2FMUstate* s), (c, s)) \
    X(fmi2SetFMUstate, S_ANY, T_NONE, (fmi2Component c, fmi2FMUstate s), (c, s)) \
    X(fmi2FreeFMUstate, S_ANY, T_NONE, (fmi2Component c, fmi2FMUstate* s), (c, s)) \
    X(fmi2SerializedFMUstateSize, S_ANY, T_NONE, (fmi2Component c, fmi2FMUstate s, size_t* n), (c, s, n)) \
    X(fmi2SerializeFMUstate, S_ANY, T_NONE, (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n), (c, s, b, n)) \
    X(fmi2DeSerializeFMUstate, S_ANY, T_NONE, (fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s), \
      (c, b, n, s)) \
    X(fmi2GetDirectionalDerivative, S_ANY, T_NONE, (fmi2Component c, const fmi2ValueReference u[], size_t nu, \
      const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]), (c, u, nu, z, nz, du, dz)) \
    X(fmi2SetRealInputDerivatives, S_ANY, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Integer order[], const fmi2Real v[]), (c, vr, n, order, v)) \
    X(fmi2GetRealOutputDerivatives, S_ANY, T_NONE, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Integer order[], fmi2Real v[]), (c, vr, n, order, v)) \
    X(fmi2CancelStep, 0u /* stepInProgress: never (no fmi2Pending) */, T_NONE, (fmi2Component c), (c)) \
    X(fmi2GetStatus, S_ANY, T_NONE, (fmi2Component c, const fmi2StatusKind k, fmi2Status* v), (c, k, v)) \
    X(fmi2GetRealStatus, S_ANY, T_NONE, (fmi2Component c, const fmi2StatusKind k, fmi2Real* v), (c, k, v)) \
    X(fmi2GetIntegerStatus, S_ANY, T_NONE, (fmi2Component c, const fmi2StatusKind k, fmi2Integer* v), (c, k, v)) \
    X(fmi2GetBooleanStatus, S_ANY, T_NONE, (fmi2Component c, const fmi2StatusKind k, fmi2Boolean* v), (c, k, v)) \
    X(fmi2GetStringStatus, S_ANY, T_NONE, (fmi2Component c, const fmi2StatusKind k, fmi2String* v), (c, k, v))

#define DECLARE_POINTER(name, allowed, transition, params, args) static fmi2Status (*real_##name) params;
FMI2_FUNCTIONS(DECLARE_POINTER)
static fmi2Component (*real_fmi2Instantiate)(fmi2String, fmi2Type, fmi2String, fmi2String,
                                             const fmi2CallbackFunctions*, fmi2Boolean, fmi2Boolean);
static void (*real_fmi2FreeInstance)(fmi2Component);
static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;
static int loaded;                 /* the wrapper's functions are resolved */
static char load_error[8192];      /* why loading failed (kept: every later instantiate reports it) */
static char load_note[8192];       /* which interpreter was chosen, when not the recorded one (logged once) */
static char model[256];            /* the modelIdentifier: this library's file name without ".so" */

/* ---- loading (loader_common.c: the runtime, the wrapper, the exit fix) -------------------------- */

#define RESOLVE(name, allowed, transition, params, args) \
    if (!(real_##name = (fmi2Status(*) params)dlsym(wrapper, #name))) \
        return snprintf(load_error, sizeof load_error, "%s lacks %s", WRAPPER_NAME, #name), -1;

static int load(void)
{
    void* wrapper = loader_open(WRAPPER_NAME, model, sizeof model, load_error, sizeof load_error, load_note,
                                sizeof load_note);
    if (!wrapper) return -1;
    FMI2_FUNCTIONS(RESOLVE)
    real_fmi2Instantiate = dlsym(wrapper, "fmi2Instantiate");
    real_fmi2FreeInstance = dlsym(wrapper, "fmi2FreeInstance");
    if (!real_fmi2Instantiate || !real_fmi2FreeInstance)
        return snprintf(load_error, sizeof load_error, "%s lacks fmi2Instantiate or fmi2FreeInstance", WRAPPER_NAME), -1;
    return 0;
}

/* ---- the FMI functions -------------------------------------------------------------------------- */

EXPORT const char* fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char* fmi2GetVersion(void) { return "2.0"; }

EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                     fmi2String fmuResourceLocation, const fmi2CallbackFunctions* functions,
                                     fmi2Boolean visible, fmi2Boolean loggingOn)
{
    const char* name = instanceName ? instanceName : "";
    pthread_mutex_lock(&load_lock);
    int first = !loaded && !load_error[0];
    if (first) loaded = load() == 0;
    pthread_mutex_unlock(&load_lock);
    if (!loaded) {
        fprintf(stderr, "FMU instance %s: %s\n", name, load_error);
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError", "%s", load_error);
        return NULL;
    }
    Instance* in = calloc(1, sizeof *in);
    if (!in) return NULL;
    if (functions) in->host = *functions;
    in->mine = in->host;
    in->mine.logger = fmi2_relay;
    in->mine.componentEnvironment = in;
    in->mine.stepFinished = NULL;                 /* no asynchronous steps */
    in->cs.state = S_INSTANTIATED;
    in->log_mask = fmi2_log_mask(loggingOn);
    in->model = model;
    snprintf(in->name, sizeof in->name, "%s", name);
    if (first && load_note[0])
        fmi2_say(in, fmi2Warning, "%s: %s", model, load_note);
    fmi2_begin(in);
    /* loggingOn for the wrapper always: the slave's hand-off passes through fmi2_relay */
    in->real = real_fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation, &in->mine, visible, 1);
    if (!in->real) {
        free(in);
        return NULL;
    }
    fmi2_settle(in, T_NONE, fmi2OK);
    return in;
}

EXPORT void fmi2FreeInstance(fmi2Component c)
{
    Instance* in = c;
    if (!loaded || !in) return;
    in->lane = NULL;                              /* the slave and its arrays go with the instance */
    /* pythonfmu 0.7's wrapper may crash (SIGSEGV in clearLogBuffer) freeing an instance whose slave
     * left a message queued since its last call (one logged in its constructor): an empty get
     * reaches Python (TableSlave answers it in every state), and the wrapper hands the queue on. */
    fmi2ValueReference none = 0;
    fmi2String ignored = NULL;
    real_fmi2GetString(in->real, &none, 0, &ignored);
    real_fmi2FreeInstance(in->real);
    free(in);
}

EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[])
{
    return loaded && c ? fmi2_debug_logging((Instance*)c, on, n, categories) : fmi2Error;
}

/* every function: a component (only a loaded wrapper hands one out), the state table, the fast lane's
 * pull before and push after (fast_lane.h), the wrapper with its own component (the inner ``c``
 * shadows the parameter), the new state */
#define FORWARD(name, allowed, transition, params, args) \
    static fmi2Status forward_##name params \
    { \
        Instance* in = c; \
        if (!loaded || !in) return fmi2Error; \
        if (!fmi2_admit(in, #name, (allowed))) return fmi2Error; \
        if (in->lane && lane_before_python(in->lane)) lane_drop(in, "its pull raised"); \
        if ((transition) == T_RESET) in->lane = NULL;     /* the slave starts afresh: a new lane, if any */ \
        fmi2_begin(in); \
        fmi2Status status; \
        { \
            fmi2Component c = in->real; \
            status = real_##name args; \
        } \
        status = fmi2_settle(in, (transition), status); \
        if (in->lane && lane_after_python(in->lane)) lane_drop(in, "its push raised"); \
        return status; \
    }
FMI2_FUNCTIONS(FORWARD)

#define EXPORT_FORWARD(name, allowed, transition, params, args) \
    EXPORT fmi2Status name params { return forward_##name args; }
FMI2_OTHER(EXPORT_FORWARD)

/* the hot calls: the fast lane when it is open and serves every value reference, else Python */
#define LANE_OPEN(in) (loaded && (in) && lane_open((in)->lane, (in)->cs.state == S_STEP_COMPLETE))

EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[])
{
    Instance* in = c;
    return LANE_OPEN(in) && lane_set_real(in->lane, vr, n, v) ? fmi2OK : forward_fmi2SetReal(c, vr, n, v);
}

EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{
    Instance* in = c;
    return LANE_OPEN(in) && lane_get_real(in->lane, vr, n, v) ? fmi2OK : forward_fmi2GetReal(c, vr, n, v);
}

EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
{
    Instance* in = c;
    return LANE_OPEN(in) && lane_get_integer(in->lane, vr, n, v) ? fmi2OK : forward_fmi2GetInteger(c, vr, n, v);
}

EXPORT fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{
    Instance* in = c;
    return LANE_OPEN(in) && lane_get_boolean(in->lane, vr, n, v) ? fmi2OK : forward_fmi2GetBoolean(c, vr, n, v);
}

EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noPrior)
{
    Instance* in = c;
    return LANE_OPEN(in) && lane_do_step(in->lane, t, h) ? fmi2OK : forward_fmi2DoStep(c, t, h, noPrior);
}
