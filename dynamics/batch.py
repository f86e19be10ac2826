"""Batches of closed-loop co-simulations (Fig. 2) on dask: ``python -m dynamics.batch``.

Sweeps over the fields of :class:`dynamics.cosim.Scenario` (trajectory, gains, communication step,
plant parameter errors, tracker mode, master algorithm, ...); every run is one
:meth:`dynamics.cosim.ClosedLoop.run` of the three FMUs through fmpy.  Results land in one table
(``batch.csv``, ``batch.parquet`` when pyarrow is installed), with ``batch_meta.json`` (FMU hashes,
cluster, timing) and a summary plot ``batch_summary.png``.

Command line
------------
::

    python -m dynamics.batch --sweep h=0.001,0.002 --sweep plant_mass_scale=0.8,1.0,1.2 --t-end 1.0
    python -m dynamics.batch --config bench/sweep_example.toml [--out results/batch]
    python -m dynamics.batch --config sweep.toml --scheduler tcp://10.0.0.5:8786
    python -m dynamics.batch --sweep bandwidth=20:80:4 --set order=jacobi --dry-run

``--sweep KEY=V1,V2,...``  one dimension of the cartesian product (``lo:hi:n``: n values from lo to
                           hi, linspace; ``center=[0.45,0.3],[0.5,0.3]`` for the centre);
``--zip KEY=V1,V2,...``    all ``--zip`` keys vary together (one dimension, equal lengths);
``--set KEY=V``            a fixed value for every run; ``--t-end T`` is ``--set t_end=T``;
``--fmu-dir DIR``          the FMUs (default ``build``; built there by :func:`build_fmus` if
                           missing, ``--resolution 40mm,6deg`` for the DK map of that build);
``--workers N``            local process pool size (default: the cores of this machine);
``--scheduler ADDRESS``    an existing dask.distributed scheduler, used as it is;
``--serial``               no dask: every run in this process, one :class:`ClosedLoop` reused;
``--fmu-transfer MODE``    ``path`` (workers open the files at the client's absolute paths: one
                           machine or a shared file system), ``bytes`` (the client sends the files
                           once to every worker, see below), ``auto`` (default: ``bytes`` with
                           ``--scheduler``, else ``path``);
``--out DIR``, ``--plot-x KEY``, ``--rms-from T`` (start of the RMS window, default 0.5 s),
``--no-plot``, ``--[no-]progress``, ``--restart-workers``, ``--strict`` (exit 1 if a run failed).

Names are the :class:`Scenario` fields (``-`` may replace ``_``); values are checked and converted
to the field's type before anything runs (a malformed value is an error of the command; a value
the scenario rejects, e.g. a negative radius, makes that run fail and is reported in the table).

Config file (TOML)
------------------
::

    [batch]                       # runner options (the command line wins)
    fmu_dir = "build"             # resolution = "40mm,6deg"; out = "results/batch"; workers = 2
    plot_x = "h"                  # scheduler = "tcp://host:8786"; fmu_transfer = "auto"; rms_from = 0.5

    [base]                        # fixed Scenario fields of every run
    t_end = 1.0

    [sweep]                       # cartesian product, in this order
    h = [0.001, 0.002]
    plant_mass_scale = [0.8, 1.0, 1.2]
    order = ["gauss-seidel", "jacobi"]

    [sweep.circle]                # a sub-table: its lists vary together (one dimension)
    radius = [0.20, 0.25]
    center = [[0.45, 0.30], [0.50, 0.30]]

    [[cases]]                     # extra runs (base + these fields), after the product
    radius = 0.85

``--sweep``/``--zip`` on the command line replace the config's dimension of the same key(s).
See ``bench/sweep_example.toml``.

Table
-----
One row per run, in run order: ``run``, ``status`` (``ok``/``failed``), ``error`` (exception type
and text, plus the messages the FMUs logged during the run, e.g. why a step was refused), the
scenario (every field; ``center`` as ``center_x``, ``center_y``), the tracking metrics
(``rms_joint_error`` after ``rms_from`` s, ``max_joint_error``, ``max_dk_vs_true`` = max |DK pose -
true pose|, ``dk_branch_errors`` = steps where they differ by more than 1e-6, ``dk_status_<name>``
counts of the DK FMU's status), timing (``wall_seconds`` of the task on the worker =
``load_seconds`` + ``init_seconds`` + ``sim_seconds`` + metrics, ``realtime_factor``) and where it
ran (``worker``, ``host``, ``pid``, ``loop_runs`` = runs served by that FMU set so far).

Design
------
*Worker FMU reuse.*  pythonfmu FMUs must be extracted once per process and their libraries never
unloaded (see :meth:`dynamics.cosim.FMUUnit.close`), and extraction plus the first instantiation
are the expensive part of a short run.  Each process keeps one :class:`ClosedLoop` per FMU set in
a module-level cache keyed by the SHA-256 of the three files, created by the first run that needs
it; later runs reuse it (``ClosedLoop.run`` resets its FMUs: new instances from the libraries
already loaded, no extraction, no second copy of a library).  A lock makes a
process run one co-simulation at a time (the FMUs are Python and hold the GIL: start workers with
one thread).  A failed run retires its instances (fmi2FreeInstance; the library stays loaded) and
the next run instantiates new ones from the same extracted copy (~20 ms), so a failure cannot
leak into later runs.  A process can hold one build of each FMU: a different build of an FMU it
has already loaded is refused (restart the workers, ``--restart-workers``).  The FMUs' resources
folders (bundled copies of ``solver``/``dynamics``) are taken off ``sys.path`` after instantiation,
so later imports, and processes spawned later from this one, use the installed packages.  The
local pool (:func:`local_cluster`) runs its workers without dask's sampling profiler and without
dask's aggressive ``MALLOC_TRIM_THRESHOLD_`` (both cost the GIL-bound runs a few per cent).

*FMU distribution.*  ``path``: tasks carry the absolute paths and the SHA-256 of each file; a
worker checks the hash of what it finds at that path (a stale copy on a node is an error, not a
silently different result).  ``bytes``: the client scatters the three files once to every worker
(``Client.scatter(..., broadcast=True)``, ~0.5 MB); the first task on a node writes them to
``$RRR_DK_FMU_CACHE`` or ``<tmp>/rrr-dk-fmus/<sha256>/<Name>.fmu`` (atomic rename, hash checked),
shared by the worker processes of that node; no shared file system is needed.

*Failures.*  Everything a run raises (invalid scenario, start pose outside the workspace, an FMU
refusing a step: ``fmi2DoStep ... discard`` plus the slave's reason) is caught on the worker and
returned as a ``failed`` row; a worker that dies is retried by dask and, after its
``allowed-failures``, reported as a failed row (``KilledWorker``).  The other runs go on.

*Determinism.*  A run depends only on its scenario: fresh FMU state (reset or new instances),
time ``t0 + k h``, no randomness, a single thread per run.  The same scenario gives the same
metrics bit for bit on any worker of the same software on the same kind of CPU (numba compiles
for the host CPU; on a heterogeneous cluster set ``NUMBA_CPU_NAME=generic`` on every node for
identical code).  The CSV writes floats with 17 significant digits (round trip exact).

Multi-node dask cluster
-----------------------
1. On every node: the same Python environment with this project installed (``pip install -e .``
   of the same source tree, or a wheel of it) -- the workers import ``dynamics.batch`` and the
   FMUs run inside the worker's interpreter, using its ``solver``/``dynamics``/numpy/numba.
2. Scheduler node: ``dask scheduler --host 0.0.0.0 --port 8786`` (on a private network; dask's
   TCP protocol is not authenticated -- use its TLS options or an SSH tunnel otherwise).
3. Each worker node: ``dask worker tcp://SCHEDULER:8786 --nworkers $(nproc) --nthreads 1``
   (optionally with ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` in its environment, as
   the local pool does).  Workers may join or leave during a batch; a lost run is retried.
4. Client (where the FMUs are built): ``python -m dynamics.batch --config sweep.toml
   --scheduler tcp://SCHEDULER:8786``; with ``--scheduler`` the FMUs go to the workers as bytes
   (``--fmu-transfer path`` with a ``--fmu-dir`` mounted at the same path on every node also works).
   The cluster is used unchanged; after rebuilding the FMUs add ``--restart-workers`` once.
The Python API is the same: ``run_batch(params, fmus, scheduler="tcp://...")`` or
``run_batch(params, fmus, client=my_client)``.

Known issue (pythonfmu 0.7): a process that loaded several pythonfmu FMUs may abort at exit
("corrupted double-linked list", from the wrappers' ``finalizePythonInterpreter`` at ``dl_fini``).
``python -m dynamics.batch --serial`` therefore ends with ``os._exit`` once its output is written,
and worker processes that loaded FMUs do the same at interpreter exit (:func:`_exit_hard`).
"""
from __future__ import annotations

