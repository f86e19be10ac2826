"""The compiled kernels an FMU ships (host side, build time; the runtime half is :mod:`fmu_src.kernel_cache`).

``build_fmu(..., kernels=warm_up(scenario))`` (:mod:`cosim.fmus.packaging`) builds the FMU, hands
it to :func:`shipped_kernels` and builds it again with the entries returned:

1. a child process (no project package imported, ``PYTHONPATH`` dropped: the FMU runs its bundled
   copies, as in a host without them) with ``NUMBA_CPU_NAME=generic`` (machine code for any
   x86-64 CPU, no CPU features) and ``NUMBA_CACHE_DIR`` = :func:`generic_root` extracts the FMU
   and runs it through fmpy along the runs of a :class:`Scenario` (instantiate, initialize, the
   steps; its reference run, so every kernel its slave calls on that path is compiled);
2. the child's numba cache of the FMU's key (``<generic root>/<model>/<key>/``, :func:`fmu_src.kernel_cache.
   bundle_key`) becomes ``resources/kernels/`` with ``resources/kernels/manifest.json``: numba and
   Python versions, machine, key, and the compile seconds of each outermost kernel (what the
   runtime quotes when it must compile one after all);
3. ``files.json`` beside them: the SHA-256 of each bundled file of the key, so that a process that runs
   its own ``solver`` and ``dynamics`` (``python -m cosim``, batch workers) loads these generic kernels
   instead of compiling them again while its files are the same (:mod:`solver.shared_kernels`);
4. the scenario's runs become ``resources/kernel_runs.json`` (:data:`fmu_src.kernel_warmup.RUNS`): a host
   whose process cannot use the shipped kernels (another numba or Python) replays them in a child
   process of its own interpreter, which compiles the kernels for it (:mod:`fmu_src.kernel_warmup`).

The generic cache lives under the project's cache root (``cache_dir("fmu-kernels-generic")``), one
folder per model (an FMU ships its own kernels, not those another FMU of the same code warmed up;
except that a new folder of one of the DK FMUs, which run the same step, starts as a copy of another
DK's folder of the same code, :func:`seed`), keyed by the bundled code: a rebuild of unchanged code
compiles nothing (the child loads every kernel) and ships the same bytes, and FMUs of one code that
differ only in start values (the DK FMU's posture and mode) share it.  Beside it, ``warm-up.json`` keeps the compile seconds measured
when each kernel was first compiled (a rebuild quotes them unchanged) and which scenarios (with the
numba and Python versions) were run: a rebuild of the same code and scenario starts no child at all.
A record without compile seconds (its kernels were in the cache before any child timed them) runs
the child again, and keeps that run's whole time as the estimate (:data:`WHOLE_RUN`).
The shipped bytes are those of the generic cache, so a build is byte-identical to the previous one
while that cache is kept; numba writes object addresses and closure hashes into its cache files,
so a fresh generic cache gives the same kernels in other bytes.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numba

from fmu_src.kernel_cache import GENERIC_CPU, MANIFEST, SHIPPED, kernel_files, key_of
from fmu_src.kernel_warmup import IN_PROCESS, RUNS
from solver import cache_dir, progress
from solver.shared_kernels import FILES as SHARED_FILES

try:
    import fcntl                        # POSIX: builds of one user wait for each other's warm-up
except ImportError:                     # pragma: no cover - Windows: no lock
    fcntl = None

__all__ = ["Run", "Scenario", "generic_root", "fmu_key", "shipped_kernels", "warm_up", "is_warmed", "has_record",
           "record_seconds", "warm_up_base", "generic_env", "seed", "KernelBuildError"]

_KEPT = "warm-up.json"

#: the child: runs the FMU (argv: FMU, scenario JSON, extraction folder) and prints what it compiled
_CHILD = r"""
import json, os, sys, time
from numba.core import event

