"""Compiling an FMU's kernels in a child process, never on the host's thread (part of the FMU runtime:
standard library only; numba is used only where it is already imported).

Why.  numba's compiler recurses deeply (its inliner deep-copies the IR): on a host thread with a
small C stack (a C++ co-simulation host's worker thread, even a plain Python thread of a few
hundred kB) it overflows and the host dies with a segmentation fault, inside an FMI call.  An FMU
has to compile when the kernels it ships cannot serve the process that runs it
(:func:`fmu_src.kernel_cache.shipped_problem`: another numba or Python, none shipped, other code).

What happens instead (:func:`ensure`, called at instantiation by :class:`fmu_src.table_slave.TableSlave`
when :func:`fmu_src.kernel_cache.attach` says the shipped kernels cannot serve):

1. if this machine already compiled this FMU's kernels (``warm.json`` in the bundle's folder of the
   user cache names this numba, Python and CPU, :func:`machine_stamp`, with the FMU's model and a
   digest of its warm-up runs: FMUs of one code share the folder but call other kernels), nothing;
2. else a child process of the same interpreter (:func:`fmu_src.requirements.interpreter`, the
   host's environment) imports the FMU's own slave from ``resources/`` and replays the runs the
   build warmed the shipped kernels with (``resources/kernel_runs.json``, :data:`RUNS`), which
   compiles every kernel the slave calls into the user cache, for this CPU; its progress (one
   line per kernel, ``compiling ...`` / ``compiled ... in N s``) goes to the host's logger
   (through the instance's log) and to the Python logger ``fmu_src.<Model>`` as it comes;
3. the host process then loads those kernels from the cache (numba's own cache, the bundle's
   locator of :mod:`fmu_src.kernel_cache`): nothing is compiled on the host's thread.

The build's own warm-up (:mod:`cosim.fmus.kernels`) compiles in process: its child sets
:data:`IN_PROCESS`.  Processes that need the same kernels at once wait for each other (a file lock beside
``warm.json``): one child compiles, the others load.  If the child fails (no interpreter that runs,
an import error, a compile error), :class:`KernelCompileError` carries its exit status and the end
of its output; the slave's constructor raises it, so the instantiation fails with the reason on the
host's logger (FMI's fmi2Instantiate has no status: it returns NULL) and the host lives on.

Runs (:data:`RUNS`): a list of ``{"n", "h", "start": {name: value}, "inputs": {name: [n values]}}``
in the FMU's variable names (an FMI 3.0 array variable takes a list per value): the start values
are set, initialization entered and left, then ``n`` steps of ``h`` s with the inputs of step k at
``t = k h``, every output read in between, as fmpy's ``simulate_fmu`` does at build time.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque

from .kernel_cache import BUNDLE_MARK, _scratch_root, _send, bundle_key, cache_root, manifest

try:
    import fcntl                      # POSIX: one child per machine compiles, the others wait
except ImportError:                   # pragma: no cover - Windows
    fcntl = None

__all__ = ["RUNS", "WARM", "IN_PROCESS", "KernelCompileError", "machine_stamp", "is_warm", "ensure", "replay", "main"]

#: the warm-up runs inside an FMU's ``resources/`` (written by the build, :mod:`cosim.fmus.kernels`)
RUNS = "kernel_runs.json"
#: in ``<cache root>/<key>/``: the machines (numba, Python, CPU) this key's kernels are compiled for
WARM = "warm.json"
#: set to "1" in the environment of a process that is itself the compiling child (the build's warm-up,
#: :mod:`cosim.fmus.kernels`, which runs on a main thread with numba's generic CPU)
IN_PROCESS = "RRR_DK_KERNELS_IN_PROCESS"
#: seconds after which a compiling child is stopped (the DK FMU's kernels take 3 minutes on a busy 2-core machine)
CHILD_TIMEOUT = 1800.0
_DONE: set = set()                    # resources folders this process made sure of
_CHILD = ("import sys; sys.path.insert(0, sys.argv[1]); from fmu_src import kernel_warmup; "
          "raise SystemExit(kernel_warmup.main(sys.argv[1:]))")


class KernelCompileError(RuntimeError):
    """The FMU's kernels could not be compiled in a child process; the message says why."""