import argparse
import atexit
import csv
import dataclasses
import hashlib
import itertools
import json
import logging
import math
import os
import re
import socket
import sys
import tempfile
import threading
import time
import tomllib
from contextlib import contextmanager
from pathlib import Path

import numpy as np

# before any FMU is instantiated: every process then runs the FMUs on the installed fmu_src runtime
# (as the serial CLI, whose build step imports it), not on the bundled copy of the first FMU loaded
import fmu_src.table_slave  # noqa: F401
import solver
from dynamics.cosim import DK_STATUS, FMU_NAMES, ClosedLoop, Scenario, build_fmus

__all__ = ["SCENARIO_FIELDS", "BatchResult", "ConfigError", "FMUBuildConflict", "expand", "parse_value",
           "parse_sweep_arg", "load_config", "fmu_spec", "run_task", "run_batch", "write_table",
           "plot_summary", "worker_state", "local_cluster", "main"]

# ============================================================================ scenario fields
SCENARIO_FIELDS = {f.name: f for f in dataclasses.fields(Scenario)}
_DEFAULTS = {f.name: (f.default if f.default is not dataclasses.MISSING else f.default_factory())
             for f in dataclasses.fields(Scenario)}
_INT_FIELDS = {"posture", "plant_substeps"}
_STR_FIELDS = {"order", "tracker_mode"}
_VEC_FIELDS = {"center": 2}
#: Threshold of a DK branch error: |DK pose - true pose| (m or rad) above this at a step.
BRANCH_TOL = 1e-6


class ConfigError(ValueError):
    """A malformed sweep, config file or option (the message names it)."""


class FMUBuildConflict(RuntimeError):
    """This process already runs another build of one of the FMUs (restart the workers)."""


def _field_name(key: str) -> str:
    name = str(key).strip().replace("-", "_")
    if name not in SCENARIO_FIELDS:
        raise ConfigError(f"{key!r} is not a Scenario field; expected one of {sorted(SCENARIO_FIELDS)}")
    return name


