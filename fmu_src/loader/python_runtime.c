/*
 * Interpreter discovery and start-up for the FMUs' loaders (fmi2_loader.c, fmi3_loader.c, through
 * loader_common.c), in a host process that has no Python (a C host: OMSimulator's command line,
 * OpenModelica, Dymola, fmusim, ...).
 *
 * A process that already has an initialized Python (fmpy, libcosimpy, ecospy: Py_IsInitialized is
 * visible globally and true) keeps it: nothing is searched or started, and a missing package is
 * reported by the slave's own check, naming the host's interpreter.
 *
 * Otherwise the candidates, in this order, first that fits wins:
 *   1. $RRR_DK_PYTHON, when set (an explicit choice comes before a guess);
 *   2. the interpreter recorded at build time (resources/python_runtime.txt, "python=");
 *   3. the first python3 on PATH.
 * Each one is run once (a child process, popen) with a short script that prints its
 * sys.executable, its shared libpython (empty for a build without --enable-shared) and every
 * requirement of resources/requirements.txt it does not meet, checked by the FMU's own
 * resources/fmu_src/requirements.py (the check the slave makes at instantiation).  A candidate fits
 * when it runs, has a shared libpython and meets every requirement.  The chosen one's libpython is
 * opened RTLD_GLOBAL, the program name set to the interpreter (so sys.prefix, the venv and its
 * site-packages are its own), Python initialized without signal handlers and the GIL released.
 * Python is never finalized (numpy, numba and scipy cannot be re-initialized in one process).
 * When none fits, the error lists each candidate with why it failed (missing, does not run, no
 * shared libpython, missing packages) and the fix.
 */
#define _GNU_SOURCE
#include "python_runtime.h"

#include <dlfcn.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <wchar.h>

/* argv[1]: the FMU's resources folder.  No single quote inside: the script is quoted with them. */
static const char PROBE[] =
    "import importlib.util as u, os, sys, sysconfig as s\n"
    "print(\"python=\" + sys.executable)\n"
    "p = os.path.join(s.get_config_var(\"LIBDIR\") or \"\", s.get_config_var(\"INSTSONAME\") or \"\")\n"
    "print(\"libpython=\" + (p if s.get_config_var(\"Py_ENABLE_SHARED\") and os.path.isfile(p) else \"\"))\n"
    "r = sys.argv[1]\n"
    "spec = u.spec_from_file_location(\"rrr_dk_requirements\", os.path.join(r, \"fmu_src\", \"requirements.py\"))\n"
    "m = u.module_from_spec(spec)\n"
    "spec.loader.exec_module(m)\n"
    "text = open(os.path.join(r, m.FILE)).read() if os.path.isfile(os.path.join(r, m.FILE)) else \"\"\n"
    "for q, why in m.problems(m.parse_requirements(text)):\n"
    "    print(\"missing=\" + why + \" (the FMU needs \" + q.spec + \")\")\n";

typedef struct {
    char python[PATH_MAX];
    char libpython[PATH_MAX];
} Runtime;

/* append a formatted line to the report (truncated, never overflowing) */
static void add(char* out, size_t size, const char* fmt, ...)
{
    size_t used = strlen(out);
    if (used + 1 >= size) return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(out + used, size - used, fmt, ap);
    va_end(ap);
}

static void strip(char* s)
{
    size_t n = strlen(s);
    while (n && (s[n - 1] == '\n' || s[n - 1] == '\r' || s[n - 1] == ' ')) s[--n] = '\0';
}

/* Run ``python`` with PROBE; 0 if it fits (rt filled), else -1 with the reason in ``why``. */
static int probe(const char* python, const char* resources, Runtime* rt, char* why, size_t size)
{
    why[0] = rt->python[0] = rt->libpython[0] = '\0';
    if (access(python, X_OK) != 0) {
        snprintf(why, size, "missing (no executable file of that name)");
        return -1;
    }
    if (strchr(python, '\'') || strchr(resources, '\'')) {
        snprintf(why, size, "not tried (a single quote in its path or in the FMU's path)");
        return -1;
    }
    char cmd[2 * PATH_MAX + sizeof PROBE + 64];
    snprintf(cmd, sizeof cmd, "'%s' -c '%s' '%s' 2>&1", python, PROBE, resources);
    FILE* f = popen(cmd, "r");
    if (!f) {
        snprintf(why, size, "cannot be run (popen failed)");
        return -1;
    }
    char line[PATH_MAX + 256], missing[2048] = "", other[1024] = "";
    while (fgets(line, sizeof line, f)) {
        strip(line);
        if (!strncmp(line, "python=", 7)) snprintf(rt->python, sizeof rt->python, "%s", line + 7);
        else if (!strncmp(line, "libpython=", 10)) snprintf(rt->libpython, sizeof rt->libpython, "%s", line + 10);
        else if (!strncmp(line, "missing=", 8)) add(missing, sizeof missing, "%s%s", missing[0] ? "; " : "", line + 8);
        else if (line[0]) snprintf(other, sizeof other, "%s", line);   /* the last line of a traceback */
    }
    int status = pclose(f);
    if (status != 0 || !rt->python[0]) {
        snprintf(why, size, "does not run the check (exit status %d%s%s)", status, other[0] ? ": " : "", other);
        return -1;
    }
    if (!rt->libpython[0])
        add(why, size, "no shared libpython (a Python built without --enable-shared)");
    if (missing[0])
        add(why, size, "%smissing packages: %s", why[0] ? "; " : "", missing);
    return why[0] ? -1 : 0;
}

