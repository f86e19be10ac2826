"""The FMUs' native binary: a loader that lets hosts without Python run the FMU (host side; never
bundled into an FMU), for the FMI 2.0 FMUs (pythonfmu) and the FMI 3.0 DK FMU (pythonfmu3).

pythonfmu's wrapper library calls the Python C API but is not linked against libpython, so only a
process that already has Python can load it; a C host fails with ``undefined symbol:
_Py_NoneStruct``.  :func:`loader_entries` turns pythonfmu's binary entries of an FMU archive into

- ``binaries/linux64/<modelIdentifier>.so``: the loader, the C files of ``fmu_src/loader/``
  (:data:`LOADER_FILES`) compiled with the system C compiler (``$CC``, else ``cc``, else ``gcc``).
  In the first ``fmi2Instantiate`` it uses the process's Python if it has one (fmpy: no second
  interpreter), else it finds an interpreter that fits the FMU (``$RRR_DK_PYTHON``, the one recorded
  below, ``python3`` on PATH), opens its libpython globally and starts it; it keeps FMI 2.0's state
  table per instance (a forbidden call returns fmi2Error without reaching Python) and forwards
  every allowed fmi2* function to
- ``binaries/linux64/libpythonfmu-export.so``: pythonfmu's wrapper, unchanged;
- ``resources/python_runtime.txt``: ``python=`` the interpreter that built the FMU (its venv and
  site-packages are what the FMU imports) and ``libpython=`` its shared library.  ``$RRR_DK_PYTHON``
  (a path to another python) comes first when it is set.

The FMI 3.0 DK FMU (:mod:`cosim.fmus.fmi3_build`, ``loader_entries(..., fmi=3)``) gets the same three
entries for pythonfmu3: ``binaries/x86_64-linux/<modelIdentifier>.so``, the FMI 3.0 loader
(:data:`LOADER3_FILES`: ``fmi3_loader.c``, ``fmi3_states.c`` and the files the two loaders share,
``loader_common.c`` and ``python_runtime.c``; FMI 3.0's Co-Simulation state table per instance),
``binaries/x86_64-linux/libpythonfmu3-export.so`` (pythonfmu3's wrapper, unchanged) and the same
``resources/python_runtime.txt``.

Without a C compiler, or on a platform other than Linux, the entries stay pythonfmu's (the FMU runs
in Python hosts only) and :func:`loader_entries` says so with a warning.

Platforms.  pythonfmu ships its wrapper for linux64 and win64.  The loader is built and tested for
linux64 only (no Windows toolchain here), and pythonfmu's win64 binary alone was never run with these
FMUs, so on Linux :func:`loader_entries` keeps the binaries of ``linux64`` only (:data:`PLATFORMS`):
an FMU lists only a platform its tests ran on (``tests/test_host_life.py`` checks it).  The compile is
deterministic (fixed flags, no debug info, stripped, run in a folder of fixed name), so builds stay
byte-identical.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Mapping

from .sources import LOADER_SOURCE

__all__ = ["LOADER_SOURCE", "LOADER_FILES", "LOADER3_FILES", "PLATFORMS", "PLATFORMS3", "WRAPPER_NAME",
           "WRAPPER3_NAME", "RUNTIME_FILE", "PYTHON_ENV", "NativeBuildWarning", "compiler", "compile_loader",
           "runtime_record", "loader_entries"]

_ALL_FILES = tuple(sorted(p for p in LOADER_SOURCE.parent.iterdir() if p.suffix in (".c", ".h")))
#: the FMI 2.0 loader's C sources and headers (``fmu_src/loader/``: ``fmi2_*`` and the shared files;
#: :data:`LOADER_SOURCE` is its main file)
LOADER_FILES = tuple(p for p in _ALL_FILES if not p.name.startswith("fmi3_"))
#: the FMI 3.0 loader's (``fmi3_*`` and the shared files ``loader_common.*``, ``python_runtime.*``)
LOADER3_FILES = tuple(p for p in _ALL_FILES if not p.name.startswith("fmi2_"))
#: the FMI platforms whose binaries an FMU built on Linux keeps (built and run by the tests)
PLATFORMS = ("linux64",)
#: the same for FMI 3.0 (its platform names)
PLATFORMS3 = ("x86_64-linux",)
#: pythonfmu's wrapper inside the FMU, beside the loader (the loader's ``WRAPPER_NAME``)
WRAPPER_NAME = "libpythonfmu-export.so"
#: pythonfmu3's wrapper inside an FMI 3.0 FMU, beside its loader (``fmi3_loader.c``'s ``WRAPPER_NAME``)
WRAPPER3_NAME = "libpythonfmu3-export.so"
#: the build-time record of the Python runtime, under resources/ (the loader's ``RUNTIME_FILE``)
RUNTIME_FILE = "python_runtime.txt"
#: the environment variable that names another python at run time (the loader's ``PYTHON_ENV``)
PYTHON_ENV = "RRR_DK_PYTHON"
_FLAGS = ["-std=c11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wno-format-truncation", "-s",
          "-Wl,-Bsymbolic", "-Wl,--build-id=none"]
_LIBS = ["-ldl", "-lpthread"]


class NativeBuildWarning(UserWarning):
    """The FMU keeps pythonfmu's binary (runs in Python hosts only); the message says why."""