def parse_value(key: str, value):
    """``value`` (a TOML value or a command-line string) converted to the type of field ``key``."""
    name = _field_name(key)
    if name in _VEC_FIELDS:
        n = _VEC_FIELDS[name]
        if isinstance(value, str):
            parts = [p for p in re.split(r"[\s,;:()\[\]]+", value) if p]
        elif isinstance(value, (list, tuple)):
            parts = list(value)
        else:
            parts = [value]
        if len(parts) != n:
            raise ConfigError(f"{name}: expected {n} numbers, got {value!r}")
        return tuple(_to_float(name, p) for p in parts)
    if isinstance(value, (list, tuple, dict)):
        raise ConfigError(f"{name}: expected a single value, got {value!r}")
    if name in _STR_FIELDS:
        return str(value).strip()
    if name in _INT_FIELDS:
        f = _to_float(name, value)
        if not float(f).is_integer():
            raise ConfigError(f"{name}: expected an integer, got {value!r}")
        return int(f)
    return _to_float(name, value)


def _to_float(name, value) -> float:
    if isinstance(value, bool):
        raise ConfigError(f"{name}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a number, got {value!r}") from None


def _split_top(text: str) -> list[str]:
    """Split on commas outside brackets: ``"[1,2],[3,4]"`` -> ``["[1,2]", "[3,4]"]``."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return [s.strip() for s in out if s.strip()]


def parse_sweep_arg(text: str) -> tuple[str, list]:
    """``"KEY=V1,V2"`` -> ``(field, [values])``; ``lo:hi:n`` gives n values (linspace)."""
    if "=" not in text:
        raise ConfigError(f"{text!r}: expected KEY=V1,V2,...")
    key, rhs = text.split("=", 1)
    name = _field_name(key)
    values = []
    for item in _split_top(rhs):
        m = re.fullmatch(r"([^:\[\]]+):([^:\[\]]+):(\d+)", item)
        if m and name not in _STR_FIELDS and name not in _VEC_FIELDS:
            lo, hi, n = _to_float(name, m[1]), _to_float(name, m[2]), int(m[3])
            if n < 1:
                raise ConfigError(f"{name}: {item!r} asks for no value")
            values.extend(parse_value(name, float(v)) for v in np.linspace(lo, hi, n))
        else:
            values.append(parse_value(name, item))
    if not values:
        raise ConfigError(f"{text!r}: no value")
    return name, values


def _dimension(key, spec) -> tuple[tuple[str, ...], list[tuple]]:
    """One dimension of the product: a list of values of one field, or a table of equal lists."""
    if isinstance(spec, dict):
        names = tuple(_field_name(k) for k in spec)
        lists = [spec[k] if isinstance(spec[k], list) else [spec[k]] for k in spec]
        if not lists or len({len(v) for v in lists}) != 1:
            raise ConfigError(f"sweep group {key!r}: expected lists of equal length, got "
                              f"{ {k: len(v) for k, v in zip(spec, lists)} }")
        rows = [tuple(parse_value(n, v) for n, v in zip(names, vals)) for vals in zip(*lists)]
        return names, rows
    name = _field_name(key)
    values = spec if isinstance(spec, list) else [spec]
    if name in _VEC_FIELDS and values and not isinstance(values[0], (list, tuple)):
        values = [values]                     # center = [0.45, 0.3]: a single value
    if not values:
        raise ConfigError(f"sweep {key!r}: no value")
    return (name,), [(parse_value(name, v),) for v in values]


def expand(base: dict | None = None, sweep: dict | None = None, cases: list | None = None) -> list[dict]:
    """Parameter dicts (every Scenario field) of the runs: ``base`` x product(``sweep``) + ``cases``.

    ``sweep``: ``{field: [values]}`` (one dimension each) or ``{group: {field: [values], ...}}``
    (the lists of a group vary together).  ``cases``: extra ``{field: value}`` runs on ``base``.
    Values are converted with :func:`parse_value`; no run is validated here (the worker does it).
    """
    fixed = dict(_DEFAULTS)
    for k, v in (base or {}).items():
        fixed[_field_name(k)] = parse_value(k, v)
    dims = [_dimension(k, v) for k, v in (sweep or {}).items()]
    seen: dict[str, str] = {}
    for names, _ in dims:
        for n in names:
            if n in seen:
                raise ConfigError(f"{n!r} is swept twice")
            seen[n] = n
    runs = []
    for combo in itertools.product(*(rows for _, rows in dims)):
        p = dict(fixed)
        for (names, _), vals in zip(dims, combo):
            p.update(zip(names, vals))
        runs.append(p)
    for case in cases or []:
        if not isinstance(case, dict):
            raise ConfigError(f"cases: expected tables of Scenario fields, got {case!r}")
        p = dict(fixed)
        for k, v in case.items():
            p[_field_name(k)] = parse_value(k, v)
        runs.append(p)
    return runs


def load_config(path) -> dict:
    """Read a TOML sweep file: ``{"batch": {...}, "base": {...}, "sweep": {...}, "cases": [...]}``."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            cfg = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    unknown = set(cfg) - {"batch", "base", "sweep", "cases"}
    if unknown:
        raise ConfigError(f"{path}: unknown sections {sorted(unknown)} (expected batch, base, sweep, cases)")
    batch = cfg.get("batch", {})
    bad = set(batch) - set(_BATCH_OPTIONS)
    if bad:
        raise ConfigError(f"{path}: unknown [batch] options {sorted(bad)}; expected {sorted(_BATCH_OPTIONS)}")
    return {"batch": batch, "base": cfg.get("base", {}), "sweep": cfg.get("sweep", {}),
            "cases": cfg.get("cases", [])}


_BATCH_OPTIONS = {"fmu_dir": "build", "resolution": None, "out": "results/batch", "workers": None,
                  "scheduler": None, "fmu_transfer": "auto", "plot_x": None, "rms_from": 0.5}


