/*
 * An FMI 3.0 Co-Simulation host in C, libc + libdl only (tests/test_c_host3.py): what a C tool without
 * Python in its process does with the FMI 3.0 DK FMU, through a whole life.
 *
 *   fmi3_host <unzipped FMU folder> <modelIdentifier> <instantiationToken> <q vr> <pose vr> <steps> <dq>
 *
 * It dlopens binaries/x86_64-linux/<modelIdentifier>.so (stdout "dlopen failed: <reason>" and exit 2
 * if that fails) and prints "python_before <0|1>" (whether Python's C API was in the process before).
 * Then, logging on (the FMU's messages go to stderr):
 *   life 1: fmi3InstantiateCoSimulation ("python_after <0|1>"), enter/exit initialization, read q
 *     (Float64[3]); <steps> runs of: q[1] += <dq>, set q, fmi3DoStep (t = k h, h = 1 ms), get the pose,
 *     print "a <k> <t> <x> <y> <phi>"; fmi3GetFMUState before step <steps>/2;
 *     then fmi3SetFMUState back to it and the second half again ("b ..."), fmi3FreeFMUState;
 *     fmi3Reset, enter/exit initialization, the same <steps> from the start values ("c ...");
 *     fmi3Terminate, fmi3FreeInstance;
 *   life 2: fmi3InstantiateCoSimulation again, the same run ("d ..."), fmi3Terminate, fmi3FreeInstance.
 * Values %.17g; "end" last; exit 0, or 1 (with the call on stderr) when a call does not return fmi3OK.
 * The test compares the rows to fmpy's FMU3Slave run of the same call sequence, bit for bit.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef void* Instance;
typedef void (*Logger)(void*, int, const char*, const char*);
typedef Instance (*InstantiateCS)(const char*, const char*, const char*, bool, bool, bool, bool, const uint32_t*,
                                  size_t, void*, Logger, void*);
typedef int (*Float64Call)(Instance, const uint32_t*, size_t, double*, size_t);
typedef int (*EnterInit)(Instance, bool, double, double, bool, double);
typedef int (*Call)(Instance);
typedef int (*DoStep)(Instance, double, double, bool, bool*, bool*, bool*, double*);
typedef int (*StateCall)(Instance, void**);
typedef int (*SetState)(Instance, void*);
typedef void (*Free)(Instance);

static struct {
    InstantiateCS instantiate;
    Float64Call set, get;
    EnterInit enter;
    Call exit_init, terminate, reset;
    DoStep step;
    StateCall get_state, free_state;
    SetState set_state;
    Free free;
    const char *token, *resources;
    uint32_t q_vr, pose_vr;
    int steps;
    double dq, h;
} F;

static void logger(void* env, int status, const char* category, const char* message)
{
    (void)env;
    fprintf(stderr, "[%d %s] %s\n", status, category ? category : "", message ? message : "");
}

static void* need(void* lib, const char* name)
{
    void* f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return f;
}

static void check(int status, const char* call)
{
    if (status != 0) {
        fprintf(stderr, "%s returned %d\n", call, status);
        printf("failed %s %d\n", call, status);
        exit(1);
    }
}

static int has_python(void) { return dlsym(RTLD_DEFAULT, "Py_IsInitialized") != NULL; }

static Instance instantiate(const char* name)
{
    Instance c = F.instantiate(name, F.token, F.resources, false, true, false, false, NULL, 0, NULL, logger, NULL);
    if (!c) {
        printf("instantiate failed\n");
        exit(1);
    }
    return c;
}

/* enter and exit initialization at t = 0; q read back (its start value) */
static void initialize(Instance c, double q[3])
{
    check(F.enter(c, false, 0.0, 0.0, false, 0.0), "fmi3EnterInitializationMode");
    check(F.exit_init(c), "fmi3ExitInitializationMode");
    check(F.get(c, &F.q_vr, 1, q, 3), "fmi3GetFloat64(q)");
}