def compiler() -> str | None:
    """The C compiler to use: ``$CC``, else ``cc``, else ``gcc`` (None if there is none)."""
    for name in (os.environ.get("CC"), "cc", "gcc"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def compile_loader(cc: str | None = None, files=LOADER_FILES) -> bytes:
    """The loader library, compiled from ``files`` (:data:`LOADER_FILES`: FMI 2.0, :data:`LOADER3_FILES`:
    FMI 3.0); raises RuntimeError with the compiler's message on failure.  Compiled once per process,
    compiler and sources' bytes (the builds of a process share it: the same bytes every build)."""
    cc = cc or compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set $CC or install gcc)")
    return _compiled(cc, tuple((Path(source).name, Path(source).read_bytes()) for source in files))


@lru_cache(maxsize=16)
def _compiled(cc: str, sources: tuple) -> bytes:
    """:func:`compile_loader` of ``sources`` ((name, bytes), ...) with the compiler ``cc``."""
    with tempfile.TemporaryDirectory(prefix="fmu_src_native_") as tmp:
        work = Path(tmp) / "loader"                   # fixed relative names: the same bytes every build
        work.mkdir()
        for name, data in sources:
            (work / name).write_bytes(data)
        c_files = [name for name, _ in sources if name.endswith(".c")]
        proc = subprocess.run([cc, *_FLAGS, "-o", "loader.so", *c_files, *_LIBS], cwd=work,
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{cc} failed on {', '.join(c_files)}:\n{proc.stderr.strip()}")
        return (work / "loader.so").read_bytes()


def runtime_record() -> bytes:
    """``resources/python_runtime.txt`` for the running interpreter (the one that builds the FMU)."""
    libpython = ""
    if sysconfig.get_config_var("Py_ENABLE_SHARED"):
        candidate = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("INSTSONAME") or "")
        libpython = str(candidate) if candidate.is_file() else ""
    return (f"# The Python runtime this FMU's binary starts in a host process without Python "
            f"(${PYTHON_ENV}=/path/to/python comes first; then this one; then python3 on PATH)\n"
            f"python={sys.executable}\nlibpython={libpython}\n").encode()


def loader_entries(entries: Mapping[str, bytes], model: str, fmi: int = 2) -> dict[str, bytes]:
    """``entries`` (an FMU archive: {name: bytes}) with the Linux binary replaced by the loader,
    pythonfmu's wrapper beside it and the runtime record, and on Linux the binaries of
    :data:`PLATFORMS` only; the binaries unchanged (with a :class:`NativeBuildWarning`) where the
    loader cannot be built.  ``fmi=3``: an FMI 3.0 FMU of pythonfmu3 (``x86_64-linux``, its wrapper
    as :data:`WRAPPER3_NAME`, the loader of :data:`LOADER3_FILES`)."""
    platforms, wrapper, files, who = ((PLATFORMS, WRAPPER_NAME, LOADER_FILES, "pythonfmu") if fmi == 2 else
                                      (PLATFORMS3, WRAPPER3_NAME, LOADER3_FILES, "pythonfmu3"))
    binary = f"binaries/{platforms[0]}/{model}.so"
    out = dict(entries)
    if binary not in entries:
        return out
    if sys.platform.startswith("linux"):            # only the platforms that are built and run (module doc)
        out = {name: data for name, data in out.items()
               if not name.startswith("binaries/") or name.split("/")[1] in platforms}
    else:
        warnings.warn(f"{model}: the loader for hosts without Python is built on Linux only; the FMU keeps "
                      f"{who}'s binary", NativeBuildWarning, stacklevel=2)
        return out
    try:
        loader = compile_loader(files=files)
    except (RuntimeError, OSError) as exc:
        warnings.warn(f"{model}: {exc}; the FMU keeps {who}'s binary and runs in Python hosts only "
                      "(fmpy, libcosimpy, ecospy)", NativeBuildWarning, stacklevel=2)
        return out
    out[f"binaries/{platforms[0]}/{wrapper}"] = entries[binary]
    out[binary] = loader
    out[f"resources/{RUNTIME_FILE}"] = runtime_record()
    return out
