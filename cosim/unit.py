"""One FMU instance driven through fmpy's ``FMU2Slave``: the driver of every host-side user.

:class:`FMUUnit` is the one FMU2Slave driver of the project: the co-simulation master
(:mod:`cosim`), the checks (:func:`cosim.fmus.checks.smoke_check`), the tests and the
benchmarks all run FMUs through it (or through fmpy's ``simulate_fmu`` / libcosim, see
:mod:`cosim.simulation` and :mod:`cosim.hosts.libcosim`).

Process rules for pythonfmu FMUs, which this module keeps:

* **Extract once, never unload.**  fmpy's ``freeInstance`` also unloads the FMU's shared library.
  With several pythonfmu FMUs in one process, unloading one of them, or loading a second extracted
  copy of the same FMU, corrupts the heap and the process aborts at exit ("corrupted double-linked
  list", reproduced here).  So every FMU file is extracted once per process (:func:`extracted`),
  its library loaded once and never unloaded; instances are freed (:meth:`FMUUnit.close`).
* **Import hygiene.**  All pythonfmu FMUs of a process share one interpreter: ``sys.modules`` (the
  slave module is imported by name; the first version loaded wins until it is forgotten),
  ``sys.path`` (every instantiation prepends its resources folder and never removes it) and the
  imported packages (a bundled ``solver`` is used only if the host has not imported ``solver`` yet;
  import it first in a host that runs FMUs repeatedly, or numba recompiles it for every fresh
  extraction).  :func:`import_hygiene` restores ``sys.path`` and forgets the modules imported from
  an FMU's folder; every instantiation here runs inside it.
* **Exit.**  A process that initialized a pythonfmu 0.7 FMU may abort at exit, in the libraries'
  finalizers (reproduced with a plain fmpy script, ``tests/test_exit.py``): :func:`exit_process`
  ends such a process, and only such a process, without the finalizers.
"""
from __future__ import annotations

import atexit
import contextlib
import itertools
import logging
import os
import shutil
import sys
from ctypes import byref
from pathlib import Path

from solver.shared_kernels import serve_from_fmu

__all__ = ["FMUUnit", "InstantiationError", "extracted", "remove_extracted", "fmus_loaded", "exit_process", "import_hygiene",
           "captured_slave_log", "with_slave_log"]

#: FMU files extracted in this process: (path, mtime, size) -> (folder, model description).
_EXTRACTED: dict = {}
#: Model descriptions of extracted folders given by the caller: folder -> model description.
_DESCRIPTIONS: dict = {}
# fmpy's logger proxy (which formats the printf-style messages ctypes cannot) keeps one Python logger
# per process, the last one installed: with a logger per unit, every FMU's messages went to the unit
# made last.  So one logger for all units, which finds the unit by the componentEnvironment the FMU
# passes back (a token per unit).
_UNIT_LOGS: dict[int, list] = {}
_TOKENS = itertools.count(1)
_LOGGER = []


def _shared_logger():
    """The one fmi2 logger callback of every unit (made once): appends ``(status, message)`` to the
    messages of the unit whose token is the componentEnvironment."""
    if not _LOGGER:
        from fmpy.fmi2 import fmi2CallbackLoggerTYPE

        def logger(env, _instance, status, _category, message):
            messages = _UNIT_LOGS.get(env or 0)
            if messages is not None:
                messages.append((int(status), message.decode("utf-8", "replace") if message else ""))
        _LOGGER.append(fmi2CallbackLoggerTYPE(logger))
    return _LOGGER[0]


def extracted(path) -> tuple[str, object]:
    """The folder this process extracted the FMU file ``path`` into (once) and its model description."""
    from fmpy import extract, read_model_description

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such FMU (build it with `python build_fmu.py`)")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _EXTRACTED:
        md = read_model_description(str(path))
        _EXTRACTED[key] = (extract(str(path)), md)
        serve_from_fmu(Path(_EXTRACTED[key][0]) / "resources")   # its kernels serve this process's solver too
    return _EXTRACTED[key]


def remove_extracted() -> None:
    """Delete the folders this process extracted FMUs into (also done at exit)."""
    for folder, _ in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)


atexit.register(remove_extracted)


def fmus_loaded() -> bool:
    """Whether this process has loaded a pythonfmu FMU (see :func:`exit_process`): one of the
    project's FMUs was instantiated here (:func:`fmu_src.requirements.instantiated`; also counts
    FMUs whose library fmpy has unloaded since), or a pythonfmu library is mapped now."""
    from fmu_src.requirements import instantiated

    if instantiated() or _EXTRACTED:
        return True
    try:
        with open("/proc/self/maps") as f:
            return any("/binaries/linux64/" in line for line in f)
    except OSError:
        return False


