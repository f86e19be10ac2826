/*
 * A minimal FMI 2.0 Co-Simulation host in C, with no Python in its process (tests/test_c_host.py).
 *
 *   fmi2_host <unzipped FMU folder> <modelIdentifier> <guid> <step size> <steps> <inputs file> <output vrs>
 *             <start values> [life <cycles>]
 *
 * It dlopens binaries/linux64/<modelIdentifier>.so, runs fmi2Instantiate, sets the real start values
 * ("vr=value,vr=value", or "-"), fmi2SetupExperiment,
 * enter/exit initialization (the inputs' first row set in initialization mode), then <steps> times:
 * set the row of inputs of that step, fmi2DoStep, fmi2GetReal of the outputs; then fmi2Terminate and
 * fmi2FreeInstance.
 * The inputs file: a first line of input value references, then one line of values per step
 * (steps + 1 lines: row k is applied at t = k h); "-" for no inputs.  Output vrs: comma-separated.
 * stdout: "python_before <0|1>" (whether Python's C API was in the process before the FMU was
 * instantiated), "python_after <0|1>", "seconds_instantiate <s>" (dlopen + fmi2Instantiate),
 * "seconds_initialize <s>" (setup, start values, enter/exit initialization), then one line per step:
 * t and the outputs (%.17g), then "seconds_step_median <s>" (the median step: set the inputs,
 * fmi2DoStep, fmi2GetReal of the outputs) and "end".
 * With "life <cycles>" (the host life test) it prints no rows; in one process it runs the same
 * sequence <cycles> times, each with its own fmi2Instantiate/fmi2FreeInstance; then two instances
 * alive at once, stepped in turn; then fmi2Reset of one of them and a second run; every run must
 * give the first run's outputs bit for bit ("life <what> identical", else exit 1).  It also checks
 * that the FMU refuses a call its state forbids (fmi2DoStep right after fmi2Instantiate) with
 * fmi2Error ("refused_status 3").
 * Exit status 0 on success, 1 on any FMI error (with the reason on stderr).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef void* fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef void (*Logger)(void*, const char*, fmi2Status, const char*, const char*, ...);
typedef struct {
    Logger logger;
    void* (*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void*);
    void (*stepFinished)(void*, fmi2Status);
    void* componentEnvironment;
} Callbacks;

static void logger(void* env, const char* instance, fmi2Status status, const char* category, const char* fmt, ...)
{
    va_list ap;
    (void)env;
    fprintf(stderr, "[%s %d %s] ", instance ? instance : "", (int)status, category ? category : "");
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

static void* symbol(void* lib, const char* name)
{
    void* f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "the FMU's binary lacks %s\n", name);
        exit(1);
    }
    return f;
}

static void check(fmi2Status s, const char* what)
{
    if (s > fmi2Warning) {
        fprintf(stderr, "%s returned status %d\n", what, (int)s);
        exit(1);
    }
}

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static int has_python(void) { return dlsym(RTLD_DEFAULT, "Py_IsInitialized") != NULL; }

/* comma or space separated value references; returns their number */
static size_t parse_vrs(char* text, fmi2ValueReference* out, size_t max)
{
    size_t n = 0;
    for (char* tok = strtok(text, ", \n"); tok && n < max; tok = strtok(NULL, ", \n"))
        out[n++] = (fmi2ValueReference)strtoul(tok, NULL, 10);
    return n;
}

/* the FMU's functions */
typedef struct {
    fmi2Component (*instantiate)(const char*, int, const char*, const char*, const Callbacks*, int, int);
    fmi2Status (*setup)(fmi2Component, int, double, double, int, double);
    fmi2Status (*enter)(fmi2Component);
    fmi2Status (*exit_init)(fmi2Component);
    fmi2Status (*set_real)(fmi2Component, const fmi2ValueReference*, size_t, const double*);
    fmi2Status (*get_real)(fmi2Component, const fmi2ValueReference*, size_t, double*);
    fmi2Status (*do_step)(fmi2Component, double, double, int);
    fmi2Status (*terminate)(fmi2Component);
    fmi2Status (*reset)(fmi2Component);
    void (*free_instance)(fmi2Component);
} Api;