def machine_stamp() -> dict:
    """What compiled kernels are valid for: numba's version, Python's, numba's target (triple, CPU
    name, CPU features).  numba must be imported (it is, once a slave imported its kernels)."""
    numba = sys.modules["numba"]
    from numba.core.registry import cpu_target

    triple, cpu, features = cpu_target.target_context.codegen().magic_tuple()
    return {"numba": numba.__version__, "python": "%d.%d" % sys.version_info[:2], "triple": triple, "cpu": cpu,
            "features": features}


def _key_folder(root: str, resources: str) -> str:
    return os.path.join(root, bundle_key(resources))


def _stamps(folder: str) -> list:
    try:
        with open(os.path.join(folder, WARM), encoding="utf-8") as f:
            return list(json.load(f).get("machines", []))
    except (OSError, ValueError, AttributeError):
        return []


def _record(resources: str) -> dict:
    """What ``warm.json`` records for the bundle in ``resources`` on this machine: the machine stamp, the
    model and a digest of its warm-up runs (FMUs of one code share a key but call other kernels)."""
    import hashlib

    with open(os.path.join(resources, "slavemodule.txt"), encoding="utf-8") as f:
        model = f.read().strip()
    with open(os.path.join(resources, RUNS), "rb") as f:
        runs = hashlib.sha256(f.read()).hexdigest()[:16]
    return {**machine_stamp(), "model": model, "runs": runs}


def is_warm(resources: str, root: str | None = None) -> bool:
    """Whether this machine compiled the kernels of the FMU in ``resources`` (its model and warm-up runs)
    into the cache ``root``."""
    if "numba" not in sys.modules or not os.path.isfile(os.path.join(resources, RUNS)):
        return False
    return _record(resources) in _stamps(_key_folder(str(root or cache_root()), resources))


def _writable_root() -> str:
    """The cache root the child writes and the host reads (the locator's: the user cache, else this
    process's own folder under the temporary folder)."""
    root = str(cache_root())
    try:
        os.makedirs(root, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=root, prefix=".probe-", delete=True)
        probe.close()
        return root
    except OSError:
        return _scratch_root()


def ensure(slave, resources: str, problem: str) -> None:
    """Make sure the kernels of the FMU in ``resources`` are compiled for this process, compiling them
    in a child process if they are not (module docstring); ``problem``: why the shipped ones do not
    serve.  Raises :class:`KernelCompileError`."""
    if resources in _DONE or os.environ.get(IN_PROCESS) == "1":
        return
    # an instance an FMI host made (pythonfmu passes a logger) of an FMU's resources folder; one made in
    # process (tests, the compiling child itself) compiles where it is
    if not getattr(slave, "_fmi_strict", True) or not os.path.isfile(os.path.join(resources, BUNDLE_MARK)):
        return
    try:
        if not os.path.isfile(os.path.join(resources, RUNS)):
            raise KernelCompileError(f"{type(slave).__name__}: {problem}, and the FMU carries no warm-up runs "
                                     f"(resources/{RUNS}) to compile them with: rebuild the FMU")
        import numba  # noqa: F401 - a slave may import its kernels in setup(), after this; no compile here

        root = _writable_root()
        folder = _key_folder(root, resources)
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, ".warm.lock"), "a") as lock:
            if fcntl is not None:
                fcntl.flock(lock, fcntl.LOCK_EX)
            if _record(resources) not in _stamps(folder):
                _compile_in_child(slave, resources, root, problem)
    except KernelCompileError as exc:
        _fail(slave, str(exc))
        raise
    except Exception as exc:  # noqa: BLE001 - a cache that cannot be written, a child that cannot be waited for
        msg = f"{type(slave).__name__}: {problem}; compiling them in a child process failed: {type(exc).__name__}: {exc}"
        _fail(slave, msg)
        raise KernelCompileError(msg) from exc
    _DONE.add(resources)


