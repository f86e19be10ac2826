"""The worker side of a batch: one closed-loop run per task (:func:`run_task`), FMUs loaded once per process.

*Worker FMU reuse.*  pythonfmu FMUs must be extracted once per process and their libraries never
unloaded (:mod:`cosim.unit`), and extraction plus the first instantiation are the expensive part
of a short run.  Each process keeps one :class:`ClosedLoop` per FMU set in :data:`STATE`, keyed by
the SHA-256 of the three files, created by the first run that needs it; later runs reuse it
(``ClosedLoop.run`` re-instantiates its FMUs from the libraries already loaded: no extraction, no
second copy of a library).  :data:`LOCK` makes a process run one co-simulation at a time (the FMUs
are Python and hold the GIL: start workers with one thread).  A failed run retires its instances
(fmi2FreeInstance; the library stays loaded) and the next run instantiates new ones from the same
extracted copy (~20 ms), so a failure cannot leak into later runs.  A process can hold one build of
each FMU: a different build of an FMU it has already loaded is refused (:class:`FMUBuildConflict`;
restart the workers).  The FMUs' resources folders (bundled copies of ``solver``/``dynamics``) are
taken off ``sys.path`` after instantiation, so later imports, and processes spawned later from this
one, use the installed packages.

*Failures.*  Everything a run raises (invalid scenario, start pose outside the workspace, an FMU
refusing a step: ``fmi2DoStep ... discard`` plus the slave's reason) is caught here and returned
as a ``failed`` row.

*Determinism.*  A run depends only on its scenario: fresh FMU state, time ``t0 + k h``, no
randomness, a single thread per run.  The same scenario gives the same metrics bit for bit on any
worker of the same software on the same kind of CPU (numba compiles for the host CPU; on a
heterogeneous cluster set ``NUMBA_CPU_NAME=generic`` on every node for identical code).
"""
from __future__ import annotations

import atexit
import os
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np

# before any FMU is instantiated: every process then runs the FMUs on the installed fmu_src runtime
# (as the serial CLI, whose build step imports it), not on the bundled copy of the first FMU loaded
import fmu_src.table_slave  # noqa: F401
from cosim import FMU_NAMES, ClosedLoop, Scenario
from cosim.unit import captured_slave_log, exit_process
from solver import STATUS, wrap_angle

from .fmu_files import materialize, sha256_file
from .sweep import VEC_FIELDS
from .table import COLUMNS, scenario_columns

__all__ = ["STATE", "LOCK", "BRANCH_TOL", "FMUBuildConflict", "worker_state", "get_loop", "run_task",
           "failed_row"]

#: Threshold of a DK branch error: |DK pose - true pose| (m or rad) above this at a step.
BRANCH_TOL = 1e-6


class FMUBuildConflict(RuntimeError):
    """This process already runs another build of one of the FMUs (restart the workers)."""


LOCK = threading.Lock()
#: What this process holds (see :func:`worker_state`); :data:`LOCK` makes it run one co-simulation at a time.
STATE = {"loops": {}, "paths": {}, "loaded": {}, "hashes": {}, "runs": {}, "created": 0, "exit_hook": False}


def worker_state() -> dict:
    """What this process holds: FMU sets (by hash), their paths, runs served, instances created."""
    with LOCK:
        return {"fmu_sets": [list(k) for k in STATE["loops"]], "loaded": dict(STATE["loaded"]),
                "paths": {",".join(k): v for k, v in STATE["paths"].items()},
                "runs": {",".join(k): v for k, v in STATE["runs"].items()},
                "instances_created": STATE["created"], "pid": os.getpid()}


def _exit_hard():
    """atexit, in processes that loaded FMUs as dask workers: skip the libraries' fini (known issue)."""
    exit_process(0)


def _local_paths(spec: dict, blobs: dict | None) -> dict:
    """Paths of the FMU files in this process: materialized bytes, or the given paths (hash checked)."""
    paths = {}
    for name in FMU_NAMES:
        sha = spec[name]["sha256"]
        if blobs is not None:
            paths[name] = str(materialize(name, sha, blobs[name]))
            continue
        p = Path(spec[name]["path"])
        if not p.is_file():
            raise FileNotFoundError(f"{name}: {p} not found on host {socket.gethostname()} (no shared file "
                                    "system? use --fmu-transfer bytes)")
        st = p.stat()
        key = (str(p), st.st_mtime_ns, st.st_size)
        if key not in STATE["hashes"]:
            STATE["hashes"][key] = sha256_file(p)
        if STATE["hashes"][key] != sha:
            raise RuntimeError(f"{name}: {p} on host {socket.gethostname()} is not the client's file "
                               f"(SHA-256 {STATE['hashes'][key][:12]}... != {sha[:12]}...)")
        paths[name] = str(p)
    return paths