/* the "python=" line of resources/python_runtime.txt, or -1 with the reason */
static int recorded_python(const char* resources, char* python, size_t size, char* why, size_t why_size)
{
    char path[PATH_MAX + 64], line[PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/%s", resources, RUNTIME_FILE);
    FILE* f = fopen(path, "r");
    python[0] = '\0';
    if (!f) {
        snprintf(why, why_size, "cannot read %s (rebuild the FMU)", path);
        return -1;
    }
    while (fgets(line, sizeof line, f)) {
        strip(line);
        if (!strncmp(line, "python=", 7)) snprintf(python, size, "%s", line + 7);
    }
    fclose(f);
    if (!python[0]) snprintf(why, why_size, "%s names no interpreter (rebuild the FMU)", path);
    return python[0] ? 0 : -1;
}

/* the first executable python3 on $PATH, or -1 */
static int python_on_path(char* out, size_t size)
{
    const char* path = getenv("PATH");
    char dirs[8192];
    snprintf(dirs, sizeof dirs, "%s", path ? path : "");
    for (char *save = NULL, *dir = strtok_r(dirs, ":", &save); dir; dir = strtok_r(NULL, ":", &save)) {
        snprintf(out, size, "%s/python3", *dir ? dir : ".");
        if (access(out, X_OK) == 0) return 0;
    }
    out[0] = '\0';
    return -1;
}

/* Open ``rt``'s libpython globally and initialize an interpreter as if ``rt->python`` ran. */
static int initialize(const Runtime* rt, char* error, size_t size)
{
    void* lib = dlopen(rt->libpython, RTLD_NOW | RTLD_GLOBAL | RTLD_NODELETE);
    if (!lib) {
        snprintf(error, size, "cannot open the Python library %s of %s (%s); set $%s to another python",
                 rt->libpython, rt->python, dlerror(), PYTHON_ENV);
        return -1;
    }
    int (*is_initialized)(void) = (int (*)(void))dlsym(lib, "Py_IsInitialized");
    void (*init)(int) = (void (*)(int))dlsym(lib, "Py_InitializeEx");
    void* (*save_thread)(void) = (void* (*)(void))dlsym(lib, "PyEval_SaveThread");
    void (*set_program_name)(const wchar_t*) = (void (*)(const wchar_t*))dlsym(lib, "Py_SetProgramName");
    wchar_t* (*decode)(const char*, size_t*) = (wchar_t* (*)(const char*, size_t*))dlsym(lib, "Py_DecodeLocale");
    if (!is_initialized || !init || !save_thread || !set_program_name || !decode) {
        snprintf(error, size, "%s lacks Py_InitializeEx, PyEval_SaveThread, Py_SetProgramName or "
                 "Py_DecodeLocale (Python 3.8-3.13 has them); set $%s to such a python", rt->libpython, PYTHON_ENV);
        return -1;
    }
    if (is_initialized()) return 0;
    wchar_t* name = decode(rt->python, NULL);  /* stays referenced by the interpreter: never freed */
    if (!name) {
        snprintf(error, size, "cannot decode the interpreter path %s", rt->python);
        return -1;
    }
    set_program_name(name);     /* sys.executable, sys.prefix, the venv: those of that interpreter */
    init(0);                    /* no signal handlers: the host owns SIGINT */
    if (!is_initialized()) {
        snprintf(error, size, "Python (%s, %s) did not initialize", rt->python, rt->libpython);
        return -1;
    }
    save_thread();              /* release the GIL: pythonfmu takes it per call (PyGILState_Ensure) */
    return 0;
}

int start_python(const char* binaries, const char* model, char* error, size_t size, char* note, size_t note_size)
{
    int (*is_initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    error[0] = note[0] = '\0';
    if (is_initialized && is_initialized()) return 0;     /* a Python host: use its interpreter */
    char resources[PATH_MAX], candidate[PATH_MAX], why[4096], tried[6144] = "";
    snprintf(resources, sizeof resources, "%s/../../resources", binaries);
    const char* chosen = getenv(PYTHON_ENV);
    Runtime rt;
    int failures = 0;
    for (int k = 0; k < 3; ++k) {
        const char* label;
        why[0] = '\0';
        if (k == 0) {
            label = "$" PYTHON_ENV;
            if (!chosen || !*chosen) {
                add(tried, sizeof tried, "\n  %s: not set", label);
                continue;
            }
            snprintf(candidate, sizeof candidate, "%s", chosen);
        } else if (k == 1) {
            label = "the interpreter recorded at build time (resources/" RUNTIME_FILE ")";
            if (recorded_python(resources, candidate, sizeof candidate, why, sizeof why)) {
                add(tried, sizeof tried, "\n  %s: %s", label, why);
                ++failures;
                continue;
            }
        } else {
            label = "python3 on PATH";
            if (python_on_path(candidate, sizeof candidate)) {
                add(tried, sizeof tried, "\n  %s: none found", label);
                ++failures;
                continue;
            }
        }
        if (probe(candidate, resources, &rt, why, sizeof why) == 0) {
            if (failures)
                snprintf(note, note_size, "using %s %s; not usable before it:%s", label, rt.python, tried);
            return initialize(&rt, error, size);
        }
        add(tried, sizeof tried, "\n  %s %s: %s", label, candidate, why);
        ++failures;
    }
    char folder[PATH_MAX];
    if (!realpath(resources, folder)) snprintf(folder, sizeof folder, "%s", resources);
    snprintf(error, size, "no Python interpreter fits the FMU %s; tried:%s\nFix: set $%s to a python built "
             "with a shared libpython whose environment has the FMU's requirements (install them with "
             "<that python> -m pip install -r %s/requirements.txt)", model, tried, PYTHON_ENV, folder);
    return -1;
}