def exit_process(code: int = 0):
    """End the process with exit status ``code``; without the libraries' finalizers if it loaded FMUs.

    A process that ran pythonfmu 0.7 FMUs may abort after its last statement, while the C runtime
    runs the shared libraries' finalizers (``_dl_fini``): glibc finds the heap corrupted
    ("corrupted double-linked list") when a library's finalizer frees memory (the core dumps show
    libgfortran's ``close_units``, loaded by numpy/scipy), so the corruption happened earlier.
    ``tests/test_exit.py`` reproduces it with a plain fmpy script: it needs an FMU that was
    initialized in the process, its rate depends on the FMU and on timing, and importing
    ``solver`` and ``dynamics`` before the FMUs lowers it without removing it (docs/reliability.md, known
    issues: the counts).  Everything is written by then, but the exit status would say 134.

    If :func:`fmus_loaded`: remove the extracted folders, flush stdout and stderr, and
    ``os._exit(code)`` (no finalizers, no ``atexit`` handlers).  Otherwise a normal exit
    (``SystemExit(code)``).  The project's command lines, its dask workers and its test session
    end this way.
    """
    if not fmus_loaded():
        raise SystemExit(int(code))
    remove_extracted()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream must not change the exit status
            pass
    os._exit(int(code))


@contextlib.contextmanager
def import_hygiene():
    """Undo what loading pythonfmu FMUs does to this process once the block is over.

    pythonfmu's C wrapper prepends the FMU's resources folder to ``sys.path`` at every
    instantiation and never removes it, and the modules the slave imports from there (its own
    module, bundled packages such as ``solver`` if the host had not imported them yet) stay in
    ``sys.modules`` although fmpy/libcosim delete the extracted folder afterwards.  Restore
    ``sys.path`` and forget those modules, so that later imports resolve normally.
    """
    saved = list(sys.path)
    before = set(sys.modules)
    try:
        yield
    finally:
        added = [p for p in set(sys.path) - set(saved) if p and os.path.isabs(p)]
        sys.path[:] = saved
        if added:
            # only the modules imported meanwhile can come from the new folders (string prefixes:
            # a pathlib test over every module of the process cost ~20 ms per instantiation)
            prefixes = tuple(os.path.join(os.path.abspath(p), "") for p in added)
            for name in set(sys.modules) - before:
                origin = getattr(sys.modules.get(name), "__file__", None)
                if origin and os.path.abspath(origin).startswith(prefixes):
                    del sys.modules[name]


@contextlib.contextmanager
def captured_slave_log(strip_traceback: bool = False):
    """Collect the warnings and errors TableSlave instances of this process send to Python logging
    (logger ``fmu_src.<Model>``); ``strip_traceback`` keeps only each message's first part."""
    records: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record):
            try:
                msg = record.getMessage()
            except Exception:  # noqa: BLE001 - a malformed record must not break the run
                return
            records.append(msg.split("\nTraceback", 1)[0] if strip_traceback else msg)

    handler = _Collect(level=logging.WARNING)
    target = logging.getLogger("fmu_src")
    target.addHandler(handler)
    try:
        yield records
    finally:
        target.removeHandler(handler)


def with_slave_log(message: str, records: list[str]) -> str:
    """``message`` followed by the slave log lines ``records`` (if any)."""
    return message + ("\nslave log:\n  " + "\n  ".join(records) if records else "")


class InstantiationError(RuntimeError):
    """fmi2Instantiate failed ("Failed to instantiate model"); ``messages``: what the FMU logged."""

    def __init__(self, message: str, messages: list[tuple[int, str]]):
        super().__init__(message)
        self.messages = messages