def _fail(slave, msg: str) -> None:
    """The reason an instantiation fails, on the Python logger (stderr) and the instance's log (error)."""
    import logging

    logging.getLogger(f"fmu_src.{type(slave).__name__}").error("%s", msg)
    try:
        from pythonfmu.enums import Fmi2Status      # the slave is a table slave (an FMI 3.0 FMU's core too)

        slave.log(msg.replace("%", "%%"), Fmi2Status.error)
    except Exception:  # noqa: BLE001 - a log must never hide the reason raised
        pass


def _compile_in_child(slave, resources: str, root: str, problem: str) -> None:
    from .requirements import interpreter

    name = type(slave).__name__
    python = interpreter()
    if not python:
        raise KernelCompileError(f"{name}: {problem}; no Python executable of this interpreter "
                                 f"(sys.executable {sys.executable!r}, prefix {sys.prefix}) to compile them in")
    total = manifest(resources).get("total_seconds")
    about = f"about {max(1, round(total))} s" if total else "a few minutes"
    _send(slave, resources, f"{name}: {problem}: compiling them in a child process ({python}), {about}, "
                            f"once for this machine (kept in {root})")
    env = dict(os.environ, NUMBA_CACHE_DIR=root)
    start = time.perf_counter()
    try:
        proc = subprocess.Popen([python, "-c", _CHILD, resources], cwd=resources, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace")
    except OSError as exc:
        raise KernelCompileError(f"{name}: {problem}; the child process {python} did not start: {exc}") from exc
    tail: deque = deque(maxlen=30)
    out: list = []
    reader = threading.Thread(target=lambda: out.extend(proc.stdout), daemon=True)
    reader.start()
    watchdog = threading.Timer(CHILD_TIMEOUT, proc.kill)   # a hung child must not hold the host for ever
    watchdog.daemon = True
    watchdog.start()
    try:
        for line in proc.stderr:
            line = line.rstrip()
            if line.startswith(("compiling ", "compiled ")):
                _send(slave, resources, f"{name}: {line}")
            elif line:
                tail.append(line)
        status = proc.wait()
    finally:
        watchdog.cancel()
    reader.join()
    seconds = time.perf_counter() - start
    if seconds >= CHILD_TIMEOUT:
        tail.append(f"(stopped after {CHILD_TIMEOUT:.0f} s)")
    if status != 0 or not any(o.startswith("WARM ") for o in out):
        text = "\n".join([*tail, *(o.rstrip() for o in out[-10:])])
        raise KernelCompileError(f"{name}: {problem}; compiling them in a child process ({python}) failed "
                                 f"(exit status {status}) after {seconds:.1f} s:\n{text}")
    _send(slave, resources, f"{name}: kernels compiled in a child process in {seconds:.1f} s")


# ---------------------------------------------------------------------- the child's side
def _assign(target, names: dict, name: str, value) -> None:
    """Set the FMU variable ``name`` (a core variable, or an FMI 3.0 row of several) of ``target``."""
    cores = names.get(name, (name,))
    values = value if isinstance(value, (list, tuple)) else [value]
    if len(values) != len(cores):
        raise ValueError(f"{RUNS}: {name!r} takes {len(cores)} values, got {value!r}")
    table = {v.name: v for v in target._table}
    for core, v in zip(cores, values):
        if core not in table:
            raise ValueError(f"{RUNS}: {type(target).__name__} has no variable {core!r}")
        var = table[core]
        setattr(target, var.attr, {"Real": float, "Integer": int, "Boolean": bool}[var.type](v))
        target._dirty = True


def _read_outputs(target) -> None:
    """Every output, as a host reads them (refreshes direct feedthrough)."""
    for kind, get in (("Real", target.get_real), ("Integer", target.get_integer), ("Boolean", target.get_boolean)):
        vrs = [vr for vr, v in enumerate(target._table) if v.is_output and v.type == kind]
        if vrs:
            get(vrs)


def replay(cls, resources: str, runs: list) -> None:
    """Run the slave class ``cls`` (a table slave, or an FMI 3.0 adapter: its core) along ``runs``
    (module docstring), in process, without an FMI host."""
    core = getattr(cls, "CORE", None) or cls
    names = {r.name: tuple(r.core) for r in getattr(cls, "ROWS", ()) if r.core}
    before = os.environ.get("RRR_DK_FAST_LANE")
    os.environ["RRR_DK_FAST_LANE"] = "warm-up"      # the slaves make their fast lanes: their steps compiled here
    try:
        _replay_runs(cls, core, names, resources, runs)
    finally:
        if before is None:
            os.environ.pop("RRR_DK_FAST_LANE", None)
        else:
            os.environ["RRR_DK_FAST_LANE"] = before


def _replay_runs(cls, core, names: dict, resources: str, runs: list) -> None:
    """:func:`replay`'s runs (``core``: the table slave class of ``cls``; ``names``: FMI 3.0 rows -> core variables)."""
    for run in runs:
        target = core(instance_name="kernel-warm-up", resources=resources)
        for name, value in getattr(cls, "START", {}).items():
            _assign(target, {}, name, value)
        for name, value in run["start"].items():
            _assign(target, names, name, value)
        target.setup_experiment(0.0)
        target.enter_initialization_mode()
        inputs = run["inputs"]
        for name, values in inputs.items():
            _assign(target, names, name, values[0])
        _read_outputs(target)
        target.exit_initialization_mode()
        h = float(run["h"])
        for k in range(int(run["n"])):
            for name, values in inputs.items():
                _assign(target, names, name, values[min(k, len(values) - 1)])
            if not target.do_step(k * h, h):
                raise RuntimeError(f"warm-up step {k} refused: {target.last_refusal}")
            _read_outputs(target)


def _listen() -> None:
    """Print one line per outermost numba compilation to stderr (the host relays them)."""
    from numba.core import event

    depth = [0, 0.0]

    class Outermost(event.Listener):
        def on_start(self, ev):
            if depth[0] == 0:
                depth[1] = time.perf_counter()
                f = ev.data["dispatcher"].py_func
                print(f"compiling {f.__module__}.{f.__qualname__}", file=sys.stderr, flush=True)
            depth[0] += 1

        def on_end(self, ev):
            depth[0] -= 1
            if depth[0] == 0:
                f = ev.data["dispatcher"].py_func
                print(f"compiled {f.__module__}.{f.__qualname__} in {time.perf_counter() - depth[1]:.1f} s",
                      file=sys.stderr, flush=True)

    event.register("numba:compile", Outermost())


def main(argv: list) -> int:
    """The child: ``argv = [resources]``; compiles by :func:`replay`, records the machine in
    ``warm.json``, prints ``WARM {...}``.  Returns the exit status."""
    import importlib

    resources = os.path.abspath(argv[0])
    with open(os.path.join(resources, "slavemodule.txt"), encoding="utf-8") as f:
        model = f.read().strip()
    with open(os.path.join(resources, RUNS), encoding="utf-8") as f:
        runs = json.load(f)
    import logging

    import numba  # noqa: F401 - the listener first: every compile is reported

    _DONE.add(resources)                    # this process is the child: it compiles, it spawns none
    quiet = logging.getLogger("fmu_src")    # the slaves' own messages (announcements, warnings) stay here
    quiet.addHandler(logging.NullHandler())
    quiet.propagate = False

    _listen()
    cls = getattr(importlib.import_module(model), model)
    inside = os.path.join(resources, "")
    for name in ("solver", "dynamics"):
        module = sys.modules.get(name)
        if module is not None and not os.path.abspath(module.__file__).startswith(inside):
            print(f"the warm-up would run another {name} ({module.__file__}), not the FMU's", file=sys.stderr)
            return 3
    start = time.perf_counter()
    replay(cls, resources, runs)
    folder = _key_folder(str(cache_root()), resources)
    os.makedirs(folder, exist_ok=True)
    stamp = _record(resources)
    machines = [m for m in _stamps(folder) if m != stamp] + [stamp]
    tmp = os.path.join(folder, f".{WARM}.{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump({"machines": machines}, f, indent=1, sort_keys=True)
    os.replace(tmp, os.path.join(folder, WARM))
    print("WARM " + json.dumps({"seconds": round(time.perf_counter() - start, 1), "machine": stamp}), flush=True)
    return 0
