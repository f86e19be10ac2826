/*
 * The FMU's binary: a loader that brings the Python runtime into a host process without Python,
 * then forwards every FMI 2.0 Co-Simulation function to pythonfmu's wrapper.
 *
 * Why.  pythonfmu's wrapper (shipped beside this file as libpythonfmu-export.so) calls the Python
 * C API but is not linked against libpython: it works only in a process that already has Python
 * (fmpy, libcosimpy, ecospy).  A C host (OMSimulator's command line, OpenModelica, Dymola, ...)
 * fails with "undefined symbol: _Py_NoneStruct".
 *
 * What it does, once per process, in the first fmi2Instantiate (serialized by a mutex):
 *  1. If the process already has an initialized Python (Py_IsInitialized visible globally and true:
 *     fmpy and other Python hosts), it uses that one and starts nothing.
 *  2. Otherwise it opens libpython with RTLD_GLOBAL (the one recorded at build time in
 *     resources/python_runtime.txt, or the one of the interpreter named by $RRR_DK_PYTHON), sets
 *     the program name to that interpreter (so sys.prefix, the venv and its site-packages are the
 *     interpreter's own), initializes Python without signal handlers and releases the GIL.
 *     It never finalizes Python: numpy, numba and scipy cannot be re-initialized in one process,
 *     and a finalize at library unload runs while the host may still hold threads.
 *  3. It opens pythonfmu's wrapper (RTLD_LOCAL | RTLD_NODELETE: its symbols do not clash with ours,
 *     and it is never unmapped under a live interpreter) and resolves its fmi2* functions.
 * pythonfmu's wrapper starts (and later finalizes) an interpreter only if Py_IsInitialized() is
 * false when it is first used, so with this loader it never does either.
 *
 * The exit crash ("corrupted double-linked list" at process exit).  The wrapper keeps a static
 * std::shared_ptr<PyState> and resets it in a __attribute__((destructor)) function.  At dlclose the
 * destructor runs first and the static's destructor then finds it empty: fine.  But when the
 * wrapper is still loaded at exit (a host that keeps the library, or a library dlclose does not
 * unmap), exit() runs the static's destructor first (registered with __cxa_atexit, which runs before
 * _dl_fini) and then the destructor function resets the destroyed shared_ptr: it decrements the
 * use count inside the freed control block (8 bytes in: the "bk" pointer of a free chunk), and
 * glibc aborts later on the corrupted free list (valgrind: "Invalid read of size 4 ... in
 * finalizePythonInterpreter ... inside a block of size 128 free'd").  So after opening the wrapper
 * the loader registers an atexit handler (run before the wrapper's static destructor, LIFO; or at the
 * loader's own dlclose) that calls the wrapper's finalizePythonInterpreter: the shared_ptr is then
 * empty before either destructor runs.  It never finalizes Python (the wrapper did not start it).
 *
 * Errors never crash the host: fmi2Instantiate returns NULL after logging, through the host's
 * logger (and stderr), what is missing and how to fix it.
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
#include <wchar.h>

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

#define WRAPPER_NAME "libpythonfmu-export.so"
#define RUNTIME_FILE "python_runtime.txt"
#define PYTHON_ENV "RRR_DK_PYTHON"

/* ---- the wrapper's functions ------------------------------------------------------------------ */

#define FMI2_FUNCTIONS(X) \
    X(fmi2SetDebugLogging, (fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]), (c, on, n, cat)) \
    X(fmi2SetupExperiment, (fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0, fmi2Boolean stopDef, \
                            fmi2Real t1), (c, tolDef, tol, t0, stopDef, t1)) \
    X(fmi2EnterInitializationMode, (fmi2Component c), (c)) \
    X(fmi2ExitInitializationMode, (fmi2Component c), (c)) \
    X(fmi2Terminate, (fmi2Component c), (c)) \
    X(fmi2Reset, (fmi2Component c), (c)) \
    X(fmi2GetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]), (c, vr, n, v)) \
    X(fmi2GetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]), (c, vr, n, v)) \
    X(fmi2GetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]), (c, vr, n, v)) \
    X(fmi2GetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]), (c, vr, n, v)) \
    X(fmi2SetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]), (c, vr, n, v)) \
    X(fmi2SetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]), \
      (c, vr, n, v)) \
    X(fmi2SetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]), \
      (c, vr, n, v)) \
    X(fmi2SetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]), \
      (c, vr, n, v)) \
    X(fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate* s), (c, s)) \
    X(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate s), (c, s)) \
    X(fmi2FreeFMUstate, (fmi2Component c, fmi2FMUstate* s), (c, s)) \
    X(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate s, size_t* n), (c, s, n)) \
    X(fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n), (c, s, b, n)) \
    X(fmi2DeSerializeFMUstate, (fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s), (c, b, n, s)) \
    X(fmi2GetDirectionalDerivative, (fmi2Component c, const fmi2ValueReference u[], size_t nu, \
      const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]), (c, u, nu, z, nz, du, dz)) \
    X(fmi2SetRealInputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Integer order[], const fmi2Real v[]), (c, vr, n, order, v)) \
    X(fmi2GetRealOutputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, \
      const fmi2Integer order[], fmi2Real v[]), (c, vr, n, order, v)) \
    X(fmi2DoStep, (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noPrior), (c, t, h, noPrior)) \
    X(fmi2CancelStep, (fmi2Component c), (c)) \
    X(fmi2GetStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Status* v), (c, k, v)) \
    X(fmi2GetRealStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Real* v), (c, k, v)) \
    X(fmi2GetIntegerStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Integer* v), (c, k, v)) \
    X(fmi2GetBooleanStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Boolean* v), (c, k, v)) \
    X(fmi2GetStringStatus, (fmi2Component c, const fmi2StatusKind k, fmi2String* v), (c, k, v))

