"""Border volume of each DK ordering rule, per posture: the evidence for the default rule.

    python bench/bench_rules.py [--step-mm 10] [--step-deg 2] [--rules real-phi literal ...]

For every posture and rule, builds the map tensor (procedure 1) and measures the
share of reachable nodes whose procedure-2 neighbourhood (default radius: 2.5
node spacings, eq. 19 weights (1, 1, rho^2)) holds more than one nonzero label.
A label border that is not a basic-region border is a place where the tracker
must work harder for nothing; the rule with the least border volume wins.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from solver import ORDERING_RULES, Manipulator, MapTensor, default_bounds


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step-mm", type=float, default=10.0)
    ap.add_argument("--step-deg", type=float, default=2.0)
    ap.add_argument("--rules", nargs="+", default=sorted(ORDERING_RULES))
    ap.add_argument("--postures", nargs="+", type=int, default=list(range(1, 9)))
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    step = (args.step_mm / 1e3, args.step_mm / 1e3, np.deg2rad(args.step_deg))
    bounds = default_bounds(model, step)
    span = bounds[:, 1] - bounds[:, 0]
    shape = (int(round(span[0] / step[0])) + 1, int(round(span[1] / step[1])) + 1, int(round(span[2] / step[2])))
    print(f"grid {shape}, step {args.step_mm} mm / {args.step_deg} deg; border = share of reachable nodes "
          f"with more than one label within 2.5 spacings")
    table = {}
    for rule in args.rules:
        for p in args.postures:
            t0 = time.perf_counter()
            mt = MapTensor.build(model, p, bounds=bounds, shape=shape, rule=rule)
            table[rule, p] = (mt.border_fraction(), len(np.unique(mt.labels)) - 1)
            print(f"  {rule:9s} posture {p}: border {100 * table[rule, p][0]:5.1f} %, labels used "
                  f"{table[rule, p][1]}, {time.perf_counter() - t0:.1f} s", flush=True)
    print("\n| rule | " + " | ".join(f"posture {p}" for p in args.postures) + " | mean |")
    print("|---|" + "---|" * (len(args.postures) + 1))
    for rule in args.rules:
        vals = [table[rule, p][0] for p in args.postures]
        print(f"| {rule} | " + " | ".join(f"{100 * v:.1f} %" for v in vals) + f" | {100 * np.mean(vals):.1f} % |")
    _report(table, args, shape)


def _report(table, args, shape):
    """The border volumes into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table as md_table
    rows = []
    for rule in args.rules:
        vals = [table[rule, p][0] for p in args.postures]
        rows.append((rule, *(f"{100 * v:.1f} %" for v in vals), f"{100 * np.mean(vals):.1f} %"))
    publish("rules", md_table(["rule", *(f"posture {p}" for p in args.postures), "mean"], rows),
            note=f"Share of reachable nodes with more than one label within 2.5 node spacings (eq. 19 weights), "
                 f"grid {shape[0]} x {shape[1]} x {shape[2]}, {args.step_mm:g} mm / {args.step_deg:g} deg.")


if __name__ == "__main__":
    main()
