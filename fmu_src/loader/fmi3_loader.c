/*
 * The FMI 3.0 FMU's binary: a loader that brings the Python runtime into a host process without
 * Python, keeps FMI 3.0's Co-Simulation state table per instance, and forwards the FMI 3.0 functions
 * it allows to pythonfmu3's wrapper.  The FMI 2.0 loader (fmi2_loader.c) does the same for
 * pythonfmu's; both are built on loader_common.c and python_runtime.c.
 *
 * Why.  pythonfmu3's wrapper (shipped beside this file as libpythonfmu3-export.so) calls the Python C
 * API without being linked against libpython: a C host (fmusim of the Reference-FMUs, ...) fails
 * with "undefined symbol: _Py_NoneStruct".  And it returns fmi3OK after every call that does not
 * raise: a set or a get the slave refuses was logged with fmi3Error but answered fmi3OK.
 *
 * Loading, once per process, in the first fmi3InstantiateCoSimulation (serialized by a mutex):
 * loader_open (loader_common.c): start_python exactly as the FMI 2.0 loader ($RRR_DK_PYTHON, the
 * interpreter of resources/python_runtime.txt, python3 on PATH; each named with its failure and the
 * fix when none fits), the wrapper opened RTLD_LOCAL | RTLD_NODELETE, this library pinned, and the
 * exit fix: pythonfmu3's wrapper has pythonfmu's static std::shared_ptr<PyState> reset by a
 * destructor function (a C host aborted at exit on 3 of 3 runs without the fix: "free(): corrupted
 * unsorted chunks"), so the same atexit handler empties it first.  Errors never crash the host:
 * the instantiation returns NULL after logging, through the host's logger (and stderr), what is
 * missing and how to fix it.
 *
 * The state table (fmi3_states.c).  A call FMI 3.0 forbids in the instance's state returns fmi3Error
 * and logs why (the call, the state, the states that allow it), without reaching Python; so does
 * every function of a feature this FMU lacks (Model Exchange, Scheduled Execution, Event Mode,
 * Configuration Mode, clocks, derivatives, dependencies), and a get or set of a type of which it has
 * no variable (its variables are Float64, Int32 and Boolean: fmu_src/fmi3_adapter.py).  The slave
 * hands its state and the status of the current call over (fmi3_states.c): a refused
 * fmi3ExitInitializationMode returns fmi3Error and leaves the instance in Terminated after an
 * fmi3Error with the reason; a set of a variable not settable in the state, or a get or set of an
 * unknown value reference, returns fmi3Error and changes nothing; a doStep the slave refuses returns
 * fmi3Discard with the state kept at the step's start, and the instance stays in StepMode.
 * An instance that returned fmi3Error for a refused call keeps its state (the FMI 2.0 loader does the
 * same).  FMI 3.0 says a function that returns fmi3Error puts the FMU in Terminated; keeping the
 * state is more lenient, and an importer that follows FMI 3.0 never notices: everything Terminated
 * allows (get, the FMU state, reset, free) is allowed in every state of this FMU.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_loader.h"

#define WRAPPER_NAME "libpythonfmu3-export.so"

/* ---- the wrapper's functions: name, the states that allow it, the transition, parameters, arguments ---- */

#define VALUES(T) (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, T v[], size_t n)
#define VALUE_ARGS (c, vr, nvr, v, n)
#define FMI3_FUNCTIONS(X) FMI3_PLAIN(X) FMI3_HOT(X) FMI3_STEP(X)
/* the hot calls of a step: the fast lane answers them when it can (fast_lane.h), else they are forwarded */
#define FMI3_HOT(X) \
    X(fmi3GetFloat64, S3_GET, T_NONE, VALUES(fmi3Float64), VALUE_ARGS) \
    X(fmi3GetInt32, S3_GET, T_NONE, VALUES(fmi3Int32), VALUE_ARGS) \
    X(fmi3GetBoolean, S3_GET, T_NONE, VALUES(fmi3Boolean), VALUE_ARGS) \
    X(fmi3SetFloat64, S_SET, T_NONE, VALUES(const fmi3Float64), VALUE_ARGS)