def get_loop(spec: dict, blobs: dict | None):
    """The cached ClosedLoop of this FMU set (created if needed); (loop, key, seconds spent, created)."""
    key = tuple(spec[n]["sha256"] for n in FMU_NAMES)
    loop = STATE["loops"].get(key)
    if loop is not None:
        return loop, key, 0.0, False
    t0 = time.perf_counter()
    for name, sha in zip(FMU_NAMES, key):
        have = STATE["loaded"].get(name)
        if have is not None and have != sha:
            raise FMUBuildConflict(
                f"this process (pid {os.getpid()}) already loaded another build of {name} (SHA-256 "
                f"{have[:12]}..., now {sha[:12]}...); pythonfmu allows one per process: restart the "
                "workers (--restart-workers or Client.restart())")
    if key not in STATE["paths"]:
        # the first paths of a set stay its paths: a second extraction of the same FMU in one
        # process would load a second copy of its library (see FMUUnit.close)
        STATE["paths"][key] = _local_paths(spec, blobs)
    saved = list(sys.path)
    try:
        loop = ClosedLoop(STATE["paths"][key])
    finally:
        # pythonfmu prepends each FMU's resources/ (bundled copies of solver, dynamics, fmu_src) to
        # sys.path at every instantiation and leaves it there: later imports in this process, and
        # processes spawned from it (a LocalCluster started after a serial run inherits sys.path),
        # would import those copies (other code, recompiled numba kernels).  The slaves are loaded.
        sys.path[:] = saved
    STATE["created"] += 1
    for name, sha in zip(FMU_NAMES, key):
        STATE["loaded"][name] = sha
    STATE["loops"][key] = loop
    if not STATE["exit_hook"] and _in_dask_worker() is not None:
        atexit.register(_exit_hard)
        STATE["exit_hook"] = True
    return loop, key, time.perf_counter() - t0, True


def _retire(key) -> None:
    loop = STATE["loops"].pop(key, None)
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
    return captured_slave_log(strip_traceback=True)


def _metrics(res, rms_from: float) -> dict:
    e = res.joint_error()
    t = res.t
    c = res.columns
    sel = t >= rms_from - 1e-12
    d = np.stack([c["x"] - c["x_true"], c["y"] - c["y_true"],
                  wrap_angle(c["phi"] - c["phi_true"])], axis=1)
    dmax = np.max(np.abs(d), axis=1) if len(d) else np.zeros(0)
    status = c["dk_status"].astype(np.int64)
    out = {"rms_joint_error": res.rms_joint_error(rms_from) if sel.any() else float("nan"),
           "max_joint_error": float(np.max(np.abs(e))) if e.size else float("nan"),
           "max_dk_vs_true": res.max_dk_error() if len(d) else float("nan"),
           "dk_branch_errors": int(np.count_nonzero(~(dmax <= BRANCH_TOL))),
           "n_steps": int(len(t)), "rms_from": float(rms_from)}
    for code, label in STATUS.items():
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
    row.update(run=int(index), status="failed", error="", **scenario_columns(params), **_where())
    with LOCK:
        t_start = time.perf_counter()
        key = None
        messages: list[str] = []
        try:
            sc = Scenario(**{k: (tuple(v) if k in VEC_FIELDS else v) for k, v in params.items()})
            loop, key, load_s, _ = get_loop(fmus, blobs)
            row["load_seconds"] = load_s
            t_run = time.perf_counter()
            with _fmu_log() as messages:
                res = loop.run(sc)
            run_s = time.perf_counter() - t_run
            STATE["runs"][key] = STATE["runs"].get(key, 0) + 1
            row.update(_metrics(res, rms_from))
            row.update(status="ok", load_seconds=load_s, sim_seconds=res.wall_seconds,
                       init_seconds=run_s - res.wall_seconds, loop_runs=STATE["runs"][key])
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


def failed_row(index: int, params: dict, exc: BaseException | str, rms_from: float) -> dict:
    """The row of a run that did not run or whose worker died."""
    row = {c: None for c in COLUMNS}
    row.update(run=int(index), status="failed", **scenario_columns(params))
    row["error"] = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return row