/* the run: the FMU, its inputs, outputs and start values */
typedef struct {
    Api f;
    const char *guid, *uri;
    double h;
    int steps;
    size_t n_in, n_out, n_start;
    fmi2ValueReference in_vr[64], out_vr[64], start_vr[64];
    double start[64];
    double* inputs;
} Run;

static Callbacks callbacks = {logger, calloc, free, NULL, NULL};

static fmi2Component instantiate(const Run* r, const char* name)
{
    fmi2Component c = r->f.instantiate(name, 1 /* fmi2CoSimulation */, r->guid, r->uri, &callbacks, 0, 0);
    if (!c) { fprintf(stderr, "fmi2Instantiate returned NULL\n"); exit(1); }
    return c;
}

/* start values, setup, initialization (the inputs' first row set in initialization mode) */
static void initialize(const Run* r, fmi2Component c)
{
    for (size_t i = 0; i < r->n_start; ++i) check(r->f.set_real(c, &r->start_vr[i], 1, &r->start[i]), "fmi2SetReal (start value)");
    check(r->f.setup(c, 0, 0.0, 0.0, 0, 0.0), "fmi2SetupExperiment");
    check(r->f.enter(c), "fmi2EnterInitializationMode");
    if (r->n_in) check(r->f.set_real(c, r->in_vr, r->n_in, r->inputs), "fmi2SetReal");
    check(r->f.exit_init(c), "fmi2ExitInitializationMode");
}

/* step k: the row of inputs, fmi2DoStep, the outputs into out[0..n_out) */
static void step(const Run* r, fmi2Component c, int k, double* out)
{
    if (r->n_in) check(r->f.set_real(c, r->in_vr, r->n_in, r->inputs + (size_t)k * r->n_in), "fmi2SetReal");
    check(r->f.do_step(c, k * r->h, r->h, 1), "fmi2DoStep");
    check(r->f.get_real(c, r->out_vr, r->n_out, out), "fmi2GetReal");
}

/* initialize and all steps on ``c``; the outputs of step k at table + k * n_out */
static void whole_run(const Run* r, fmi2Component c, double* table)
{
    initialize(r, c);
    for (int k = 0; k < r->steps; ++k) step(r, c, k, table + (size_t)k * r->n_out);
    check(r->f.terminate(c), "fmi2Terminate");
}

static void same(const Run* r, const double* a, const double* b, const char* what)
{
    if (memcmp(a, b, sizeof(double) * r->n_out * (size_t)r->steps) != 0) {
        fprintf(stderr, "life: %s differs from the first run\n", what);
        exit(1);
    }
    printf("life %s identical\n", what);
}

/* the host life test (top of the file) */
static int life(Run* r, int cycles)
{
    size_t size = sizeof(double) * r->n_out * (size_t)r->steps;
    double *first = malloc(size), *other = malloc(size), *second = malloc(size);
    for (int k = 0; k < cycles; ++k) {
        fmi2Component c = instantiate(r, "life");
        if (k == 0) printf("refused_status %d\n", (int)r->f.do_step(c, 0.0, r->h, 1));
        whole_run(r, c, k ? other : first);
        r->f.free_instance(c);
        if (k) same(r, first, other, "cycle");
    }
    fmi2Component a = instantiate(r, "a"), b = instantiate(r, "b");
    initialize(r, a);
    initialize(r, b);
    for (int k = 0; k < r->steps; ++k) {         /* in turn: each instance keeps its own state */
        step(r, a, k, other + (size_t)k * r->n_out);
        step(r, b, k, second + (size_t)k * r->n_out);
    }
    same(r, first, other, "two_instances_a");
    same(r, first, second, "two_instances_b");
    check(r->f.terminate(a), "fmi2Terminate");
    check(r->f.reset(a), "fmi2Reset");
    whole_run(r, a, other);
    same(r, first, other, "reset");
    r->f.free_instance(a);
    r->f.free_instance(b);
    free(first), free(other), free(second);
    printf("end\n");
    fflush(stdout);
    return 0;
}