# ============================================================================ FMU files
def _sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fmu_spec(fmus: dict) -> dict:
    """``{name: {"path": absolute path, "sha256": ..., "size": bytes}}`` of the three FMU files."""
    spec = {}
    for name in FMU_NAMES:
        if name not in fmus:
            raise ConfigError(f"no {name} FMU given")
        p = Path(fmus[name]).resolve()
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such FMU")
        spec[name] = {"path": str(p), "sha256": _sha256_file(p), "size": p.stat().st_size}
    return spec


def _cache_root() -> Path:
    return Path(os.environ.get("RRR_DK_FMU_CACHE") or Path(tempfile.gettempdir()) / "rrr-dk-fmus")


def _materialize(name: str, sha: str, data: bytes) -> Path:
    """Write ``data`` to ``<cache>/<sha>/<name>.fmu`` once (atomic, hash checked); its path."""
    target = _cache_root() / sha / f"{name}.fmu"
    if target.is_file() and target.stat().st_size == len(data):
        return target
    if hashlib.sha256(data).hexdigest() != sha:
        raise RuntimeError(f"{name}: the bytes received do not match their SHA-256 {sha[:12]}...")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


# ============================================================================ worker side
_LOCK = threading.Lock()
_STATE = {"loops": {}, "paths": {}, "loaded": {}, "hashes": {}, "runs": {}, "created": 0, "exit_hook": False}


def worker_state() -> dict:
    """What this process holds: FMU sets (by hash), their paths, runs served, instances created."""
    with _LOCK:
        return {"fmu_sets": [list(k) for k in _STATE["loops"]], "loaded": dict(_STATE["loaded"]),
                "paths": {",".join(k): v for k, v in _STATE["paths"].items()},
                "runs": {",".join(k): v for k, v in _STATE["runs"].items()},
                "instances_created": _STATE["created"], "pid": os.getpid()}


def _exit_hard():
    """atexit, in processes that loaded FMUs as dask workers: skip the libraries' fini (known issue)."""
    from dynamics.cosim import exit_process

    exit_process(0)


def _local_paths(spec: dict, blobs: dict | None) -> dict:
    """Paths of the FMU files in this process: materialized bytes, or the given paths (hash checked)."""
    paths = {}
    for name in FMU_NAMES:
        sha = spec[name]["sha256"]
        if blobs is not None:
            paths[name] = str(_materialize(name, sha, blobs[name]))
            continue
        p = Path(spec[name]["path"])
        if not p.is_file():
            raise FileNotFoundError(f"{name}: {p} not found on host {socket.gethostname()} (no shared file "
                                    "system? use --fmu-transfer bytes)")
        st = p.stat()
        key = (str(p), st.st_mtime_ns, st.st_size)
        if key not in _STATE["hashes"]:
            _STATE["hashes"][key] = _sha256_file(p)
        if _STATE["hashes"][key] != sha:
            raise RuntimeError(f"{name}: {p} on host {socket.gethostname()} is not the client's file "
                               f"(SHA-256 {_STATE['hashes'][key][:12]}... != {sha[:12]}...)")
        paths[name] = str(p)
    return paths


def _get_loop(spec: dict, blobs: dict | None):
    """The cached ClosedLoop of this FMU set (created if needed); (loop, key, seconds spent, created)."""
    key = tuple(spec[n]["sha256"] for n in FMU_NAMES)
    loop = _STATE["loops"].get(key)
    if loop is not None:
        return loop, key, 0.0, False
    t0 = time.perf_counter()
    for name, sha in zip(FMU_NAMES, key):
        have = _STATE["loaded"].get(name)
        if have is not None and have != sha:
            raise FMUBuildConflict(
                f"this process (pid {os.getpid()}) already loaded another build of {name} (SHA-256 "
                f"{have[:12]}..., now {sha[:12]}...); pythonfmu allows one per process: restart the "
                "workers (--restart-workers or Client.restart())")
    if key not in _STATE["paths"]:
        # the first paths of a set stay its paths: a second extraction of the same FMU in one
        # process would load a second copy of its library (see FMUUnit.close)
        _STATE["paths"][key] = _local_paths(spec, blobs)
    saved = list(sys.path)
    try:
        loop = ClosedLoop(_STATE["paths"][key])
    finally:
        # pythonfmu prepends each FMU's resources/ (bundled copies of solver, dynamics, fmu_src) to
        # sys.path at every instantiation and leaves it there: later imports in this process, and
        # processes spawned from it (a LocalCluster started after a serial run inherits sys.path),
        # would import those copies (other code, recompiled numba kernels).  The slaves are loaded.
        sys.path[:] = saved
    _STATE["created"] += 1
    for name, sha in zip(FMU_NAMES, key):
        _STATE["loaded"][name] = sha
    _STATE["loops"][key] = loop
    if not _STATE["exit_hook"] and _in_dask_worker() is not None:
        atexit.register(_exit_hard)
        _STATE["exit_hook"] = True
    return loop, key, time.perf_counter() - t0, True


def _retire(key) -> None:
    loop = _STATE["loops"].pop(key, None)
    if loop is not None:
        try:
            loop.close()
        except Exception:  # noqa: BLE001 - the instances are gone either way
            pass


def _in_dask_worker():
    try:
        from distributed import get_worker
        return get_worker()
    except Exception:  # noqa: BLE001 - not in a worker (ValueError) or no distributed
        return None


def _fmu_log():
    """Collect what the FMU slaves log (logger ``fmu_src.<Model>``) during a run."""
    from fmu_src.fmi_build import captured_slave_log

    return captured_slave_log(strip_traceback=True)