#define DECLARE_POINTER(name, params, args) static fmi2Status (*real_##name) params;
FMI2_FUNCTIONS(DECLARE_POINTER)
static fmi2Component (*real_fmi2Instantiate)(fmi2String, fmi2Type, fmi2String, fmi2String,
                                             const fmi2CallbackFunctions*, fmi2Boolean, fmi2Boolean);
static void (*real_fmi2FreeInstance)(fmi2Component);
static void (*release_py_state)(void);   /* the wrapper's finalizePythonInterpreter */

static pthread_mutex_t load_lock = PTHREAD_MUTEX_INITIALIZER;
static int loaded;                 /* the wrapper's functions are resolved */
static char load_error[8192];      /* why loading failed (kept: every later instantiate reports it) */

/* ---- helpers ------------------------------------------------------------------------------------ */

static int fail(const char* fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(load_error, sizeof load_error, fmt, ap);
    va_end(ap);
    return -1;
}

/* The folder of this library (binaries/linux64), without the trailing slash. */
static int own_folder(char* out, size_t size)
{
    Dl_info info;
    if (!dladdr((void*)&own_folder, &info) || !info.dli_fname)
        return fail("the FMU's binary cannot find its own path (dladdr failed)");
    snprintf(out, size, "%s", info.dli_fname);
    char* slash = strrchr(out, '/');
    if (!slash)
        return fail("the FMU's binary was loaded without a path (%s)", info.dli_fname);
    *slash = '\0';
    return 0;
}

static void strip(char* s)
{
    size_t n = strlen(s);
    while (n && (s[n - 1] == '\n' || s[n - 1] == '\r' || s[n - 1] == ' ')) s[--n] = '\0';
}

/* Read "python=" and "libpython=" from the build-time record or, with $RRR_DK_PYTHON, ask that
 * interpreter (it prints the same two lines). */
static int python_runtime(const char* binaries, char* python, char* libpython, size_t size)
{
    char source[PATH_MAX + 64];
    const char* chosen = getenv(PYTHON_ENV);
    FILE* f;
    int from_env = chosen && *chosen;
    if (from_env) {
        if (strchr(chosen, '\'')) return fail("$%s must not contain a quote: %s", PYTHON_ENV, chosen);
        char cmd[PATH_MAX + 512];
        snprintf(cmd, sizeof cmd,
                 "'%s' -c 'import os, sys, sysconfig as s; print(\"python=\" + sys.executable); "
                 "print(\"libpython=\" + (os.path.join(s.get_config_var(\"LIBDIR\"), s.get_config_var(\"INSTSONAME\")) "
                 "if s.get_config_var(\"Py_ENABLE_SHARED\") else \"\"))' 2>/dev/null", chosen);
        snprintf(source, sizeof source, "$%s=%s", PYTHON_ENV, chosen);
        f = popen(cmd, "r");
    } else {
        snprintf(source, sizeof source, "%s/../../resources/%s", binaries, RUNTIME_FILE);
        f = fopen(source, "r");
    }
    if (!f) return fail("cannot read %s", source);
    char line[PATH_MAX + 64];
    python[0] = libpython[0] = '\0';
    while (fgets(line, sizeof line, f)) {
        strip(line);
        if (!strncmp(line, "python=", 7)) snprintf(python, size, "%s", line + 7);
        else if (!strncmp(line, "libpython=", 10)) snprintf(libpython, size, "%s", line + 10);
    }
    int status = from_env ? pclose(f) : fclose(f);
    if (!python[0])
        return fail("%s does not name a Python interpreter%s", source,
                    from_env ? " that runs (set it to the python of the environment that has the FMU's "
                               "requirements)" : " (rebuild the FMU, or set $" PYTHON_ENV " to a python)");
    if (!libpython[0])
        return fail("the Python of %s (%s) has no shared libpython (a build without --enable-shared); "
                    "set $%s to a Python built with a shared library", source, python, PYTHON_ENV);
    (void)status;
    return 0;
}

