/*
 * The fast lane (fast_lane.h): the hot calls answered on the slave's arrays, and the two calls into
 * Python that keep the slave's attributes and the arrays one state.
 *
 * Python is called only from here and only with the GIL taken (PyGILState_Ensure: any thread of the
 * host, the interpreter started by the loader or the host's own); the functions are looked up in
 * the process when the lane is handed over (the Python runtime is up by then: a slave is running).
 */
#define _GNU_SOURCE
#include "fast_lane.h"

#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef int (*gil_ensure_fn)(void);
typedef void (*gil_release_fn)(int);
typedef void* (*call_fn)(void*, void*);
typedef void (*decref_fn)(void*);
typedef void (*void_fn)(void);

static gil_ensure_fn gil_ensure;
static gil_release_fn gil_release;
static call_fn call_object;
static decref_fn dec_ref;
static void_fn print_error;

static int resolve_python(void)
{
    if (gil_ensure) return 0;
    gil_release_fn release = (gil_release_fn)dlsym(RTLD_DEFAULT, "PyGILState_Release");
    call_fn call = (call_fn)dlsym(RTLD_DEFAULT, "PyObject_CallObject");
    decref_fn decref = (decref_fn)dlsym(RTLD_DEFAULT, "Py_DecRef");
    void_fn print = (void_fn)dlsym(RTLD_DEFAULT, "PyErr_Print");
    gil_ensure_fn ensure = (gil_ensure_fn)dlsym(RTLD_DEFAULT, "PyGILState_Ensure");
    if (!(release && call && decref && print && ensure)) return -1;      /* none published: tried again later */
    gil_release = release, call_object = call, dec_ref = decref, print_error = print;
    gil_ensure = ensure;                                                  /* last: the mark of all resolved */
    return 0;
}

Lane* lane_take(const char* text, char* why, size_t why_size)
{
    why[0] = '\0';
    char* end = NULL;
    unsigned long long address = strtoull(text, &end, 0);
    if (!address) return NULL;
    if (end == text || *end) {
        snprintf(why, why_size, "unreadable lane address %s", text);
        return NULL;
    }
    Lane* lane = (Lane*)(uintptr_t)address;
    if (lane->version != LANE_VERSION) {
        snprintf(why, why_size, "lane of layout version %lld, this loader reads version %d", (long long)lane->version,
                 LANE_VERSION);
        return NULL;
    }
    if (resolve_python()) {
        snprintf(why, why_size, "the Python C API (PyGILState_Ensure, PyObject_CallObject) is not in the process");
        return NULL;
    }
    return lane;
}

/* the lane serves value reference k (below n_vr): all bits of ``want``, not an output gone stale (dirty) */
static inline int lane_serves_one(const Lane* lane, int64_t k, unsigned want)
{
    unsigned f = lane->flags[k];
    return (f & want) == want && !(lane->dirty && (f & LANE_OUTPUT));
}

/* an input's new value: stored, and the outputs of direct feedthrough stale if it marks them */
static inline void lane_store(Lane* lane, int64_t k, double v)
{
    lane->real[k] = v;
    if (lane->flags[k] & LANE_DIRTIES) lane->dirty = 1;     /* as the slave's set marks it */
}

/* every value reference below n_vr and served (lane_serves_one) */
static int lane_serves(const Lane* lane, const unsigned vr[], size_t n, unsigned want)
{
    if (n && !vr) return 0;                 /* the Python path answers a malformed call */
    for (size_t i = 0; i < n; i++)
        if ((int64_t)vr[i] >= lane->n_vr || !lane_serves_one(lane, vr[i], want)) return 0;
    return 1;
}

int lane_set_real(Lane* lane, const unsigned vr[], size_t n, const double v[])
{
    if (n && !v) return 0;
    if (!lane_serves(lane, vr, n, LANE_REAL | LANE_SET)) return 0;
    for (size_t i = 0; i < n; i++) lane_store(lane, vr[i], v[i]);
    if (n) lane->py_stale = 1;
    lane->fast_calls++;
    return 1;
}