def _scenario_columns(params: dict) -> dict:
    cols = {}
    for name in SCENARIO_FIELDS:
        v = params.get(name, _DEFAULTS[name])
        if name == "center":
            try:
                cols["center_x"], cols["center_y"] = float(v[0]), float(v[1])
            except Exception:  # noqa: BLE001
                cols["center_x"] = cols["center_y"] = float("nan")
        else:
            cols[name] = v
    return cols


METRIC_COLUMNS = ("rms_joint_error", "max_joint_error", "max_dk_vs_true", "dk_branch_errors",
                  *(f"dk_status_{s}" for s in DK_STATUS.values()), "n_steps", "rms_from")
TIMING_COLUMNS = ("wall_seconds", "load_seconds", "init_seconds", "sim_seconds", "realtime_factor")
WHERE_COLUMNS = ("worker", "host", "pid", "loop_runs")
COLUMNS = ("run", "status", "error", *(c for c in _scenario_columns({})), *METRIC_COLUMNS, *TIMING_COLUMNS,
           *WHERE_COLUMNS)
_INT_COLUMNS = {"dk_branch_errors", "n_steps", "pid", "loop_runs", *(f"dk_status_{s}" for s in DK_STATUS.values())}


def _metrics(res, rms_from: float) -> dict:
    e = res.joint_error()
    t = res.t
    c = res.columns
    sel = t >= rms_from - 1e-12
    d = np.stack([c["x"] - c["x_true"], c["y"] - c["y_true"],
                  solver.wrap_angle(c["phi"] - c["phi_true"])], axis=1)
    dmax = np.max(np.abs(d), axis=1) if len(d) else np.zeros(0)
    status = c["dk_status"].astype(np.int64)
    out = {"rms_joint_error": res.rms_joint_error(rms_from) if sel.any() else float("nan"),
           "max_joint_error": float(np.max(np.abs(e))) if e.size else float("nan"),
           "max_dk_vs_true": res.max_dk_error() if len(d) else float("nan"),
           "dk_branch_errors": int(np.count_nonzero(~(dmax <= BRANCH_TOL))),
           "n_steps": int(len(t)), "rms_from": float(rms_from)}
    for code, label in DK_STATUS.items():
        out[f"dk_status_{label}"] = int(np.count_nonzero(status == code))
    return out


def _where() -> dict:
    w = _in_dask_worker()
    name = "local" if w is None else str(w.name if w.name is not None else w.address)
    return {"worker": name, "host": socket.gethostname(), "pid": os.getpid()}


def run_task(index: int, params: dict, fmus: dict, blobs: dict | None = None, rms_from: float = 0.5) -> dict:
    """One run on this process (a dask task, or called directly): the table row, never raises.

    ``fmus``: :func:`fmu_spec` of the FMU files; ``blobs``: ``{name: bytes}`` when the files travel
    as bytes (then ``fmus[name]["path"]`` is only informative).
    """
    row = {c: None for c in COLUMNS}
    row.update(run=int(index), status="failed", error="", **_scenario_columns(params), **_where())
    with _LOCK:
        t_start = time.perf_counter()
        key = None
        messages: list[str] = []
        try:
            sc = Scenario(**{k: (tuple(v) if k in _VEC_FIELDS else v) for k, v in params.items()})
            loop, key, load_s, _ = _get_loop(fmus, blobs)
            row["load_seconds"] = load_s
            t_run = time.perf_counter()
            with _fmu_log() as messages:
                res = loop.run(sc)
            run_s = time.perf_counter() - t_run
            _STATE["runs"][key] = _STATE["runs"].get(key, 0) + 1
            row.update(_metrics(res, rms_from))
            row.update(status="ok", load_seconds=load_s, sim_seconds=res.wall_seconds,
                       init_seconds=run_s - res.wall_seconds, loop_runs=_STATE["runs"][key])
        except Exception as exc:  # noqa: BLE001 - every failure becomes a row
            text = f"{type(exc).__name__}: {exc}"
            if messages:
                text += " | FMU log: " + " | ".join(dict.fromkeys(m.strip() for m in messages))
            row["error"] = text[:4000]
            if key is not None:
                _retire(key)              # fresh instances for the next run
        row["wall_seconds"] = time.perf_counter() - t_start
        if row["status"] == "ok":
            row["realtime_factor"] = row["t_end"] / row["wall_seconds"]
    return row


def _failed_row(index: int, params: dict, exc: BaseException | str, rms_from: float) -> dict:
    row = {c: None for c in COLUMNS}
    row.update(run=int(index), status="failed", **_scenario_columns(params))
    row["error"] = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return row


# ============================================================================ client side
@dataclasses.dataclass
class BatchResult:
    """Rows (one per run, in run order) and facts about the batch."""

    rows: list
    meta: dict

    @property
    def n_failed(self) -> int:
        return sum(r["status"] != "ok" for r in self.rows)

    def column(self, name) -> list:
        return [r[name] for r in self.rows]


