"""Procedure 1 at the default resolution: build time, throughput, file size, memory peak.

    python bench/bench_maptensor.py [--posture 1] [--rule aspect]

Target: >= 100,000 nodes per second.  Memory: the process's maximum resident set size before
and after the build (tracemalloc is not used: it hooks the allocator that the compiled kernels'
small arrays go through and slows the build about tenfold).
"""
from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

import numpy as np

from solver import DEFAULT_RULE, DEFAULT_STEP, Manipulator, MapTensor, dk_all


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--posture", type=int, default=1)
    ap.add_argument("--rule", default=DEFAULT_RULE)
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    dk_all(model, np.zeros((4096, 3)))                 # compile / load the kernels first
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    mt = MapTensor.build(model, args.posture, rule=args.rule)
    seconds = time.perf_counter() - t0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with tempfile.TemporaryDirectory() as d:
        path = mt.save(os.path.join(d, "map.npz"))
        size = path.stat().st_size
        t1 = time.perf_counter()
        MapTensor.load(path, model=model)
        load = time.perf_counter() - t1
    n = mt.labels.size
    print(f"default resolution: step {DEFAULT_STEP[0] * 1e3:g} mm, {DEFAULT_STEP[1] * 1e3:g} mm, "
          f"{np.rad2deg(DEFAULT_STEP[2]):g} deg -> grid {mt.shape[0]} x {mt.shape[1]} x {mt.shape[2]} = {n:,} nodes "
          f"({mt.stats['reachable_nodes']:,} reachable)")
    print(f"build (posture {args.posture}, rule {args.rule!r}): {seconds:.2f} s -> {n / seconds:,.0f} nodes/s "
          f"(target >= 100,000); reachable nodes only: {mt.stats['reachable_nodes'] / seconds:,.0f} nodes/s")
    print(f"file: {size / 1e6:.3f} MB compressed (labels {n / 1e6:.2f} MB as int8); load + verify {load * 1e3:.0f} ms")
    print(f"memory: process max RSS {rss0 / 1e3:.0f} MB before the build, {rss1 / 1e3:.0f} MB after "
          f"(the build's peak adds {(rss1 - rss0) / 1e3:.0f} MB)")
    print(f"largest node-solution distance: {mt.stats['max_node_solution_distance']:.2e}")
    _report(mt, seconds, size, load, (rss1 - rss0) / 1e3)


def _report(mt, seconds, size, load, extra_mb):
    """The headline rows into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    n, reach = mt.labels.size, mt.stats["reachable_nodes"]
    rows = [("grid (default resolution)", f"{mt.shape[0]} x {mt.shape[1]} x {mt.shape[2]} = {n:,} nodes "
             f"({reach:,} reachable)", ""),
            (f"build, posture {mt.posture}, rule `{mt.rule}`", f"{seconds:.1f} s = {n / seconds:,.0f} nodes/s "
             f"({reach / seconds:,.0f} reachable nodes/s)", ">= 100,000 nodes/s"),
            ("file (compressed) / labels as int8", f"{size / 1e6:.3f} MB / {n / 1e6:.2f} MB", ""),
            ("load + verify", f"{load * 1e3:.0f} ms", ""),
            ("peak resident memory added by the build", f"{extra_mb:.0f} MB", ""),
            ("largest node-solution distance", f"{mt.stats['max_node_solution_distance']:.1e}", "")]
    publish("maptensor", table(["what", "measured", "target"], rows),
            headline=[("map tensor build, default resolution", rows[1][1].split(" (")[0], rows[1][2])])


if __name__ == "__main__":
    main()
