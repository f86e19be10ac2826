/*
 * The Python runtime of the FMU's loader (python_runtime.c): find an interpreter that fits the FMU
 * and start it in a host process that has no Python.
 */
#ifndef RRR_DK_PYTHON_RUNTIME_H
#define RRR_DK_PYTHON_RUNTIME_H

#include <stddef.h>

#define RUNTIME_FILE "python_runtime.txt"
#define PYTHON_ENV "RRR_DK_PYTHON"

/* Use the process's Python if it has one; else find the first interpreter that fits (module
 * comment of python_runtime.c), open its libpython globally and initialize it.  Returns 0 on
 * success (``note``: "" or a line saying which interpreter was chosen instead of the recorded one),
 * -1 with the reason and the fix in ``error``.  ``binaries``: the folder of the loader; ``model``: the
 * modelIdentifier (named in the fix). */
int start_python(const char* binaries, const char* model, char* error, size_t error_size, char* note,
                 size_t note_size);

#endif