SECONDS, DEPTH = {}, [0, 0.0]
class Outermost(event.Listener):
    def on_start(self, ev):
        if DEPTH[0] == 0:
            DEPTH[1] = time.perf_counter()
        DEPTH[0] += 1
    def on_end(self, ev):
        DEPTH[0] -= 1
        if DEPTH[0] == 0:
            f = ev.data["dispatcher"].py_func
            name = f"{f.__module__}.{f.__qualname__}"
            SECONDS[name] = SECONDS.get(name, 0.0) + time.perf_counter() - DEPTH[1]
event.register("numba:compile", Outermost())

import numba, numpy as np
from fmpy import extract, simulate_fmu
folder = extract(sys.argv[1], unzipdir=sys.argv[3])
with open(sys.argv[2]) as f:
    runs = json.load(f)
for run in runs:
    names = sorted(run["inputs"])
    table = None
    if names:
        t = np.arange(len(run["inputs"][names[0]])) * run["h"]
        table = np.array(list(zip(t, *(run["inputs"][n] for n in names))),
                         dtype=[("time", np.float64)] + [(n, np.float64, np.shape(run["inputs"][n][0])) for n in names])
    simulate_fmu(folder, stop_time=run["n"] * run["h"], step_size=run["h"], output_interval=run["h"],
                 start_values=run["start"], input=table, fmi_type="CoSimulation")
resources = os.path.join(folder, "resources")
for name in ("solver", "dynamics"):
    module = sys.modules.get(name)
    if module is not None and not os.path.abspath(module.__file__).startswith(resources):
        raise SystemExit(f"the warm-up ran the host's {name} ({module.__file__}), not the FMU's")
cache = sys.modules["fmu_src.kernel_cache"]
print("KERNELS " + json.dumps({"key": cache.bundle_key(resources), "seconds": SECONDS, "numba": numba.__version__,
                               "python": "%d.%d" % sys.version_info[:2]}))
sys.stdout.flush()
os._exit(0)
"""


class KernelBuildError(RuntimeError):
    """The warm-up run of an FMU failed; the message carries its output."""


@dataclass
class Run:
    """One fmpy run of the warm-up: ``n`` steps of ``h`` s, start values, inputs ``{name: n values}`` (a
    value may be a list: an FMI 3.0 array variable)."""

    n: int
    h: float
    start: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        # an array value (an FMI 3.0 variable) is a list of floats, an array input a list of rows
        return {"n": int(self.n), "h": float(self.h),
                "start": {k: (v if isinstance(v, (int, bool)) else float(v) if not isinstance(v, (list, tuple))
                              else [float(x) for x in v]) for k, v in self.start.items()},
                "inputs": {k: [[float(y) for y in x] if isinstance(x, (list, tuple)) else float(x) for x in v]
                           for k, v in self.inputs.items()}}


@dataclass
class Scenario:
    """The runs that call every kernel an FMU's slave uses (its reference run, at least)."""

    runs: list[Run]


#: The end of the name under which a kernel compiled before the warm-up (:mod:`cosim.fmus.early_compile`) has
#: its seconds recorded: a manifest quotes them, a warm-up's estimate of what is left leaves them out.
BESIDE = "(compiled beside the map)"

#: The key of :func:`shipped_kernels`' compile seconds when only the warm-up's whole run was timed.
WHOLE_RUN = "(the whole warm-up run)"


def generic_root() -> Path:
    """Where the warm-up keeps the generic kernels: ``cache_dir("fmu-kernels-generic")``."""
    return cache_dir("fmu-kernels-generic")


def warm_up_base() -> Path:
    """This user's folder (made) of the warm-ups' extraction folders and locks, under the temporary folder."""
    base = Path(tempfile.gettempdir()) / f"rrr-dk-warm-up-{getattr(os, 'getuid', lambda: 0)()}"
    base.mkdir(exist_ok=True)
    return base