/* steps [from, to) of a run; q holds the input before step ``from``; the state is saved before step ``save`` */
static void run(Instance c, const char* tag, double q[3], int from, int to, int save, void** state, double saved_q[3])
{
    for (int k = from; k < to; ++k) {
        if (k == save) {
            check(F.get_state(c, state), "fmi3GetFMUState");
            memcpy(saved_q, q, 3 * sizeof *q);
        }
        bool event, stop, early;
        double last, pose[3];
        q[1] += F.dq;
        check(F.set(c, &F.q_vr, 1, q, 3), "fmi3SetFloat64(q)");
        check(F.step(c, k * F.h, F.h, false, &event, &stop, &early, &last), "fmi3DoStep");
        if (event || stop || early || last != k * F.h + F.h) {
            printf("failed doStep return arguments %d %d %d %.17g\n", event, stop, early, last);
            exit(1);
        }
        check(F.get(c, &F.pose_vr, 1, pose, 3), "fmi3GetFloat64(pose)");
        printf("%s %d %.17g %.17g %.17g %.17g\n", tag, k, (k + 1) * F.h, pose[0], pose[1], pose[2]);
    }
}

int main(int argc, char** argv)
{
    if (argc != 8) {
        fprintf(stderr, "usage: fmi3_host <folder> <modelIdentifier> <token> <q vr> <pose vr> <steps> <dq>\n");
        return 1;
    }
    char path[4096], resources[4096];
    snprintf(path, sizeof path, "%s/binaries/x86_64-linux/%s.so", argv[1], argv[2]);
    snprintf(resources, sizeof resources, "%s/resources/", argv[1]);
    printf("python_before %d\n", has_python());
    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen failed: %s\n", dlerror());
        return 2;
    }
    F.instantiate = (InstantiateCS)need(lib, "fmi3InstantiateCoSimulation");
    F.set = (Float64Call)need(lib, "fmi3SetFloat64");
    F.get = (Float64Call)need(lib, "fmi3GetFloat64");
    F.enter = (EnterInit)need(lib, "fmi3EnterInitializationMode");
    F.exit_init = (Call)need(lib, "fmi3ExitInitializationMode");
    F.terminate = (Call)need(lib, "fmi3Terminate");
    F.reset = (Call)need(lib, "fmi3Reset");
    F.step = (DoStep)need(lib, "fmi3DoStep");
    F.get_state = (StateCall)need(lib, "fmi3GetFMUState");
    F.free_state = (StateCall)need(lib, "fmi3FreeFMUState");
    F.set_state = (SetState)need(lib, "fmi3SetFMUState");
    F.free = (Free)need(lib, "fmi3FreeInstance");
    F.token = argv[3];
    F.resources = resources;
    F.q_vr = (uint32_t)atoi(argv[4]);
    F.pose_vr = (uint32_t)atoi(argv[5]);
    F.steps = atoi(argv[6]);
    F.dq = atof(argv[7]);
    F.h = 1e-3;
    int half = F.steps / 2;
    double q[3], saved_q[3];
    void* state = NULL;

    Instance c = instantiate("c-host");
    printf("python_after %d\n", has_python());
    initialize(c, q);
    run(c, "a", q, 0, F.steps, half, &state, saved_q);
    check(F.set_state(c, state), "fmi3SetFMUState");
    memcpy(q, saved_q, sizeof q);
    run(c, "b", q, half, F.steps, -1, NULL, NULL);
    check(F.free_state(c, &state), "fmi3FreeFMUState");
    check(F.reset(c), "fmi3Reset");
    initialize(c, q);
    run(c, "c", q, 0, F.steps, -1, NULL, NULL);
    check(F.terminate(c), "fmi3Terminate");
    F.free(c);

    c = instantiate("c-host-2");
    initialize(c, q);
    run(c, "d", q, 0, F.steps, -1, NULL, NULL);
    check(F.terminate(c), "fmi3Terminate");
    F.free(c);
    printf("end\n");
    fflush(stdout);
    return 0;
}