class _Progress:
    def __init__(self, total: int, enabled: bool):
        self.bar = None
        self.total, self.done, self.failed = total, 0, 0
        self.enabled = enabled
        self._last = 0.0
        if enabled:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=total, unit="run", file=sys.stderr, dynamic_ncols=True)
            except ImportError:
                pass

    def update(self, row: dict):
        self.done += 1
        self.failed += row["status"] != "ok"
        if self.bar is not None:
            self.bar.set_postfix(failed=self.failed, refresh=False)
            self.bar.update(1)
        elif self.enabled and (time.monotonic() - self._last > 2.0 or self.done == self.total):
            self._last = time.monotonic()
            print(f"  {self.done}/{self.total} runs done, {self.failed} failed", file=sys.stderr, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def run_batch(params: list[dict], fmus: dict, *, scheduler: str | None = None, client=None,
              n_workers: int | None = None, serial: bool = False, fmu_transfer: str = "auto",
              rms_from: float = 0.5, progress: bool = False, restart_workers: bool = False,
              log=print) -> BatchResult:
    """Run every parameter dict of ``params`` (see :func:`expand`) with the FMUs ``fmus``.

    Where: ``serial=True`` in this process; ``client`` (a ``distributed.Client``) or ``scheduler``
    (its address) on that cluster, unchanged; otherwise a ``LocalCluster`` of ``n_workers``
    processes (default: the cores) with one thread each, on 127.0.0.1, closed at the end.
    ``fmu_transfer``: ``"path"``, ``"bytes"`` or ``"auto"`` (bytes on a given cluster, else path).
    """
    if fmu_transfer not in ("auto", "path", "bytes"):
        raise ConfigError(f"fmu_transfer: expected auto, path or bytes, got {fmu_transfer!r}")
    spec = fmu_spec(fmus)
    remote = client is not None or scheduler is not None
    transfer = ("bytes" if remote else "path") if fmu_transfer == "auto" else fmu_transfer
    meta = {"n_runs": len(params), "fmus": spec, "fmu_transfer": "in-process" if serial else transfer,
            "rms_from": rms_from, "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    t0 = time.perf_counter()
    rows: dict[int, dict] = {}
    bar = _Progress(len(params), progress)
    try:
        _execute(params, spec, serial, client, scheduler, n_workers, transfer, rms_from, restart_workers,
                 rows, bar, meta, log)
    except KeyboardInterrupt:
        meta["interrupted"] = True
        log(f"interrupted: {len(rows)} of {len(params)} runs done; the others are reported as not run")
    finally:
        bar.close()
    meta["wall_seconds"] = time.perf_counter() - t0
    out = [rows[i] if i in rows else _failed_row(i, params[i], "not run (interrupted)", rms_from)
           for i in range(len(params))]
    meta["n_failed"] = sum(r["status"] != "ok" for r in out)
    return BatchResult(out, meta)


def _execute(params, spec, serial, client, scheduler, n_workers, transfer, rms_from, restart_workers, rows, bar,
             meta, log):
    """Fill ``rows`` {index: row} in this process or on dask (see :func:`run_batch`)."""
    if serial:
        meta["cluster"] = "serial (this process)"
        for i, p in enumerate(params):
            rows[i] = run_task(i, p, spec, None, rms_from)
            bar.update(rows[i])
        return
    from distributed import Client

    own = cluster = None
    try:
        if client is None:
            if scheduler is not None:
                client = own = Client(scheduler, timeout="30s")
            else:
                cluster, client = local_cluster(n_workers)
                own = client
        if restart_workers:
            client.restart()
        info = client.scheduler_info(n_workers=-1) if _accepts_n_workers(client) else client.scheduler_info()
        workers = info.get("workers", {})
        meta["cluster"] = client.scheduler.address
        meta["workers"] = {a: {"name": str(w.get("name")), "nthreads": w.get("nthreads"), "host": w.get("host")}
                           for a, w in workers.items()}
        if not workers:
            log("warning: the cluster has no worker yet; the runs wait for one")
        _submit_and_collect(client, params, spec, transfer, rms_from, rows, bar)
    finally:
        if own is not None:
            own.close()
        if cluster is not None:
            cluster.close()


def local_cluster(n_workers: int | None = None):
    """A ``LocalCluster`` of ``n_workers`` processes (default: the cores), one thread each, on 127.0.0.1
    (no dashboard); returns ``(cluster, client)``, the workers started."""
    import warnings

    import dask
    from distributed import Client, LocalCluster

    n = n_workers or _default_workers()
    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ") or {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    tuning = {
        # the runs are pure-Python loops holding the GIL: the worker's sampling profiler (every
        # 10 ms) takes it from them, and glibc's aggressive trimming (dask's default 64 kB
        # threshold, for data-heavy workers) slows the many small allocations of an FMU's
        # instantiation; neither helps here
        "distributed.worker.profile.enabled": False,
        "distributed.nanny.pre-spawn-environ": environ,
    }
    with warnings.catch_warnings(), dask.config.set(tuning):
        # the scheduler's HTTP endpoint falls back from the default port 8787 to a free one
        warnings.filterwarnings("ignore", message=r"Port \d+ is already in use", category=UserWarning)
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
    client = Client(cluster)
    client.wait_for_workers(n, timeout=120)
    return cluster, client


def _accepts_n_workers(client) -> bool:
    import inspect
    try:
        return "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):
        return False


def _cost(p: dict) -> int:
    """Estimated relative cost of a run: plant steps (0 when the parameters are not numbers)."""
    try:
        return int(min(float(p["t_end"]) / float(p["h"]) * max(int(p["plant_substeps"]), 1), 1e9))
    except (TypeError, ValueError, ZeroDivisionError, KeyError, OverflowError):
        return 0


def _submit_and_collect(client, params, spec, transfer, rms_from, rows, bar):
    from distributed import as_completed

    blobs = None
    if transfer == "bytes":
        data = {name: Path(spec[name]["path"]).read_bytes() for name in FMU_NAMES}
        blobs = client.scatter(data, broadcast=True, hash=True)
    batch_id = hashlib.sha256(f"{time.time_ns()}-{os.getpid()}".encode()).hexdigest()[:10]
    futures = {}
    for i, p in enumerate(params):
        # longest runs first (priority = estimated plant steps): the last tasks are short, so the
        # workers finish together; results are reported in run order anyway
        fut = client.submit(run_task, i, p, spec, blobs, rms_from, key=f"rrr-run-{batch_id}-{i:05d}",
                            pure=False, priority=_cost(p))
        futures[fut] = i
    try:
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - worker died (KilledWorker), cancelled, ...
                row = _failed_row(i, params[i], exc, rms_from)
            rows[i] = row
            bar.update(row)
            fut.release()
    except BaseException:
        client.cancel(list(futures))
        raise
    finally:
        for fut in (blobs or {}).values():
            fut.release()


# ============================================================================ output
def _csv_cell(v):
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return v


def write_table(result: BatchResult, out_dir) -> list[Path]:
    """``batch.csv`` (+ ``batch.parquet`` with pyarrow) and ``batch_meta.json`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "batch.csv"]
    with open(paths[0], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in result.rows:
            w.writerow([_csv_cell(r.get(c)) for c in COLUMNS])
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        pa = None
    if pa is not None:
        cols = {}
        for c in COLUMNS:
            vals = [r.get(c) for r in result.rows]
            if c in _INT_COLUMNS:
                cols[c] = pa.array([None if v is None else int(v) for v in vals], type=pa.int64())
            elif c in ("error", "status", "worker", "host", "order", "tracker_mode"):
                cols[c] = pa.array([None if v is None else str(v) for v in vals], type=pa.string())
            elif c == "run":
                cols[c] = pa.array(vals, type=pa.int64())
            else:
                cols[c] = pa.array([None if v is None else _as_float(v) for v in vals], type=pa.float64())
        paths.append(out / "batch.parquet")
        pq.write_table(pa.table(cols), paths[-1])
    paths.append(out / "batch_meta.json")
    paths[-1].write_text(json.dumps(result.meta, indent=2, default=str) + "\n")
    return paths


def _as_float(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _varying(rows) -> list[str]:
    keys = [k for k in _scenario_columns({}) if k != "run"]
    out = []
    for k in keys:
        vals = {repr(r.get(k)) for r in rows}
        if len(vals) > 1:
            out.append(k)
    return out


def plot_summary(result: BatchResult, path, x: str | None = None, max_lines: int = 16) -> Path | None:
    """PNG: RMS joint error and max |DK - true| vs one swept parameter, a line per other combination."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result.rows
    varying = _varying(rows)
    if x is not None:
        x = "center_x" if x == "center" else _field_name(x) if x not in ("center_x", "center_y") else x
    numeric = [k for k in varying if k not in _STR_FIELDS]
    if x is None:
        x = numeric[0] if numeric else None
    others = [k for k in varying if k != x]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), dpi=110)
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in others), []).append(r)
    n_failed = sum(r["status"] != "ok" for r in rows)
    plotted = [False, False]
    failed_labelled = [False]
    for gi, (gkey, grows) in enumerate(sorted(groups.items(), key=lambda kv: repr(kv[0]))):
        label = ", ".join(f"{k}={_short(v)}" for k, v in zip(others, gkey)) or "all runs"
        ok = [r for r in grows if r["status"] == "ok"]
        xs = [r[x] if x else r["run"] for r in ok]
        order = np.argsort(np.asarray(xs, float), kind="stable") if xs else []
        for k, (ax, metric) in enumerate(zip(axes, ("rms_joint_error", "max_dk_vs_true"))):
            ys = np.array([_as_float(ok[j][metric]) for j in order])
            xv = np.array([_as_float(xs[j]) for j in order])
            plotted[k] |= bool(np.isfinite(ys).any())
            if len(ys):
                ax.plot(xv, np.maximum(ys, 1e-18), "o-", ms=4, lw=1, label=label if gi < max_lines else None)
        bad = [_as_float(r[x] if x else r["run"]) for r in grows if r["status"] != "ok"]
        if bad:
            for ax in axes:
                ax.plot(bad, [0.03] * len(bad), "x", color="tab:red", ms=7, transform=ax.get_xaxis_transform(),
                        label=None if failed_labelled[0] else "failed run")
            failed_labelled[0] = True
    xl = x or "run"
    axes[0].set_title(f"RMS joint error after {result.meta.get('rms_from', 0.5):g} s", fontsize=10)
    axes[0].set_ylabel("rad")
    axes[1].set_title("max |DK pose - true pose| (m or rad)", fontsize=10)
    for ax, any_data in zip(axes, plotted):
        ax.set_xlabel(xl)
        if any_data:
            ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"batch: {len(rows)} runs, {n_failed} failed (red x at the bottom: a failed run)", fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    if len(groups) > 1 or n_failed:
        ncol = 2 if len(labels) > 3 else max(len(labels), 1)
        nrows = math.ceil(len(labels) / ncol)
        extra = 0.2 * nrows + 0.3
        fig.set_size_inches(12, 4.8 + extra)
        fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7, frameon=False)
        fig.tight_layout(rect=(0, extra / (4.8 + extra), 1, 1))
    else:
        fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def _short(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)