def generic_env(root: Path) -> dict:
    """The environment of a child that compiles kernels for the generic CPU into the numba cache ``root``: no
    ``PYTHONPATH`` (it runs the bundled packages), the generic CPU without features, fixed hash seed."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CPU_FEATURES")}
    env.update(NUMBA_CPU_NAME=GENERIC_CPU, NUMBA_CPU_FEATURES="", NUMBA_CACHE_DIR=str(root), PYTHONHASHSEED="0")
    env[IN_PROCESS] = "1"               # this child is where they compile (the FMU would ask for a child of its own)
    return env


@contextlib.contextmanager
def _extraction_folder(fmu: Path):
    """The one folder the warm-up extracts ``fmu`` into (its path ends up in the compiled code: a fixed
    one keeps builds byte-identical), held with a lock against a concurrent build."""
    base = warm_up_base()
    with _locked(base / f"{fmu.stem}.lock"):
        folder = base / fmu.stem
        shutil.rmtree(folder, ignore_errors=True)
        try:
            yield folder
        finally:
            shutil.rmtree(folder, ignore_errors=True)


def _run_child(fmu: Path, scenario: Scenario, root: Path) -> dict:
    env = generic_env(root)
    with tempfile.TemporaryDirectory(prefix="fmu_kernels_") as tmp, _extraction_folder(fmu) as folder:
        runs = Path(tmp) / "runs.json"
        runs.write_text(json.dumps([r.as_json() for r in scenario.runs]))
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(fmu), str(runs), str(folder)],
                              capture_output=True, text=True, env=env, cwd=tmp)
    for line in proc.stdout.splitlines():
        if line.startswith("KERNELS "):
            return json.loads(line[len("KERNELS "):])
    raise KernelBuildError(f"the warm-up run of {fmu.name} failed (exit {proc.returncode}):\n"
                           f"{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")


def _bundled(fmu: Path) -> list[tuple[str, bytes]]:
    """The ``.py`` files of ``fmu``'s ``resources/``: (path relative to resources, bytes)."""
    with zipfile.ZipFile(fmu) as z:
        return [(i.filename[len("resources/"):], z.read(i)) for i in z.infolist()
                if i.filename.startswith("resources/") and i.filename.endswith(".py")]


def fmu_key(fmu: Path) -> str:
    """The kernel key of the FMU file ``fmu`` (:func:`fmu_src.kernel_cache.key_of` of its ``resources/``)."""
    return key_of(_bundled(Path(fmu)))


def _record_files(bundled: list, folder: Path) -> None:
    """``folder/files.json``: the SHA-256 of each file of the kernel packages an FMU bundles (``bundled``, as
    :func:`_bundled`; the files of its key), which a process running its own packages checks before it
    loads kernels from ``folder`` (:mod:`solver.shared_kernels`: kernels compiled once)."""
    files = {name: hashlib.sha256(data).hexdigest() for name, data in kernel_files(bundled)}
    text = json.dumps(files, indent=1, sort_keys=True) + "\n"
    path = folder / SHARED_FILES
    if not path.is_file() or path.read_text() != text:
        tmp = path.with_suffix(".tmp")
        tmp.write_text(text)
        os.replace(tmp, path)


def _warmed(scenario: Scenario) -> str:
    """What a warm-up of ``scenario`` compiles for: its runs, numba, Python, the generic CPU (a digest)."""
    text = json.dumps([[r.as_json() for r in scenario.runs], numba.__version__, sys.version_info[:2], GENERIC_CPU])
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def has_record(folder: Path) -> bool:
    """Whether the store folder ``folder`` holds a record (``warm-up.json``): a warm-up, an early compile or a
    seed wrote its kernels' compile seconds there."""
    return (Path(folder) / _KEPT).is_file()


def is_warmed(folder: Path, scenario: Scenario) -> bool:
    """Whether the store folder ``folder`` (``<root>/<model>/<key>``) has been warmed up along ``scenario``
    with this numba and Python (its ``warm-up.json``): a build of that key would start no child."""
    record = _readable_record(Path(folder))
    return _warmed(scenario) in record["warmed"] and bool(record["seconds"])