static int by_value(const void* a, const void* b)
{
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

int main(int argc, char** argv)
{
    if (argc != 9 && !(argc == 11 && !strcmp(argv[9], "life"))) {
        fprintf(stderr, "usage: %s <folder> <modelIdentifier> <guid> <h> <steps> <inputs|-> <output vrs> "
                        "<vr=start,...|-> [life <cycles>]\n", argv[0]);
        return 2;
    }
    const char *folder = argv[1], *model = argv[2];
    static Run r;
    r.guid = argv[3];
    r.h = atof(argv[4]);
    r.steps = atoi(argv[5]);
    r.n_out = parse_vrs(argv[7], r.out_vr, 64);
    if (strcmp(argv[6], "-") != 0) {
        FILE* f = fopen(argv[6], "r");
        char line[4096];
        if (!f || !fgets(line, sizeof line, f)) { fprintf(stderr, "cannot read %s\n", argv[6]); return 1; }
        r.n_in = parse_vrs(line, r.in_vr, 64);
        r.inputs = calloc((size_t)(r.steps + 1) * r.n_in, sizeof(double));
        for (size_t i = 0; i < (size_t)(r.steps + 1) * r.n_in; ++i)
            if (fscanf(f, "%lf", &r.inputs[i]) != 1) { fprintf(stderr, "%s: too few values\n", argv[6]); return 1; }
        fclose(f);
    }
    if (strcmp(argv[8], "-") != 0) {
        for (char* tok = strtok(argv[8], ","); tok && r.n_start < 64; tok = strtok(NULL, ",")) {
            char* eq = strchr(tok, '=');
            r.start_vr[r.n_start] = (fmi2ValueReference)strtoul(tok, NULL, 10);
            r.start[r.n_start++] = eq ? strtod(eq + 1, NULL) : 0.0;
        }
    }

    char path[4096], uri[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", folder, model);
    snprintf(uri, sizeof uri, "file://%s/resources", folder);
    r.uri = uri;
    printf("python_before %d\n", has_python());
    double t0 = now();
    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen failed: %s\n", dlerror()); return 1; }
    r.f.instantiate = symbol(lib, "fmi2Instantiate");
    r.f.setup = symbol(lib, "fmi2SetupExperiment");
    r.f.enter = symbol(lib, "fmi2EnterInitializationMode");
    r.f.exit_init = symbol(lib, "fmi2ExitInitializationMode");
    r.f.set_real = symbol(lib, "fmi2SetReal");
    r.f.get_real = symbol(lib, "fmi2GetReal");
    r.f.do_step = symbol(lib, "fmi2DoStep");
    r.f.terminate = symbol(lib, "fmi2Terminate");
    r.f.reset = symbol(lib, "fmi2Reset");
    r.f.free_instance = symbol(lib, "fmi2FreeInstance");
    if (argc == 11) return life(&r, atoi(argv[10]));

    fmi2Component c = instantiate(&r, "c_host");
    double t1 = now();
    printf("python_after %d\n", has_python());
    initialize(&r, c);
    printf("seconds_instantiate %.3f\nseconds_initialize %.3f\n", t1 - t0, now() - t1);
    double out[64];
    double* seconds = malloc(sizeof(double) * (size_t)(r.steps > 0 ? r.steps : 1));
    for (int k = 0; k < r.steps; ++k) {
        double s0 = now();
        step(&r, c, k, out);
        seconds[k] = now() - s0;
        printf("%.17g", (k + 1) * r.h);
        for (size_t i = 0; i < r.n_out; ++i) printf(" %.17g", out[i]);
        printf("\n");
    }
    if (r.steps > 0) {                 /* the median step: set the inputs, fmi2DoStep, get the outputs */
        qsort(seconds, (size_t)r.steps, sizeof(double), by_value);
        printf("seconds_step_median %.9f\n", seconds[r.steps / 2]);
    }
    free(seconds);
    check(r.f.terminate(c), "fmi2Terminate");
    r.f.free_instance(c);
    printf("end\n");
    fflush(stdout);
    free(r.inputs);
    return 0;
}