# ============================================================================ command line
def _build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m dynamics.batch", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", help="TOML sweep file")
    ap.add_argument("--sweep", action="append", default=[], metavar="KEY=V1,V2", help="a product dimension")
    ap.add_argument("--zip", action="append", default=[], metavar="KEY=V1,V2", help="keys that vary together")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=V", help="a fixed Scenario field")
    ap.add_argument("--t-end", type=float, help="simulated time of every run, s")
    ap.add_argument("--fmu-dir", help="folder of the three FMUs (built there if missing)")
    ap.add_argument("--resolution", help="DK map resolution if the DK FMU must be built, e.g. 40mm,6deg")
    ap.add_argument("--out", help="output folder (default results/batch)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--scheduler", help="address of an existing dask scheduler (tcp://host:port)")
    where.add_argument("--serial", action="store_true", help="run in this process, no dask")
    ap.add_argument("--workers", type=int, help="local cluster size (default: the cores)")
    ap.add_argument("--fmu-transfer", choices=("auto", "path", "bytes"))
    ap.add_argument("--restart-workers", action="store_true", help="Client.restart() before the runs")
    ap.add_argument("--rms-from", type=float, help="start of the RMS window, s (default 0.5)")
    ap.add_argument("--plot-x", help="x axis of the summary plot (a swept field)")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                    help="progress bar (default: when stderr is a terminal)")
    ap.add_argument("--dry-run", action="store_true", help="list the runs and stop")
    ap.add_argument("--strict", action="store_true", help="exit status 1 if a run failed")
    return ap


