"""Speed of dk_all: single-call latency and batched throughput.

    python bench/bench_dk.py [--batch 1000000] [--repeat 15]

Prints the median single-call time (target <= 30 us) and the batched rate over
10^6 joint vectors (target >= 100,000 solution sets per second).  The first
call compiles the kernel (or loads it from numba's cache); it is timed apart.
"""
from __future__ import annotations

import argparse
import os
import platform
import time
import timeit

import numpy as np

from solver import Manipulator, dk_all, ik


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(0, 1, 4 * args.batch // 3), rng.uniform(-0.2, 0.9, 4 * args.batch // 3),
                         rng.uniform(-np.pi, np.pi, 4 * args.batch // 3)])
    q = ik(model, X, rng.integers(1, 9, len(X)))
    q = q[~np.isnan(q[:, 0])]
    n_ik = int(0.8 * args.batch)       # 80 % joint vectors of reachable poses, 20 % uniform angles
    q = np.concatenate([q[:n_ik], rng.uniform(-np.pi, np.pi, (args.batch - n_ik, 3))])
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    t0 = time.perf_counter()
    dk_all(model, q[0])
    dk_all(model, q[:4096])
    print(f"first calls (compile or load from cache): {time.perf_counter() - t0:.2f} s")

    samples = []
    for k in range(200):
        qk = q[k]
        n = 500
        samples.append(timeit.timeit(lambda: dk_all(model, qk), number=n) / n)
    samples = np.array(samples) * 1e6
    print(f"dk_all single call over 200 joint vectors x 500 calls: median {np.median(samples):.1f} us, "
          f"p90 {np.percentile(samples, 90):.1f} us  (target <= 30 us)")

    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        sol = dk_all(model, q)
        times.append(time.perf_counter() - t0)
    best = min(times)
    counts = np.bincount(sol.n_real.ravel(), minlength=7)
    print(f"dk_all batch of {len(q):,}: best of 3 {best:.3f} s -> {len(q) / best:,.0f} solution sets/s "
          f"(target >= 100,000)")
    print("  real-solution counts 0/2/4/6: " + " / ".join(str(counts[i]) for i in (0, 2, 4, 6))
          + f"; odd counts: {int(counts[1::2].sum())}")
    _report(np.median(samples), len(q), best, counts)


def _report(single_us, n, best, counts):
    """The headline rows into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    rows = [("`dk_all` single call, median over 200 joint vectors", f"{single_us:.1f} us", "<= 30 us"),
            (f"`dk_all` batch of {n:,} joint vectors", f"{n / best:,.0f} sets/s", ">= 100,000 sets/s"),
            ("joint vectors with 0 / 2 / 4 / 6 real solutions",
             " / ".join(f"{counts[i]:,}" for i in (0, 2, 4, 6)) + f"; odd counts {int(counts[1::2].sum())}",
             "no odd count")]
    publish("dk", table(["what", "measured", "target"], rows), headline=rows[:2])


if __name__ == "__main__":
    main()