class FMUUnit:
    """One FMU instance driven through fmpy's ``FMU2Slave`` (instantiated at construction).

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.
    name : str
        Instance name.
    unzip_dir : str or Path, optional
        A folder the FMU is already extracted into (``fmpy.extract``); default: the one extraction
        of ``path`` in this process (:func:`extracted`).
    logging_on : bool
        fmi2Instantiate's ``loggingOn``: the slave's log messages reach :attr:`messages`.

    Attributes
    ----------
    fmu : fmpy.fmi2.FMU2Slave
        The instance, for the FMI calls of a hot loop (``fmu.setReal``, ``fmu.fmi2DoStep``...).
    md : fmpy model description; ``vars``: name -> its ScalarVariable.
    messages : list of (int, str)
        What the FMU logged: (fmi2Status, text).
    """

    def __init__(self, path, name: str = "unit", unzip_dir=None, logging_on: bool = False):
        from fmpy.fmi2 import FMU2Slave

        self.path = Path(path)
        if unzip_dir is None:
            folder, self.md = extracted(self.path)
        else:
            folder = str(unzip_dir)
            if folder not in _DESCRIPTIONS:
                from fmpy import read_model_description

                _DESCRIPTIONS[folder] = read_model_description(folder)
                serve_from_fmu(Path(folder) / "resources")
            self.md = _DESCRIPTIONS[folder]
        self.unzip_dir = folder
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.messages: list[tuple[int, str]] = []
        self._callbacks = self._make_callbacks()
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=folder,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self._logging_on = logging_on
        self.name = name
        self._instantiate()

    def _make_callbacks(self):
        """This unit's callbacks: the shared logger (:func:`_shared_logger`) with this unit's token as the
        componentEnvironment, which every FMU passes back to its logger."""
        import fmpy
        from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions
        from fmpy.logging import addLoggerProxy

        token = self._log_token = next(_TOKENS)
        _UNIT_LOGS[token] = self.messages
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = _shared_logger()
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        callbacks.componentEnvironment = token
        addLoggerProxy(byref(callbacks))          # formats the printf-style message
        return callbacks

    def _instantiate(self):
        """fmi2Instantiate, leaving ``sys.path`` and ``sys.modules`` as they were.

        pythonfmu's wrapper puts the FMU's resources folder first on ``sys.path`` and imports the
        slave module by name at every instantiation; left there, a later FMU with a module of the
        same name (another build of it) would get this one.  The live instance keeps what it uses.
        """
        with import_hygiene():
            try:
                self.fmu.instantiate(callbacks=self._callbacks, loggingOn=self._logging_on)
            except Exception as exc:  # fmpy: "Failed to instantiate model" (fmi2Instantiate returned NULL)
                raise InstantiationError(with_slave_log(f"{self.name}: {exc} {self.path.name}",
                                                        [m for _, m in self.messages]), self.messages) from None

    def vr(self, *names) -> list[int]:
        """Value references of ``names`` (looked up once by the caller)."""
        try:
            return [self.vars[n].valueReference for n in names]
        except KeyError as exc:
            raise KeyError(f"{self.name}: no variable {exc.args[0]!r} in {self.path.name}") from None

    def vr_array(self, *names):
        """The value references of ``names`` as a ctypes ``fmi2ValueReference`` array, for the fmi2Get*/
        fmi2Set* calls of a hot loop (made once, before the loop)."""
        from fmpy.fmi2 import fmi2ValueReference

        return (fmi2ValueReference * len(names))(*self.vr(*names))

    def initialize(self, t0: float = 0.0, start_values: dict | None = None) -> None:
        """setupExperiment, enterInitializationMode, start values, exitInitializationMode."""
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        self.set_values(start_values or {})
        self.fmu.exitInitializationMode()

    def set_values(self, values: dict) -> None:
        """Set variables of any type by name (initialization, tests; not the hot path)."""
        for name, value in values.items():
            v = self.vars[name]
            if v.type == "Real":
                self.fmu.setReal([v.valueReference], [float(value)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            elif v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            else:
                raise TypeError(f"{self.name}.{name}: unsupported type {v.type}")

    def get_values(self, names) -> list:
        """Values of variables of any type by name, in the order of ``names`` (one get per type)."""
        getters = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger, "Boolean": self.fmu.getBoolean,
                   "String": self.fmu.getString}
        by_type: dict[str, list[int]] = {}
        for i, name in enumerate(names):
            by_type.setdefault(self.vars[name].type, []).append(i)
        out = [None] * len(names)
        for kind, where in by_type.items():
            for i, value in zip(where, getters[kind]([self.vars[names[i]].valueReference for i in where])):
                out[i] = value
        return out

    def errors(self, least: int = 2) -> list[str]:
        """The logged messages of status ``least`` or worse (default fmi2Discard)."""
        return [m for s, m in self.messages if s >= least]

    def reset(self) -> None:
        """Back to the state after instantiation (then :meth:`initialize` again).

        Done by fmi2FreeInstance + fmi2Instantiate from the already loaded library, not by
        fmi2Reset: with our pythonfmu 0.7 FMUs, three or more fmi2Reset calls in one process leave
        the heap corrupted and the process aborts at exit (reproduced; a fresh instance does not).
        """
        self.fmu.fmi2FreeInstance(self.fmu.component)
        self._instantiate()

    def close(self) -> None:
        """fmi2Terminate and fmi2FreeInstance; the shared library stays loaded (module docstring)."""
        if self.fmu is None:
            return
        try:
            self.fmu.terminate()
        except Exception:  # noqa: BLE001 - terminate after an error may be refused; free anyway
            pass
        self.fmu.fmi2FreeInstance(self.fmu.component)
        self.fmu = None
        _UNIT_LOGS.pop(self._log_token, None)               # this unit's log is its own list now

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