/* Open libpython globally and start an interpreter unless the process has one. */
static int ensure_python(const char* binaries)
{
    int (*is_initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (is_initialized && is_initialized())
        return 0;                                           /* a Python host: use its interpreter */
    char python[PATH_MAX], libpython[PATH_MAX];
    if (python_runtime(binaries, python, libpython, sizeof python)) return -1;
    void* lib = dlopen(libpython, RTLD_NOW | RTLD_GLOBAL | RTLD_NODELETE);
    if (!lib)
        return fail("cannot open the Python library %s (%s); set $%s to a python whose environment has the "
                    "FMU's requirements (resources/requirements.txt)", libpython, dlerror(), PYTHON_ENV);
    is_initialized = (int (*)(void))dlsym(lib, "Py_IsInitialized");
    void (*initialize)(int) = (void (*)(int))dlsym(lib, "Py_InitializeEx");
    void* (*save_thread)(void) = (void* (*)(void))dlsym(lib, "PyEval_SaveThread");
    void (*set_program_name)(const wchar_t*) = (void (*)(const wchar_t*))dlsym(lib, "Py_SetProgramName");
    wchar_t* (*decode)(const char*, size_t*) = (wchar_t* (*)(const char*, size_t*))dlsym(lib, "Py_DecodeLocale");
    if (!is_initialized || !initialize || !save_thread || !set_program_name || !decode)
        return fail("%s lacks Py_InitializeEx, PyEval_SaveThread, Py_SetProgramName or Py_DecodeLocale "
                    "(Python 3.8-3.13 has them); set $%s to such a python", libpython, PYTHON_ENV);
    if (is_initialized())
        return 0;
    /* the program name stays referenced by the interpreter: never freed */
    wchar_t* name = decode(python, NULL);
    if (!name) return fail("cannot decode the interpreter path %s", python);
    set_program_name(name);     /* sys.executable, sys.prefix, the venv: those of that interpreter */
    initialize(0);              /* no signal handlers: the host owns SIGINT */
    if (!is_initialized())
        return fail("Python (%s, %s) did not initialize", python, libpython);
    save_thread();              /* release the GIL: pythonfmu takes it per call (PyGILState_Ensure) */
    return 0;
}

/* see "The exit crash" above; runs at exit, or when the host unloads this library */
static void release_wrapper_state(void)
{
    if (release_py_state) release_py_state();
}

#define RESOLVE(name, params, args) \
    if (!(real_##name = (fmi2Status(*) params)dlsym(wrapper, #name))) return fail("%s lacks %s", path, #name);

static int load(void)
{
    char binaries[PATH_MAX], path[PATH_MAX + 64];
    if (own_folder(binaries, sizeof binaries) || ensure_python(binaries)) return -1;
    snprintf(path, sizeof path, "%s/%s", binaries, WRAPPER_NAME);
    void* wrapper = dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!wrapper) return fail("cannot open pythonfmu's wrapper %s: %s", path, dlerror());
    FMI2_FUNCTIONS(RESOLVE)
    real_fmi2Instantiate = dlsym(wrapper, "fmi2Instantiate");
    real_fmi2FreeInstance = dlsym(wrapper, "fmi2FreeInstance");
    if (!real_fmi2Instantiate || !real_fmi2FreeInstance)
        return fail("%s lacks fmi2Instantiate or fmi2FreeInstance", path);
    release_py_state = (void (*)(void))dlsym(wrapper, "finalizePythonInterpreter");
    if (release_py_state) atexit(release_wrapper_state);   /* after the wrapper's statics: runs first */
    return 0;
}

/* ---- the FMI functions -------------------------------------------------------------------------- */

EXPORT const char* fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char* fmi2GetVersion(void) { return "2.0"; }

EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                     fmi2String fmuResourceLocation, const fmi2CallbackFunctions* functions,
                                     fmi2Boolean visible, fmi2Boolean loggingOn)
{
    pthread_mutex_lock(&load_lock);
    if (!loaded && !load_error[0])
        loaded = load() == 0;
    pthread_mutex_unlock(&load_lock);
    if (!loaded) {
        const char* name = instanceName ? instanceName : "";
        fprintf(stderr, "FMU instance %s: %s\n", name, load_error);
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError", "%s", load_error);
        return NULL;
    }
    return real_fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation, functions, visible, loggingOn);
}

EXPORT void fmi2FreeInstance(fmi2Component c)
{
    if (loaded && c) real_fmi2FreeInstance(c);
}

/* every other function needs a component, which only a loaded wrapper hands out */
#define FORWARD(name, params, args) \
    EXPORT fmi2Status name params { return loaded ? real_##name args : fmi2Error; }
FMI2_FUNCTIONS(FORWARD)
