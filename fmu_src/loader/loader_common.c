/*
 * The part of the FMU's loader that does not depend on the FMI version (loader_common.h): used by
 * the FMI 2.0 loader (fmi2_loader.c, fmi2_states.c) and the FMI 3.0 loader (fmi3_loader.c,
 * fmi3_states.c); each FMU's binary is one of them compiled with this file and python_runtime.c.
 *
 * loader_open: once per process, in the first instantiation (the caller holds its lock), start_python
 * (the process's Python, else the first interpreter that fits), then the wrapper (pythonfmu's or
 * pythonfmu3's C++ library, shipped beside this one under its own name) opened RTLD_LOCAL |
 * RTLD_NODELETE: its symbols do not clash with ours, and it is never unmapped under a live
 * interpreter.  This library pins itself (a host that unloads and loads it again finds the same
 * loaded state).  Both wrappers keep a static std::shared_ptr<PyState> that a destructor function
 * resets after exit() already destroyed it (glibc aborts: "corrupted double-linked list"); the atexit
 * handler registered here after opening the wrapper runs before the wrapper's static destructor
 * (LIFO) and empties the pointer first through the wrapper's finalizePythonInterpreter.
 */
#define _GNU_SOURCE
#include "loader_common.h"

#include <dlfcn.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "python_runtime.h"

/* ---- loading ------------------------------------------------------------------------------------ */

static void (*release_py_state)(void);   /* the wrapper's finalizePythonInterpreter */

static void release_wrapper_state(void)
{
    if (release_py_state) release_py_state();
}

static void* fail(char* error, size_t size, const char* fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(error, size, fmt, ap);
    va_end(ap);
    return NULL;
}

void* loader_open(const char* wrapper_name, char* model, size_t model_size, char* error, size_t error_size,
                  char* note, size_t note_size)
{
    Dl_info info;
    char binaries[PATH_MAX], path[PATH_MAX + 64];
    if (!dladdr((void*)&loader_open, &info) || !info.dli_fname)
        return fail(error, error_size, "the FMU's binary cannot find its own path (dladdr failed)");
    dlopen(info.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);    /* pinned: never unmapped */
    snprintf(binaries, sizeof binaries, "%s", info.dli_fname);
    char* slash = strrchr(binaries, '/');
    if (!slash) return fail(error, error_size, "the FMU's binary was loaded without a path (%s)", info.dli_fname);
    *slash = '\0';
    snprintf(model, model_size, "%s", slash + 1);
    char* dot = strrchr(model, '.');
    if (dot) *dot = '\0';
    if (start_python(binaries, model, error, error_size, note, note_size)) return NULL;
    snprintf(path, sizeof path, "%s/%s", binaries, wrapper_name);
    void* wrapper = dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (!wrapper) return fail(error, error_size, "cannot open the Python wrapper %s: %s", path, dlerror());
    release_py_state = (void (*)(void))dlsym(wrapper, "finalizePythonInterpreter");
    if (release_py_state) atexit(release_wrapper_state);   /* after the wrapper's statics: runs first */
    return wrapper;
}

/* ---- states ------------------------------------------------------------------------------------- */

/* the slave's (FMI 2.0) state names, as fmu_src/fmi_states.py hands them over */
static const char* const CORE_NAMES[N_STATES] = {
    "instantiated", "initializationMode", "stepComplete", "stepFailed", "terminated", "error", "fatal"};

const char* state_text(const Dialect* d, unsigned state)
{
    for (unsigned k = 0; k < N_STATES; ++k)
        if (state == 1u << k) return d->names[k];
    return "unknown";
}

void states_text(const Dialect* d, unsigned allowed, char* out, size_t size)
{
    out[0] = '\0';
    for (unsigned k = 0; k < N_STATES; ++k)
        if (allowed & (1u << k))
            snprintf(out + strlen(out), size - strlen(out), "%s%s", out[0] ? ", " : "", d->names[k]);
}

void call_begin(CallState* cs)
{
    cs->reported = 0;
    cs->call_status = 0;
}

int call_settle(CallState* cs, const Dialect* d, Transition t, int status)
{
    /* the state after a successful call, by transition (T_NONE: unchanged); the same in both versions */
    static const unsigned next[] = {0, S_INITIALIZATION_MODE, S_STEP_COMPLETE, S_STEP_COMPLETE, S_TERMINATED,
                                    S_INSTANTIATED};
    if (cs->call_status > status) status = cs->call_status;
    if (status >= 4) {                                  /* fmi2Fatal, fmi3Fatal */
        cs->state = S_FATAL;
    } else if (cs->reported) {
        cs->state = cs->reported;
    } else if (status <= 1) {                           /* OK, Warning */
        if (next[t]) cs->state = next[t];
    } else if (t == T_STEP && status == 2) {            /* Discard */
        if (d->discard_state) cs->state = d->discard_state;
    } else if (status == 3 && (t == T_EXIT || t == T_STEP)) {
        cs->state = S_ERROR;
    }
    if (cs->state != S_ERROR) cs->reason[0] = '\0';
    return status;
}

int take_hand_off(CallState* cs, const char* text, unsigned (*map)(unsigned))
{
    const char* space = strchr(text, ' ');
    size_t n = space ? (size_t)(space - text) : strlen(text);
    unsigned state = 0;
    for (unsigned k = 0; k < N_STATES && !state; ++k)
        if (strlen(CORE_NAMES[k]) == n && !strncmp(text, CORE_NAMES[k], n)) state = 1u << k;
    if (!state) return -1;
    cs->reported = map ? map(state) : state;
    if (space) {
        char* end;
        long status = strtol(space + 1, &end, 10);
        if (end != space + 1 && status > (long)cs->call_status && status <= 4) cs->call_status = (int)status;
        if (*end == ' ' && state == S_ERROR) snprintf(cs->reason, sizeof cs->reason, "%s", end + 1);
    }
    return 0;
}

/* ---- log categories ----------------------------------------------------------------------------- */

static const char* const CATEGORIES[N_CATEGORIES] = {
    "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal", "logAll"};

unsigned log_mask_of(int on) { return on ? ALL_CATEGORIES : 0u; }

int category_bit(const char* name)
{
    for (unsigned k = 0; k < N_CATEGORIES; ++k)
        if (name && !strcmp(name, CATEGORIES[k])) return (int)k;
    return -1;
}

const char* category_of(int status)
{
    static const char* const by_status[] = {"logAll", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                            "logStatusFatal"};
    return status >= 0 && status <= 4 ? by_status[status] : "logAll";
}

int debug_logging(unsigned* mask, int on, size_t n, const char* const categories[], const char** unknown)
{
    if (n == 0) {
        *mask = log_mask_of(on);
        return 0;
    }
    unsigned bits = 0;
    for (size_t i = 0; i < n; ++i) {
        int bit = categories ? category_bit(categories[i]) : -1;
        if (bit < 0) {
            *unknown = categories && categories[i] ? categories[i] : "(null)";
            return -1;
        }
        bits |= 1u << bit;
    }
    *mask = on ? (*mask | bits) : (*mask & ~bits);
    return 0;
}