def _readable_record(folder: Path) -> dict:
    """The store folder's ``warm-up.json`` as ``{"seconds": {...}, "warmed": [...]}``; empty when missing or
    unreadable."""
    try:
        record = json.loads((folder / _KEPT).read_text())
    except (OSError, ValueError):
        record = None
    if not isinstance(record, dict):
        record = {}
    return {**record, "seconds": dict(record.get("seconds") or {}), "warmed": list(record.get("warmed") or [])}


def record_seconds(folder: Path, seconds: dict) -> None:
    """Add ``{kernel: compile seconds}`` measured outside the warm-up (:mod:`cosim.fmus.early_compile`) to the
    record of the store folder ``folder``, as the warm-up's own (the manifest then quotes them).  A kernel
    already recorded keeps the longer time: a later run that found it compiled loads it in a second."""
    folder = Path(folder)
    with _locked(folder / ".lock"):
        record = _readable_record(folder)
        for k, v in seconds.items():
            record["seconds"][k] = max(round(float(v), 1), record["seconds"].get(k, 0.0))
        (folder / _KEPT).write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")


def shipped_kernels(fmu: Path, scenario: Scenario, root: Path | None = None, model: str | None = None,
                    seeds: tuple = ()) -> dict[str, bytes]:
    """The entries ``{"resources/kernels/...": bytes}`` of the kernels ``fmu`` calls along ``scenario``,
    compiled for a generic CPU, and their manifest (the module docstring).

    ``root``: the generic kernel cache (default :func:`generic_root`).  The child runs only when
    this key has not been warmed up along this scenario, numba and Python before (``warm-up.json``).
    ``model``: the store folder's model name (default: the FMU file's stem).  ``seeds``: models whose
    store folder of the same key seeds this one when it holds no kernel yet (:func:`seed`).
    """
    root = Path(root) if root is not None else generic_root()
    store = root / (model or Path(fmu).stem)    # one FMU's kernels only
    bundled = _bundled(Path(fmu))
    key, done = key_of(bundled), _warmed(scenario)
    folder = store / key
    folder.mkdir(parents=True, exist_ok=True)
    with _locked(folder / ".lock"):             # builds in parallel (batch workers): one warms up, the others wait
        seed(folder, [root / m / key for m in seeds])
        entries = _warmed_entries(fmu, scenario, store, folder, key, done)
        _record_files(bundled, folder)
        return entries


def seed(folder: Path, sources: list) -> str | None:
    """Copy into the store folder ``folder`` (held locked, holding no kernel yet) the kernels of the first of
    ``sources`` (store folders of the same key, other models) that holds any; the source's model, or None.

    FMUs of one code share most kernels (the 3-RRR's FMI 2.0 and 3.0 DK FMUs and the 3-RPR's DK FMU
    call the same tracker step and its C entry point): the second FMU's warm-up then loads them instead
    of compiling them again (minutes), and compiles only its own.  The folder stays this model's: it
    ships what was seeded and what its runs added, and a rebuild ships the same bytes.

    Best effort: a source whose warm-up writes it now is skipped (not waited for: two builds seeding each
    other never deadlock), an error copies nothing usable and the warm-up compiles, as without a seed.
    Each file is written under a temporary name and renamed, the data files before the indexes and the
    record last, so a build killed halfway leaves no truncated index (numba raises on one) and no record."""
    try:
        if any(folder.rglob("*.nbi")):
            return None
        for source in sources:
            if source == folder or not has_record(source):
                continue
            with _locked(source / ".lock", wait=False, shared=True) as free:
                if not free:                    # that model's warm-up writes it now: not complete
                    continue
                files = sorted((p for p in source.rglob("*") if p.suffix in (".nbi", ".nbc")),
                               key=lambda p: (p.suffix == ".nbi", str(p)))
                for p in files:
                    _write_atomically(folder / p.relative_to(source), p.read_bytes())
                seconds = _readable_record(source)["seconds"]
            if files:                           # and their compile seconds: a host that must compile is told them
                record = {"seconds": seconds, "warmed": [], "seeded_from": source.parent.name}
                _write_atomically(folder / _KEPT, (json.dumps(record, indent=1, sort_keys=True) + "\n").encode())
                return source.parent.name
    except OSError as e:
        progress.note(f"{folder.parent.name}: its kernels were not seeded from another DK's ({e}); its warm-up "
                      "compiles them")
    return None