/* a get of one type: every value reference served, else 0 (the call goes to Python) */
#define LANE_GET(name, type, array, bit) \
    int name(Lane* lane, const unsigned vr[], size_t n, type v[]) \
    { \
        if ((n && !v) || !lane_serves(lane, vr, n, (bit))) return 0; \
        for (size_t i = 0; i < n; i++) v[i] = lane->array[vr[i]]; \
        lane->fast_calls++; \
        return 1; \
    }
LANE_GET(lane_get_real, double, real, LANE_REAL)
LANE_GET(lane_get_integer, int, integer, LANE_INTEGER)
LANE_GET(lane_get_boolean, int, boolean, LANE_BOOLEAN)

/* FMI 3.0: every value reference mapped onto core value references the lane serves (lane_serves_one),
 * ``n`` values in all; else 0 */
static int lane3_serves(const Lane* lane, const uint32_t vr[], size_t nvr, size_t n, unsigned want)
{
    if (!lane->first3 || !lane->count3 || (nvr && !vr)) return 0;
    size_t total = 0;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] >= lane->n_vr3) return 0;
        int64_t first = lane->first3[vr[i]], count = lane->count3[vr[i]];
        if (first < 0 || count <= 0 || first + count > lane->n_vr) return 0;
        for (int64_t k = first; k < first + count; k++)
            if (!lane_serves_one(lane, k, want)) return 0;
        total += (size_t)count;
    }
    return total == n;
}

int lane3_set_float64(Lane* lane, const uint32_t vr[], size_t nvr, const double v[], size_t n)
{
    if ((n && !v) || !lane3_serves(lane, vr, nvr, n, LANE_REAL | LANE_SET)) return 0;
    size_t j = 0;
    for (size_t i = 0; i < nvr; i++)
        for (int64_t k = lane->first3[vr[i]], end = k + lane->count3[vr[i]]; k < end; k++) lane_store(lane, k, v[j++]);
    if (n) lane->py_stale = 1;
    lane->fast_calls++;
    return 1;
}

/* an FMI 3.0 get of one type: every value reference served, else 0 (the call goes to Python) */
#define LANE3_GET(name, type, array, bit, convert) \
    int name(Lane* lane, const uint32_t vr[], size_t nvr, type v[], size_t n) \
    { \
        if ((n && !v) || !lane3_serves(lane, vr, nvr, n, (bit))) return 0; \
        size_t j = 0; \
        for (size_t i = 0; i < nvr; i++) \
            for (int64_t k = lane->first3[vr[i]], end = k + lane->count3[vr[i]]; k < end; k++) \
                v[j++] = convert(lane->array[k]); \
        lane->fast_calls++; \
        return 1; \
    }
#define AS_IS(x) (x)
#define AS_BOOL(x) ((x) != 0)
LANE3_GET(lane3_get_float64, double, real, LANE_REAL, AS_IS)
LANE3_GET(lane3_get_int32, int32_t, integer, LANE_INTEGER, AS_IS)
LANE3_GET(lane3_get_boolean, bool, boolean, LANE_BOOLEAN, AS_BOOL)

int lane_do_step(Lane* lane, double t, double h)
{
    if (lane->step(lane->table, LANE_CMD_PUBLISH, t, h) != LANE_PUBLISHED) {
        lane->py_stale = 1;     /* the slave looks at the step's state before it takes the step itself */
        return 0;
    }
    lane->dirty = 0;
    lane->py_stale = 1;
    lane->fast_steps++;
    return 1;
}

static int call_python(void* method)
{
    int gil = gil_ensure();
    void* result = call_object(method, NULL);
    if (result)
        dec_ref(result);
    else
        print_error();          /* the traceback to stderr; the loader drops the lane */
    gil_release(gil);
    return result ? 0 : -1;
}

int lane_before_python(Lane* lane)
{
    if (!lane->py_stale) return 0;
    return call_python(lane->pull);
}

int lane_after_python(Lane* lane) { return call_python(lane->push); }
