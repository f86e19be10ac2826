"""The client side of a batch: where the runs go (this process, a local pool, a dask cluster) and the rows back.

:func:`run_batch` submits one :func:`cosim.batch.worker.run_task` per parameter dict, longest
first, and collects the rows in run order; a worker that dies is retried by dask and, after its
``allowed-failures``, reported as a failed row (``KilledWorker``); the other runs go on.  The local
pool (:func:`local_cluster`) runs its workers without dask's sampling profiler and without dask's
aggressive ``MALLOC_TRIM_THRESHOLD_`` (both cost the GIL-bound runs a few per cent).  With
``fmu_transfer="bytes"`` the client scatters the three FMU files once to every worker
(``Client.scatter(..., broadcast=True)``, ~0.5 MB; :mod:`cosim.batch.fmu_files`).
"""
from __future__ import annotations

import hashlib
import os
import sys
import time
from pathlib import Path

from cosim import FMU_NAMES

from .fmu_files import fmu_spec
from .sweep import ConfigError
from .table import BatchResult
from .worker import failed_row, run_task

__all__ = ["run_batch", "local_cluster", "default_workers"]


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


def default_workers() -> int:
    """The cores this process may use."""
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
    out = [rows[i] if i in rows else failed_row(i, params[i], "not run (interrupted)", rms_from)
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

    n = n_workers or default_workers()
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
                row = failed_row(i, params[i], exc, rms_from)
            rows[i] = row
            bar.update(row)
            fut.release()
    except BaseException:
        client.cancel(list(futures))
        raise
    finally:
        for fut in (blobs or {}).values():
            fut.release()