#define FMI3_PLAIN(X) \
    X(fmi3EnterInitializationMode, S_INSTANTIATED, T_ENTER, (fmi3Instance c, fmi3Boolean tolDef, fmi3Float64 tol, \
      fmi3Float64 t0, fmi3Boolean stopDef, fmi3Float64 t1), (c, tolDef, tol, t0, stopDef, t1)) \
    X(fmi3ExitInitializationMode, S_INITIALIZATION_MODE, T_EXIT, (fmi3Instance c), (c)) \
    X(fmi3Terminate, S3_TERMINATE, T_TERMINATE, (fmi3Instance c), (c)) \
    X(fmi3Reset, S_ANY, T_RESET, (fmi3Instance c), (c)) \
    X(fmi3SetInt32, S_SET, T_NONE, VALUES(const fmi3Int32), VALUE_ARGS) \
    X(fmi3SetBoolean, S_SET, T_NONE, VALUES(const fmi3Boolean), VALUE_ARGS) \
    X(fmi3GetFMUState, S_ANY, T_NONE, (fmi3Instance c, fmi3FMUState* s), (c, s)) \
    X(fmi3SetFMUState, S_ANY, T_NONE, (fmi3Instance c, fmi3FMUState s), (c, s)) \
    X(fmi3FreeFMUState, S_ANY, T_NONE, (fmi3Instance c, fmi3FMUState* s), (c, s)) \
    X(fmi3SerializedFMUStateSize, S_ANY, T_NONE, (fmi3Instance c, fmi3FMUState s, size_t* n), (c, s, n)) \
    X(fmi3SerializeFMUState, S_ANY, T_NONE, (fmi3Instance c, fmi3FMUState s, fmi3Byte b[], size_t n), (c, s, b, n)) \
    X(fmi3DeserializeFMUState, S_ANY, T_NONE, (fmi3Instance c, const fmi3Byte b[], size_t n, fmi3FMUState* s), \
      (c, b, n, s))
#define FMI3_STEP(X) \
    X(fmi3DoStep, S_STEP_MODE, T_STEP, (fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noPrior, \
      fmi3Boolean* event, fmi3Boolean* stop, fmi3Boolean* early, fmi3Float64* last), \
      (c, t, h, noPrior, event, stop, early, last))

/* the types of which the FMU has no variable: the state table, then fmi3Error unless the call names none */
#define FMI3_NO_VARIABLES(X) \
    X(Float32, fmi3Float32) X(Int8, fmi3Int8) X(UInt8, fmi3UInt8) X(Int16, fmi3Int16) X(UInt16, fmi3UInt16) \
    X(UInt32, fmi3UInt32) X(Int64, fmi3Int64) X(UInt64, fmi3UInt64) X(String, fmi3String)

