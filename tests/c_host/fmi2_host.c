/*
 * A minimal FMI 2.0 Co-Simulation host in C, with no Python in its process (tests/test_c_host.py).
 *
 *   fmi2_host <unzipped FMU folder> <modelIdentifier> <guid> <step size> <steps> <inputs file> <output vrs>
 *             <start values>
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
 * t and the outputs (%.17g), then "end".
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

int main(int argc, char** argv)
{
    if (argc != 9) {
        fprintf(stderr, "usage: %s <folder> <modelIdentifier> <guid> <h> <steps> <inputs|-> <output vrs> "
                        "<vr=start,...|->\n", argv[0]);
        return 2;
    }
    const char *folder = argv[1], *model = argv[2], *guid = argv[3];
    double h = atof(argv[4]);
    int steps = atoi(argv[5]);
    fmi2ValueReference in_vr[64], out_vr[64];
    size_t n_in = 0, n_out = parse_vrs(argv[7], out_vr, 64);
    double* inputs = NULL;
    if (strcmp(argv[6], "-") != 0) {
        FILE* f = fopen(argv[6], "r");
        char line[4096];
        if (!f || !fgets(line, sizeof line, f)) { fprintf(stderr, "cannot read %s\n", argv[6]); return 1; }
        n_in = parse_vrs(line, in_vr, 64);
        inputs = calloc((size_t)(steps + 1) * n_in, sizeof(double));
        for (size_t i = 0; i < (size_t)(steps + 1) * n_in; ++i)
            if (fscanf(f, "%lf", &inputs[i]) != 1) { fprintf(stderr, "%s: too few values\n", argv[6]); return 1; }
        fclose(f);
    }

    char path[4096], uri[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", folder, model);
    snprintf(uri, sizeof uri, "file://%s/resources", folder);
    printf("python_before %d\n", has_python());
    double t0 = now();
    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen failed: %s\n", dlerror()); return 1; }

    fmi2Component (*instantiate)(const char*, int, const char*, const char*, const Callbacks*, int, int) =
        symbol(lib, "fmi2Instantiate");
    fmi2Status (*setup)(fmi2Component, int, double, double, int, double) = symbol(lib, "fmi2SetupExperiment");
    fmi2Status (*enter)(fmi2Component) = symbol(lib, "fmi2EnterInitializationMode");
    fmi2Status (*exit_init)(fmi2Component) = symbol(lib, "fmi2ExitInitializationMode");
    fmi2Status (*set_real)(fmi2Component, const fmi2ValueReference*, size_t, const double*) = symbol(lib, "fmi2SetReal");
    fmi2Status (*get_real)(fmi2Component, const fmi2ValueReference*, size_t, double*) = symbol(lib, "fmi2GetReal");
    fmi2Status (*do_step)(fmi2Component, double, double, int) = symbol(lib, "fmi2DoStep");
    fmi2Status (*terminate)(fmi2Component) = symbol(lib, "fmi2Terminate");
    void (*free_instance)(fmi2Component) = symbol(lib, "fmi2FreeInstance");

    static Callbacks callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("c_host", 1 /* fmi2CoSimulation */, guid, uri, &callbacks, 0, 0);
    if (!c) { fprintf(stderr, "fmi2Instantiate returned NULL\n"); return 1; }
    double t1 = now();
    printf("python_after %d\n", has_python());
    if (strcmp(argv[8], "-") != 0) {
        for (char* tok = strtok(argv[8], ","); tok; tok = strtok(NULL, ",")) {
            fmi2ValueReference vr = (fmi2ValueReference)strtoul(tok, NULL, 10);
            char* eq = strchr(tok, '=');
            double v = eq ? strtod(eq + 1, NULL) : 0.0;
            check(set_real(c, &vr, 1, &v), "fmi2SetReal (start value)");
        }
    }
    check(setup(c, 0, 0.0, 0.0, 0, 0.0), "fmi2SetupExperiment");
    check(enter(c), "fmi2EnterInitializationMode");
    if (n_in) check(set_real(c, in_vr, n_in, inputs), "fmi2SetReal");
    check(exit_init(c), "fmi2ExitInitializationMode");
    printf("seconds_instantiate %.3f\nseconds_initialize %.3f\n", t1 - t0, now() - t1);
    double out[64];
    for (int k = 0; k < steps; ++k) {
        double t = k * h;
        if (n_in) check(set_real(c, in_vr, n_in, inputs + (size_t)k * n_in), "fmi2SetReal");
        check(do_step(c, t, h, 1), "fmi2DoStep");
        check(get_real(c, out_vr, n_out, out), "fmi2GetReal");
        printf("%.17g", (k + 1) * h);
        for (size_t i = 0; i < n_out; ++i) printf(" %.17g", out[i]);
        printf("\n");
    }
    check(terminate(c), "fmi2Terminate");
    free_instance(c);
    printf("end\n");
    fflush(stdout);
    free(inputs);
    return 0;
}