def _write_atomically(dst: Path, data: bytes) -> None:
    """``data`` written to ``dst`` (its folder made) under a temporary name, then renamed into place."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(dst.name + f".seed-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, dst)


@contextlib.contextmanager
def _locked(path: Path, wait: bool = True, shared: bool = False):
    """An exclusive lock on the file ``path`` (created), held for the ``with`` block (none without fcntl); it
    yields True, or with ``wait=False`` False at once when another process holds it.  ``shared``: a
    reader's lock (readers share it; a writer's exclusive lock excludes them)."""
    with open(path, "a") as f:
        if fcntl is not None:
            mode = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | (0 if wait else fcntl.LOCK_NB)
            try:
                fcntl.flock(f, mode)            # released when f closes
            except BlockingIOError:
                yield False
                return
        yield True


def _warmed_entries(fmu, scenario, root, folder, key, done) -> dict[str, bytes]:
    """:func:`shipped_kernels` for the kernel folder ``folder`` (held locked)."""
    kept = folder / _KEPT
    record = json.loads(kept.read_text()) if kept.is_file() else {"seconds": {}, "warmed": []}
    if done not in record["warmed"] or not record["seconds"]:
        total = sum(v for k, v in record["seconds"].items() if not k.endswith(BESIDE))  # what is left to compile
        if record.get("seeded_from") and not record["warmed"]:
            hint = f"most of them from {record['seeded_from']}'s compile of the same code: seconds"
        else:
            hint = f"about {total:.0f} s" if total else "a first build: up to a few minutes, once per code"
        with progress.phase(f"compiling the kernels {Path(fmu).stem} ships (generic x86-64 CPU)", hint):
            start = time.perf_counter()
            found = _run_child(Path(fmu), scenario, root)
            run = time.perf_counter() - start
        if found["key"] != key:
            raise KernelBuildError(f"{Path(fmu).name}: the warm-up ran key {found['key']}, the FMU's is {key}")
        record["seconds"].update({k: round(v, 1) for k, v in found["seconds"].items()})
        if not record["seconds"]:           # no compile reached the child's listener (the kernels were there):
            record["seconds"][WHOLE_RUN] = round(run, 1)    # the whole warm-up run, an upper bound
        record["warmed"] = sorted({*record["warmed"], done})
        kept.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    entries = {f"resources/{SHIPPED}/{p.relative_to(folder).as_posix()}": p.read_bytes()
               for p in sorted(folder.rglob("*")) if p.suffix in (".nbi", ".nbc")}
    if not entries:
        raise KernelBuildError(f"the warm-up run of {Path(fmu).name} compiled no kernel into {folder}")
    seconds = record["seconds"]
    manifest = {"numba": numba.__version__, "python": "%d.%d" % sys.version_info[:2], "cpu": GENERIC_CPU,
                "machine": platform.machine().lower(), "key": key, "seconds": seconds,
                "total_seconds": round(sum(seconds.values()), 1)}
    entries[f"resources/{SHIPPED}/{MANIFEST}"] = (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()
    entries[f"resources/{RUNS}"] = (json.dumps([r.as_json() for r in scenario.runs], sort_keys=True) + "\n").encode()
    return entries


def warm_up(scenario: Scenario, root: Path | None = None, model: str | None = None, seeds: tuple = ()):
    """The ``kernels`` argument of :func:`cosim.fmus.packaging.build_fmu` for ``scenario`` (the other
    arguments: :func:`shipped_kernels`')."""
    return lambda fmu: shipped_kernels(fmu, scenario, root, model, seeds)