/* the functions of features this FMU lacks: fmi3Error in every state (the reason is the ``note``) */
#define NO_ME "Model Exchange only (this FMU is Co-Simulation)"
#define NO_EVENTS "this FMU has no Event Mode (hasEventMode false)"
#define NO_CLOCKS "this FMU has no clocks"
#define FMI3_ABSENT(X) \
    X(fmi3EnterEventMode, NO_EVENTS, (fmi3Instance c)) \
    X(fmi3EnterStepMode, NO_EVENTS, (fmi3Instance c)) \
    X(fmi3UpdateDiscreteStates, NO_EVENTS, (fmi3Instance c, fmi3Boolean* a, fmi3Boolean* b, fmi3Boolean* d, \
      fmi3Boolean* e, fmi3Boolean* f, fmi3Float64* g)) \
    X(fmi3EvaluateDiscreteStates, NO_EVENTS, (fmi3Instance c)) \
    X(fmi3EnterConfigurationMode, "this FMU has no structural parameters (no Configuration Mode)", (fmi3Instance c)) \
    X(fmi3ExitConfigurationMode, "this FMU has no structural parameters (no Configuration Mode)", (fmi3Instance c)) \
    X(fmi3GetBinary, "this FMU has no Binary variable", (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      size_t sizes[], fmi3Binary v[], size_t n)) \
    X(fmi3SetBinary, "this FMU has no Binary variable", (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      const size_t sizes[], const fmi3Binary v[], size_t n)) \
    X(fmi3GetClock, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock v[])) \
    X(fmi3SetClock, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock v[])) \
    X(fmi3GetIntervalDecimal, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      fmi3Float64 v[], fmi3IntervalQualifier q[])) \
    X(fmi3GetIntervalFraction, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      fmi3UInt64 a[], fmi3UInt64 b[], fmi3IntervalQualifier q[])) \
    X(fmi3GetShiftDecimal, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 v[])) \
    X(fmi3GetShiftFraction, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      fmi3UInt64 a[], fmi3UInt64 b[])) \
    X(fmi3SetIntervalDecimal, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      const fmi3Float64 v[])) \
    X(fmi3SetIntervalFraction, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      const fmi3UInt64 a[], const fmi3UInt64 b[])) \
    X(fmi3SetShiftDecimal, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      const fmi3Float64 v[])) \
    X(fmi3SetShiftFraction, NO_CLOCKS, (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, \
      const fmi3UInt64 a[], const fmi3UInt64 b[])) \
    X(fmi3ActivateModelPartition, "Scheduled Execution only (this FMU is Co-Simulation)", \
      (fmi3Instance c, fmi3ValueReference k, fmi3Float64 t)) \
    X(fmi3GetNumberOfVariableDependencies, "this FMU provides no per-element dependencies", \
      (fmi3Instance c, fmi3ValueReference vr, size_t* n)) \
    X(fmi3GetVariableDependencies, "this FMU provides no per-element dependencies", (fmi3Instance c, \
      fmi3ValueReference vr, size_t a[], fmi3ValueReference b[], size_t d[], fmi3DependencyKind k[], size_t n)) \
    X(fmi3GetDirectionalDerivative, "this FMU provides no directional derivatives", (fmi3Instance c, \
      const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[], size_t nk, const fmi3Float64 s[], \
      size_t ns, fmi3Float64 d[], size_t nd)) \
    X(fmi3GetAdjointDerivative, "this FMU provides no adjoint derivatives", (fmi3Instance c, \
      const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[], size_t nk, const fmi3Float64 s[], \
      size_t ns, fmi3Float64 d[], size_t nd)) \
    X(fmi3GetOutputDerivatives, "this FMU provides no output derivatives (maxOutputDerivativeOrder 0)", \
      (fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 o[], fmi3Float64 v[], size_t n)) \
    X(fmi3EnterContinuousTimeMode, NO_ME, (fmi3Instance c)) \
    X(fmi3CompletedIntegratorStep, NO_ME, (fmi3Instance c, fmi3Boolean p, fmi3Boolean* e, fmi3Boolean* t)) \
    X(fmi3SetTime, NO_ME, (fmi3Instance c, fmi3Float64 t)) \
    X(fmi3SetContinuousStates, NO_ME, (fmi3Instance c, const fmi3Float64 x[], size_t n)) \
    X(fmi3GetContinuousStateDerivatives, NO_ME, (fmi3Instance c, fmi3Float64 x[], size_t n)) \
    X(fmi3GetEventIndicators, NO_ME, (fmi3Instance c, fmi3Float64 x[], size_t n)) \
    X(fmi3GetContinuousStates, NO_ME, (fmi3Instance c, fmi3Float64 x[], size_t n)) \
    X(fmi3GetNominalsOfContinuousStates, NO_ME, (fmi3Instance c, fmi3Float64 x[], size_t n)) \
    X(fmi3GetNumberOfEventIndicators, NO_ME, (fmi3Instance c, size_t* n)) \
    X(fmi3GetNumberOfContinuousStates, NO_ME, (fmi3Instance c, size_t* n))

