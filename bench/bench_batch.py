"""Batch of closed-loop co-simulations: one process vs a local dask pool of worker processes.

    python bench/bench_batch.py [--fmu-dir build] [--runs 64] [--t-end 4.0] [--workers 2]

The same ``--runs`` scenarios (a sweep of plant mass error x controller bandwidth x communication
step x master order, ``--t-end`` simulated seconds each) are run

1. serially, in this process, by :func:`cosim.batch.run_batch` with ``serial=True``: one
   :class:`ClosedLoop` created by the first run and reused (``ClosedLoop.run`` resets it) by the others;
2. on a ``LocalCluster`` of ``--workers`` processes (one thread each): the cluster is started first
   (timed apart), then the batch; each worker creates its ClosedLoop in its first task and reuses it.

Both start cold (this process and the workers load the FMUs in their first run), so the FMU load
counts once per process in both.  Printed: wall time of each, the speedup (batch on a started
cluster, and including the cluster start), and the per-run split: FMU load (extract + instantiate,
first run of a process), first-run warm-up (imports and compiled kernels loaded inside the FMUs
and the master's first initialization), per-run initialization (reset of the three FMUs, i.e. new
instances from the loaded libraries, + their setup and initialization), simulation (the step loop), and the dask overhead per run (worker-seconds not spent
in a task).  Also checks that both give the same metrics bit for bit.  Numbers, no assertions;
run it with the machine otherwise idle (the load average is printed).  The default 4 s of simulated
time per run amortises the ~2 s a process spends once on loading the FMUs (paid by the serial
process and, in parallel, by every worker), which bounds the speedup of short batches.
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

import solver  # noqa: F401  (first: the FMUs then use this copy of the package)
from cosim import batch
from cosim import build_fmus
from cosim.unit import exit_process

METRICS = ("rms_joint_error", "max_joint_error", "max_dk_vs_true", "dk_branch_errors", "dk_status_ok", "n_steps")


def scenarios(n: int, t_end: float) -> list[dict]:
    sweep = {"plant_mass_scale": [0.8, 0.9, 1.1, 1.2], "bandwidth": [30.0, 40.0, 50.0, 60.0],
             "h": [0.001, 0.002], "order": ["gauss-seidel", "jacobi"]}
    runs = batch.expand({"t_end": t_end}, sweep)
    while len(runs) < n:
        runs = runs + runs
    return runs[:n]


def split(rows, label: str, workers: int, wall: float) -> dict:
    ok = [r for r in rows if r["status"] == "ok"]
    first = [r for r in ok if r["loop_runs"] == 1 and r["load_seconds"] > 0]
    rest = [r for r in ok if r not in first]
    mean = lambda key, rs: float(np.mean([r[key] for r in rs])) if rs else float("nan")  # noqa: E731
    init_steady, sim = mean("init_seconds", rest), mean("sim_seconds", ok)
    busy = sum(r["wall_seconds"] for r in rows)
    out = {
        "label": label, "wall": wall, "n": len(rows), "failed": len(rows) - len(ok),
        "load": mean("load_seconds", first), "warmup": mean("init_seconds", first) - init_steady,
        "init": init_steady, "sim": sim, "task": mean("wall_seconds", rest),
        "dask_overhead": (wall * workers - busy) / len(rows),
        "loads": len(first), "workers_used": len({(r["host"], r["pid"]) for r in rows}),
    }
    return out


def show(s: dict) -> None:
    print(f"  {s['label']}: {s['wall']:.2f} s wall for {s['n']} runs ({s['failed']} failed), "
          f"{s['workers_used']} process(es), FMUs loaded {s['loads']} time(s)")
    print(f"    per process, once: FMU load (extract + instantiate) {s['load'] * 1e3:.0f} ms, "
          f"first-run warm-up {s['warmup'] * 1e3:.0f} ms")
    print(f"    per run (mean): init (reset + setup) {s['init'] * 1e3:.1f} ms, simulation {s['sim'] * 1e3:.1f} ms, "
          f"task {s['task'] * 1e3:.1f} ms; idle/scheduling per run {s['dask_overhead'] * 1e3:.1f} ms")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fmu-dir", default="build")
    ap.add_argument("--runs", type=int, default=64)
    ap.add_argument("--t-end", type=float, default=4.0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)

    fmus = build_fmus(args.fmu_dir)
    params = scenarios(args.runs, args.t_end)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}; load average before: {os.getloadavg()[0]:.2f}")
    steps = sum(round(args.t_end / p["h"]) for p in params)
    print(f"{len(params)} runs of {args.t_end:g} s simulated (h = 1 or 2 ms: {steps} macro steps in all); "
          f"FMUs from {Path(args.fmu_dir).resolve()}")

    t0 = time.perf_counter()
    serial = batch.run_batch(params, fmus, serial=True)
    t_serial = time.perf_counter() - t0

    t0 = time.perf_counter()
    cluster, client = batch.local_cluster(args.workers)
    t_start = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        pooled = batch.run_batch(params, fmus, client=client, fmu_transfer="path")
        t_pool = time.perf_counter() - t0
    finally:
        client.close()
        cluster.close()

    s1 = split(serial.rows, "serial, 1 process", 1, t_serial)
    s2 = split(pooled.rows, f"dask LocalCluster, {args.workers} processes", args.workers, t_pool)
    print()
    show(s1)
    show(s2)
    print(f"    cluster start-up (not in the batch time): {t_start:.2f} s")
    same = all([repr(a[k]) for k in METRICS] == [repr(b[k]) for k in METRICS] and a["status"] == b["status"]
               for a, b in zip(serial.rows, pooled.rows))          # repr: bit for bit, NaN == NaN
    print()
    print(f"speedup {args.workers} workers vs serial: {t_serial / t_pool:.2f}x on a started cluster, "
          f"{t_serial / (t_pool + t_start):.2f}x including the cluster start-up")
    print(f"ideal with the per-process load counted once in both: "
          f"{t_serial / (t_serial / args.workers + (s1['load'] + s1['warmup']) * (1 - 1 / args.workers)):.2f}x")
    print(f"same metrics bit for bit, serial vs workers: {same}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    _report(args, len(params), s1, s2, t_serial, t_pool, t_start, same)
    # FMUs were loaded in this process: skip the pythonfmu libraries' exit code (see cosim.unit)
    exit_process(0)


def _report(args, n, s1, s2, t_serial, t_pool, t_start, same):
    """The batch timings into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    rows = []
    for s in (s1, s2):
        rows.append((s["label"], f"{s['wall']:.1f} s", f"{s['failed']}", f"{s['load'] * 1e3:.0f} ms",
                     f"{s['init'] * 1e3:.1f} ms", f"{s['sim'] * 1e3:.0f} ms"))
    speedup = t_serial / t_pool
    body = (table(["how", "wall", "failed runs", "FMU load, once per process", "init per run", "simulation per run"],
                  rows)
            + f"\n\nSpeed-up of {args.workers} workers: {speedup:.2f}x on a started cluster, "
            f"{t_serial / (t_pool + t_start):.2f}x counting its start-up ({t_start:.1f} s). Same metrics bit for "
            f"bit, serial vs workers: {same}.")
    publish("batch", body, note=f"{n} runs of {args.t_end:g} s simulated at h = 1 or 2 ms.",
            headline=[(f"batch: {n} runs of {args.t_end:g} s, {args.workers} workers vs one process",
                       f"{speedup:.2f}x ({t_serial:.1f} s -> {t_pool:.1f} s)", ">= 1.7x on 2 cores")])


if __name__ == "__main__":
    main()
