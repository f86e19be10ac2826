"""The 3-RPR through the same tracker: errors, silent errors, false alarms per method, the cusp loops.

    python bench/bench_rpr.py [--step-mm 25 --step-deg 3] [--out results] [--no-plot]

Manipulator: the cuspidal 3-RPR (:meth:`solver.rpr.RPRManipulator.zein_wenger_chablat`).
Suite (:func:`experiments.rpr_suite.rpr_suite`): circles passing 20, 5 and 1 mm from a singular
curve about three seed poses (1000, 300, 100, 30 points), and loops of 2 cm in joint space
around five cusps (1000, 100, 30, 12 points) along which the platform changes assembly mode
without meeting a singularity.  The map tensor covers the suite's region, built here.
Per method: errors (pose more than 1e-6 from the true one), silent errors (wrong and
``certain``), false alarms (right, not ``certain``), as for the 3-RRR (``bench_tracker.py``).
Also writes ``rpr_suite.csv`` and, unless ``--no-plot``, the basic regions with the singular
curves at three orientations (``figures/rpr_regions_phi*.png``).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench_tracker import methods, pose_errors, print_totals, run_suite, totals
from experiments.rpr_suite import rpr_suite
from solver import MapTensor
from solver.rpr import RPR_WORK_BOUNDS, RPRManipulator


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step-mm", type=float, default=25.0)
    ap.add_argument("--step-deg", type=float, default=3.0)
    ap.add_argument("--out", default="results")
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    model = RPRManipulator.zein_wenger_chablat()
    t0 = time.perf_counter()
    suite = rpr_suite(model)
    b = np.array(RPR_WORK_BOUNDS)
    st = np.array([args.step_mm / 1e3, args.step_mm / 1e3, np.deg2rad(args.step_deg)])
    shape = (int(round((b[0, 1] - b[0, 0]) / st[0])) + 1, int(round((b[1, 1] - b[1, 0]) / st[1])) + 1,
             int(round(2 * np.pi / st[2])))
    mt = MapTensor.build(model, 1, bounds=b, shape=shape)
    t_map = time.perf_counter() - t0
    maps = {1: mt}
    table = run_suite(model, maps, suite)
    names = list(methods(model, maps))
    print(f"3-RPR {model.name}: {len(suite)} streams, {sum(p.resolvable for p in suite)} resolvable, "
          f"{sum(len(p.X) - 1 for p in suite):,} steps; map {shape} nodes, suite + map {t_map:.0f} s")
    loops = [p for p in suite if "loop" in p.name]
    circles = [p for p in suite if "loop" not in p.name]
    print_totals("near-singular circles", totals(table, circles, names), names)
    print_totals("cusp loops (non-singular assembly-mode changes)", totals(table, loops, names), names)
    _report({"near-singular circles": (circles, totals(table, circles, names)),
             "cusp loops (non-singular assembly-mode changes)": (loops, totals(table, loops, names))}, names, shape)
    print("\n| loop | samples | ratio | resolvable | default: errors/silent/alarms | newton: errors | "
          "end pose, default / newton (distance to the true one) |")
    print("|---|---|---|---|---|---|---|")
    makers = methods(model, maps)
    for p in loops:
        d, nw = table[p.name, "default"], table[p.name, "newton"]
        ends = []
        for n in ("default", "newton"):
            X = makers[n](1).track(p.q, p.X[0]).X
            ends.append(pose_errors(X[-1:], p.X[-1:])[0])
        print(f"| {p.name.split('/')[0]} | {len(p.X) - 1} | {p.ratio:.2f} | {'yes' if p.resolvable else 'no'} | "
              f"{d[0]}/{d[1]}/{d[2]} | {nw[0]} | {ends[0]:.1e} / {ends[1]:.1e} |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "rpr_suite.csv", "w") as f:
        f.write("path,samples,ratio,resolvable," + ",".join(f"{n}_errors,{n}_silent,{n}_alarms" for n in names) + "\n")
        for p in suite:
            f.write(f"{p.name},{len(p.X)},{p.ratio:.6g},{int(p.resolvable)},"
                    + ",".join(f"{table[p.name, n][0]},{table[p.name, n][1]},{table[p.name, n][2]}" for n in names)
                    + "\n")
    if not args.no_plot:
        from experiments.figures import plot_cross_sections
        res = plot_cross_sections(model, 1, (-60.0, 0.0, 60.0), out_dir=out / "figures", step=0.01,
                                  bounds=RPR_WORK_BOUNDS)
        for phd, (path, stats) in res.items():
            print(f"{path}: label-border nodes within a cell of a singular curve {100 * stats['border_singular']:.0f} %"
                  f" (the rest: borders that are not singular curves)")


def _report(groups, names, shape):
    """The totals of the circles and of the cusp loops into docs/benchmarks.md (bench/report.py)."""
    from bench_tracker import TOTALS_HEADER, totals_rows
    from report import publish, table
    parts = [f"{title}: {len(ps)} streams, {sum(len(p.X) - 1 for p in ps):,} steps.\n\n"
             + table(TOTALS_HEADER, totals_rows(tot, names)) for title, (ps, tot) in groups.items()]
    tot = [sum(t["default"][i] for _, t in groups.values()) for i in range(5)]
    steps = sum(len(p.X) - 1 for ps, _ in groups.values() for p in ps)
    headline = [(f"3-RPR (cuspidal), default mode: errors / silent errors / false alarms, {steps:,} steps",
                 f"{tot[1]} / {tot[2]} / {tot[3]}", "0 silent")]
    publish("rpr", "\n\n".join(parts), headline=headline,
            note=f"The cuspidal 3-RPR, map {shape[0]} x {shape[1]} x {shape[2]} nodes over the suite's region. "
                 "Per-path counts: `results/rpr_suite.csv`.")


if __name__ == "__main__":
    main()