#define DECLARE_POINTER(name, allowed, transition, params, args) static fmi3Status (*real_##name) params;
FMI3_FUNCTIONS(DECLARE_POINTER)
static fmi3Instance (*real_instantiate)(fmi3String, fmi3String, fmi3String, fmi3Boolean, fmi3Boolean, fmi3Boolean,
                                        fmi3Boolean, const fmi3ValueReference[], size_t, fmi3InstanceEnvironment,
                                        fmi3LogMessageCallback, fmi3IntermediateUpdateCallback);
static void (*real_free)(fmi3Instance);

static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;
static int loaded;                 /* the wrapper's functions are resolved */
static char load_error[8192];      /* why loading failed (kept: every later instantiation reports it) */
static char load_note[8192];       /* which interpreter was chosen, when not the recorded one (logged once) */
static char model[256];            /* the modelIdentifier: this library's file name without ".so" */

/* ---- loading (loader_common.c: the runtime, the wrapper, the exit fix) -------------------------- */

#define RESOLVE(name, allowed, transition, params, args) \
    if (!(real_##name = (fmi3Status(*) params)dlsym(wrapper, #name))) \
        return snprintf(load_error, sizeof load_error, "%s lacks %s", WRAPPER_NAME, #name), -1;

static int load(void)
{
    void* wrapper = loader_open(WRAPPER_NAME, model, sizeof model, load_error, sizeof load_error, load_note,
                                sizeof load_note);
    if (!wrapper) return -1;
    FMI3_FUNCTIONS(RESOLVE)
    real_instantiate = dlsym(wrapper, "fmi3InstantiateCoSimulation");
    real_free = dlsym(wrapper, "fmi3FreeInstance");
    if (!real_instantiate || !real_free)
        return snprintf(load_error, sizeof load_error, "%s lacks fmi3InstantiateCoSimulation or fmi3FreeInstance",
                        WRAPPER_NAME), -1;
    return 0;
}

/* ---- instances ---------------------------------------------------------------------------------- */

EXPORT const char* fmi3GetVersion(void) { return "3.0"; }

/* the instantiation's refusal: logged (and on stderr), NULL */
static fmi3Instance refuse_instance(const char* name, fmi3InstanceEnvironment env, fmi3LogMessageCallback logger,
                                    const char* why)
{
    fprintf(stderr, "FMU instance %s: %s\n", name, why);
    if (logger) logger(env, fmi3Error, "logStatusError", why);
    return NULL;
}

EXPORT fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String token, fmi3String resources,
                                                fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                                fmi3Boolean earlyReturnAllowed, const fmi3ValueReference required[],
                                                size_t nRequired, fmi3InstanceEnvironment env,
                                                fmi3LogMessageCallback logger, fmi3IntermediateUpdateCallback update)
{
    const char* name = instanceName ? instanceName : "";
    pthread_mutex_lock(&load_lock);
    int first = !loaded && !load_error[0];
    if (first) loaded = load() == 0;
    pthread_mutex_unlock(&load_lock);
    if (!loaded) return refuse_instance(name, env, logger, load_error);
    if (eventModeUsed) {
        char why[512];
        snprintf(why, sizeof why, "%s instance '%s': fmi3InstantiateCoSimulation with eventModeUsed: this FMU has "
                 "no Event Mode (hasEventMode false); instantiate it with eventModeUsed = false", model, name);
        return refuse_instance(name, env, logger, why);
    }
    Instance3* in = calloc(1, sizeof *in);
    if (!in) return NULL;
    in->env = env;
    in->logger = logger;
    in->cs.state = S_INSTANTIATED;
    in->log_mask = log_mask_of(loggingOn);
    in->model = model;
    snprintf(in->name, sizeof in->name, "%s", name);
    if (first && load_note[0]) fmi3_say(in, fmi3Warning, "%s: %s", model, load_note);
    call_begin(&in->cs);
    /* loggingOn for the wrapper always: the slave's hand-off passes through fmi3_relay.  No
     * intermediate update (the FMU never returns early; earlyReturnAllowed changes nothing) */
    (void)earlyReturnAllowed;
    (void)update;
    in->real = real_instantiate(instanceName, token, resources, visible, true, false, false, required, nRequired, in,
                                fmi3_relay, NULL);
    if (!in->real) {
        free(in);
        return NULL;
    }
    fmi3_settle(in, T_NONE, fmi3OK);
    return in;
}

EXPORT fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String token, fmi3String resources,
                                                 fmi3Boolean visible, fmi3Boolean loggingOn,
                                                 fmi3InstanceEnvironment env, fmi3LogMessageCallback logger)
{
    (void)token, (void)resources, (void)visible, (void)loggingOn;
    return refuse_instance(instanceName ? instanceName : "", env, logger,
                           "fmi3InstantiateModelExchange: this FMU is Co-Simulation only; use fmi3InstantiateCoSimulation");
}

EXPORT fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String token, fmi3String resources,
                                                      fmi3Boolean visible, fmi3Boolean loggingOn,
                                                      fmi3InstanceEnvironment env, fmi3LogMessageCallback logger,
                                                      fmi3ClockUpdateCallback clock, fmi3LockPreemptionCallback lock,
                                                      fmi3UnlockPreemptionCallback unlock)
{
    (void)token, (void)resources, (void)visible, (void)loggingOn, (void)clock, (void)lock, (void)unlock;
    return refuse_instance(instanceName ? instanceName : "", env, logger, "fmi3InstantiateScheduledExecution: this "
                           "FMU is Co-Simulation only; use fmi3InstantiateCoSimulation");
}