def _plan(args) -> tuple[dict, list[dict]]:
    cfg = load_config(args.config) if args.config else {"batch": {}, "base": {}, "sweep": {}, "cases": []}
    opts = dict(_BATCH_OPTIONS)
    opts.update(cfg["batch"])
    for name in ("fmu_dir", "resolution", "out", "workers", "scheduler", "fmu_transfer", "plot_x", "rms_from"):
        v = getattr(args, name)
        if v is not None:
            opts[name] = v
    if args.serial:
        opts["scheduler"] = None
    base = dict(cfg["base"])
    for item in args.set:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        base[_field_name(k)] = parse_value(k, v)
    if args.t_end is not None:
        base["t_end"] = args.t_end
    sweep = {(_field_name(k) if not isinstance(v, dict) else k): v for k, v in cfg["sweep"].items()}
    for item in args.sweep:
        name, values = parse_sweep_arg(item)
        _drop_key(sweep, name)
        sweep[name] = values
    if args.zip:
        group = {}
        for item in args.zip:
            name, values = parse_sweep_arg(item)
            _drop_key(sweep, name)
            group[name] = values
        sweep["--zip"] = group
    params = expand(base, sweep, cfg["cases"])
    opts["base"], opts["sweep"], opts["cases"] = base, sweep, cfg["cases"]
    return opts, params


def _drop_key(sweep: dict, name: str):
    for k in list(sweep):
        v = sweep[k]
        if k == name:
            del sweep[k]
        elif isinstance(v, dict) and name in v:
            raise ConfigError(f"{name!r} is part of the sweep group {k!r} of the config; sweep the group there")


def _parse_resolution(text):
    if text is None:
        return None
    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root))
    try:
        import build_fmu
    finally:
        sys.path.pop(0)
    return build_fmu.parse_resolution(text)


def main(argv=None) -> int:
    """Command line (see the module docstring); returns the exit status."""
    args = _build_parser().parse_args(argv)
    try:
        opts, params = _plan(args)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not params:
        print("error: no run to do", file=sys.stderr)
        return 2
    if args.dry_run:
        varying = _varying([_scenario_columns(p) for p in params]) or ["t_end"]
        print(f"{len(params)} runs; varying: {', '.join(varying)}")
        for i, p in enumerate(params):
            cols = _scenario_columns(p)
            print(f"  {i:4d}  " + "  ".join(f"{k}={_short(cols[k])}" for k in varying))
        return 0
    try:
        fmus = build_fmus(opts["fmu_dir"], resolution=_parse_resolution(opts["resolution"]))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    n_local = opts["workers"] or _default_workers()
    where = "this process" if args.serial else (opts["scheduler"] or f"a local cluster of {n_local} processes")
    print(f"{len(params)} runs on {where}")
    result = run_batch(params, fmus, scheduler=opts["scheduler"], n_workers=opts["workers"], serial=args.serial,
                       fmu_transfer=opts["fmu_transfer"], rms_from=float(opts["rms_from"]), progress=progress,
                       restart_workers=args.restart_workers)
    result.meta.update(base=opts["base"], sweep=opts["sweep"], cases=opts["cases"], argv=sys.argv[1:] if argv is None
                       else list(argv))
    paths = write_table(result, opts["out"])
    if not args.no_plot:
        try:
            paths.append(plot_summary(result, Path(opts["out"]) / "batch_summary.png", x=opts["plot_x"]))
        except ConfigError as exc:
            print(f"warning: no plot: {exc}", file=sys.stderr)
    for p in paths:
        print(f"wrote {p}")
    ok = [r for r in result.rows if r["status"] == "ok"]
    print(f"{len(ok)}/{len(result.rows)} runs ok, {result.n_failed} failed, {result.meta['wall_seconds']:.1f} s wall")
    failed = [r for r in result.rows if r["status"] != "ok"]
    for r in failed[:10]:
        print(f"  run {r['run']} failed: {r['error'][:300]}")
    if len(failed) > 10:
        print(f"  ... and {len(failed) - 10} more (see the table)")
    if ok:
        rms = np.array([_as_float(r["rms_joint_error"]) for r in ok])
        print(f"RMS joint error after {opts['rms_from']:g} s: min {np.nanmin(rms):.3e}, max {np.nanmax(rms):.3e} rad"
              if np.isfinite(rms).any() else "RMS joint error: no sample in the window")
    if result.meta.get("interrupted"):
        return 130
    return 1 if (args.strict and result.n_failed) else 0


def _main_and_exit():
    code = main()
    if _STATE["created"]:
        # FMUs were loaded in this process (--serial): skip the libraries' exit code (known issue)
        from dynamics.cosim import exit_process

        exit_process(code)
    sys.exit(code)


if __name__ == "__main__":
    # run the importable module, not this __main__ copy: dask pickles functions of __main__ by value
    from dynamics.batch import _main_and_exit as _entry

    _entry()
