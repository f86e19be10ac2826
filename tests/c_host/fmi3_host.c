/*
 * A minimal FMI 3.0 Co-Simulation host in C, libc + libdl only (tests/test_fmu3.py): what a C tool
 * without Python in its process does with the FMI 3.0 DK FMU.
 *
 *   fmi3_host <unzipped FMU folder> <modelIdentifier> <instantiationToken> <q vr> <pose vr> <steps> <dq>
 *
 * It dlopens binaries/x86_64-linux/<modelIdentifier>.so (stdout "dlopen failed: <reason>" and exit 2
 * if that fails), instantiates (loggingOn; the FMU's messages go to stderr), enters and exits
 * initialization, reads q (Float64[3]), then <steps> times adds <dq> to q[1], sets q, fmi3DoStep
 * (t = k * 1 ms, h = 1 ms); then prints "pose <x> <y> <phi>" (%.17g) and exits 0; 1 on an FMI error.
 */
#include <dlfcn.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

typedef void* Instance;
typedef void (*Logger)(void*, int, const char*, const char*);
typedef Instance (*InstantiateCS)(const char*, const char*, const char*, bool, bool, bool, bool, const uint32_t*,
                                  size_t, void*, Logger, void*);
typedef int (*Float64Call)(Instance, const uint32_t*, size_t, double*, size_t);
typedef int (*EnterInit)(Instance, bool, double, double, bool, double);
typedef int (*Call)(Instance);
typedef int (*DoStep)(Instance, double, double, bool, bool*, bool*, bool*, double*);

static void logger(void* env, int status, const char* category, const char* message) {
    (void)env;
    fprintf(stderr, "[%d %s] %s\n", status, category ? category : "", message ? message : "");
}

static void* need(void* lib, const char* name) {
    void* f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return f;
}

int main(int argc, char** argv) {
    if (argc != 8) {
        fprintf(stderr, "usage: fmi3_host <folder> <modelIdentifier> <token> <q vr> <pose vr> <steps> <dq>\n");
        return 1;
    }
    char path[4096], resources[4096];
    snprintf(path, sizeof path, "%s/binaries/x86_64-linux/%s.so", argv[1], argv[2]);
    snprintf(resources, sizeof resources, "%s/resources", argv[1]);
    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen failed: %s\n", dlerror());
        return 2;
    }
    InstantiateCS instantiate = (InstantiateCS)need(lib, "fmi3InstantiateCoSimulation");
    Float64Call set = (Float64Call)need(lib, "fmi3SetFloat64"), get = (Float64Call)need(lib, "fmi3GetFloat64");
    EnterInit enter = (EnterInit)need(lib, "fmi3EnterInitializationMode");
    Call exit_init = (Call)need(lib, "fmi3ExitInitializationMode");
    DoStep step = (DoStep)need(lib, "fmi3DoStep");
    Instance c = instantiate("c-host", argv[3], resources, false, true, false, false, NULL, 0, NULL, logger, NULL);
    if (!c) {
        printf("instantiate failed\n");
        return 1;
    }
    uint32_t q_vr = (uint32_t)atoi(argv[4]), pose_vr = (uint32_t)atoi(argv[5]);
    int steps = atoi(argv[6]);
    double dq = atof(argv[7]), q[3], pose[3];
    if (enter(c, false, 0.0, 0.0, false, 0.0) || exit_init(c) || get(c, &q_vr, 1, q, 3)) return 1;
    for (int k = 0; k < steps; k++) {
        bool event, terminate, early;
        double last;
        q[1] += dq;
        if (set(c, &q_vr, 1, q, 3) || step(c, k * 1e-3, 1e-3, true, &event, &terminate, &early, &last)) return 1;
    }
    if (get(c, &pose_vr, 1, pose, 3)) return 1;
    printf("pose %.17g %.17g %.17g\n", pose[0], pose[1], pose[2]);
    return 0;
}