EXPORT void fmi3FreeInstance(fmi3Instance c)
{
    Instance3* in = c;
    if (!loaded || !in) return;
    /* an empty get first hands on what the slave may have queued since its last call (the FMI 2.0
     * loader does the same for pythonfmu, whose wrapper crashed freeing such an instance) */
    if (in->cs.state != S_FATAL) {
        fmi3ValueReference none = 0;
        fmi3Float64 ignored = 0.0;
        real_fmi3GetFloat64(in->real, &none, 0, &ignored, 0);
    }
    real_free(in->real);
    free(in);
}

EXPORT fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n, const fmi3String categories[])
{
    return loaded && c ? fmi3_debug_logging((Instance3*)c, on, n, categories) : fmi3Error;
}

/* ---- the forwarded functions: the state table, the fast lane's pull before and push after
 * (fast_lane.h), the wrapper with its own instance (the inner ``c`` shadows the parameter), the new
 * state ----------------------------------------------------------------------------------------- */

#define FORWARD_BODY(name, allowed, transition, args) \
    Instance3* in = c; \
    if (!loaded || !in) return fmi3Error; \
    if (!fmi3_admit(in, #name, (allowed), NULL)) return fmi3Error; \
    if (in->lane && lane_before_python(in->lane)) lane3_drop(in, "its pull raised"); \
    if ((transition) == T_RESET) in->lane = NULL;     /* the slave starts afresh: a new lane, if any */ \
    call_begin(&in->cs); \
    fmi3Status status; \
    { \
        fmi3Instance c = in->real; \
        status = real_##name args; \
    } \
    status = fmi3_settle(in, (transition), status); \
    if (in->lane && lane_after_python(in->lane)) lane3_drop(in, "its push raised"); \
    return status;

#define FORWARD(name, allowed, transition, params, args) \
    EXPORT fmi3Status name params { FORWARD_BODY(name, allowed, transition, args) }
FMI3_PLAIN(FORWARD)
#define FORWARD_STEP(name, allowed, transition, params, args) \
    static fmi3Status forward_##name params { FORWARD_BODY(name, allowed, transition, args) }
FMI3_HOT(FORWARD_STEP)
FMI3_STEP(FORWARD_STEP)

/* the hot calls: the fast lane when it is open and serves every value reference, else Python */
#define LANE_OPEN(in) (loaded && (in) && lane_open((in)->lane, (in)->cs.state == S_STEP_MODE))
#define HOT(name, lane_call, T) \
    EXPORT fmi3Status name VALUES(T) \
    { \
        Instance3* in = c; \
        return LANE_OPEN(in) && lane_call(in->lane, vr, nvr, v, n) ? fmi3OK : forward_##name VALUE_ARGS; \
    }
HOT(fmi3GetFloat64, lane3_get_float64, fmi3Float64)
HOT(fmi3GetInt32, lane3_get_int32, fmi3Int32)
HOT(fmi3GetBoolean, lane3_get_boolean, fmi3Boolean)
HOT(fmi3SetFloat64, lane3_set_float64, const fmi3Float64)

/* fmi3DoStep: the return arguments are defined before the wrapper runs (pythonfmu3's sets
 * lastSuccessfulTime and terminateSimulation only; the FMU never asks for an event or returns early);
 * a refused call leaves them defined too; a NULL one is replaced by a local (the wrapper writes
 * through the pointers unchecked) */
EXPORT fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noPrior, fmi3Boolean* event,
                             fmi3Boolean* stop, fmi3Boolean* early, fmi3Float64* last)
{
    fmi3Boolean spare[3];
    fmi3Float64 spare_time;
    event = event ? event : &spare[0];
    stop = stop ? stop : &spare[1];
    early = early ? early : &spare[2];
    last = last ? last : &spare_time;
    *event = *stop = *early = false;
    *last = t;
    Instance3* in = c;
    if (LANE_OPEN(in) && lane_do_step(in->lane, t, h)) {
        *last = t + h;          /* as pythonfmu3's wrapper reports a step it took */
        return fmi3OK;
    }
    return forward_fmi3DoStep(c, t, h, noPrior, event, stop, early, last);
}

/* ---- answered by the loader --------------------------------------------------------------------- */

#define NO_VARIABLE_CALL(call, T, allowed) \
    { \
        Instance3* in = c; \
        (void)v, (void)n; \
        if (!loaded || !in) return fmi3Error; \
        if (!fmi3_admit(in, call, (allowed), NULL)) return fmi3Error; \
        if (nvr == 0) return fmi3OK; \
        fmi3_say(in, fmi3Error, "%s instance '%s': %s: this FMU has no " #T " variable (value reference %u; its " \
                 "variables are Float64, Int32 and Boolean); nothing done (fmi3Error)", in->model, in->name, call, \
                 (unsigned)vr[0]); \
        return fmi3Error; \
    }
#define NO_VARIABLES(T, type) \
    EXPORT fmi3Status fmi3Get##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, type v[], size_t n) \
    NO_VARIABLE_CALL("fmi3Get" #T, T, S3_GET) \
    EXPORT fmi3Status fmi3Set##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const type v[], size_t n) \
    NO_VARIABLE_CALL("fmi3Set" #T, T, S_SET)
FMI3_NO_VARIABLES(NO_VARIABLES)

#define ABSENT(name, note, params) \
    EXPORT fmi3Status name params \
    { \
        Instance3* in = c; \
        if (!loaded || !in) return fmi3Error; \
        fmi3_admit(in, #name, 0u, note); \
        return fmi3Error; \
    }
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-parameter"
FMI3_ABSENT(ABSENT)
#pragma GCC diagnostic pop
