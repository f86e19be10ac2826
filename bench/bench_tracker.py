"""The tracker benchmark: branch errors and per-step time of every method on the suite.

    python bench/bench_tracker.py [--rule aspect] [--step-mm 10 --step-deg 2] [--out results]

For every path of :func:`solver.suite.default_suite` (the paper circle and
circles passing 20, 5 and 1 mm from a type-1 singularity in postures 1, 3, 5,
each sampled at 1000, 300, 100 and 30 points) and every method (the tracker in
default and paper mode, the four baselines) it counts branch errors (steps
whose pose differs from the truth by more than 1e-6 in x, y or wrapped phi)
and the largest error, and prints:

1. per path: ambiguity ratio, resolvable or not, errors per method;
2. totals per method, over resolvable paths and over all paths;
3. per-step time: median of ``step`` for each method on the paper circle at
   1000 points (all methods timed in the same run, interleaved).

It writes ``<out>/tracker_suite.csv`` and ``<out>/figures/tracker_errors.png``.
Maps are cached in ``build/maps/`` (rebuilt when missing).
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from solver import DEFAULT_RULE, Manipulator, ik, wrap_angle
from solver.baselines import BASELINES
from solver.maptensor import DEFAULT_STEP, load_or_build
from solver.suite import default_suite
from solver.tracker import Tracker
from solver.trajectories import circle_path


def pose_errors(X, truth):
    d = np.abs(X - truth)
    d[:, 2] = np.abs(wrap_angle(X[:, 2] - truth[:, 2]))
    return d.max(axis=1)


def methods(model, maps):
    out = {"default": lambda p: Tracker(model, maps[p]), "paper": lambda p: Tracker(model, maps[p], mode="paper")}
    for name, cls in BASELINES.items():
        out[name] = (lambda c: (lambda p: c(model)))(cls)
    return out


def run_suite(model, maps, suite):
    """Errors per (path, method): dict[(path.name, method)] -> (n_errors, max_error, n_ambiguous)."""
    table = {}
    for path in suite:
        for name, make in methods(model, maps).items():
            res = make(path.posture).track(path.q, path.X[0])
            e = pose_errors(res.X, path.X)
            table[path.name, name] = (int(np.sum(e > 1e-6)), float(e.max()), int(res.ambiguous.sum()))
    return table


def time_steps(model, maps, n_repeat=5):
    """Median single-step time (us) of every method on the paper circle (1000 points)."""
    X = circle_path(1000)
    q = ik(model, X, 1)
    trackers = {name: make(1) for name, make in methods(model, maps).items()}
    samples = {name: [] for name in trackers}
    for _ in range(n_repeat):
        for name, tr in trackers.items():                   # interleaved: same conditions for all
            tr.reset(X[0], q[0])
            step = tr.step
            for k in range(1, len(q)):
                t0 = time.perf_counter()
                step(q[k])
                samples[name].append(time.perf_counter() - t0)
    return {name: 1e6 * float(np.median(s)) for name, s in samples.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rule", default=DEFAULT_RULE)
    ap.add_argument("--step-mm", type=float, default=DEFAULT_STEP[0] * 1e3)
    ap.add_argument("--step-deg", type=float, default=float(np.rad2deg(DEFAULT_STEP[2])))
    ap.add_argument("--out", default="results")
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    step = (args.step_mm / 1e3, args.step_mm / 1e3, np.deg2rad(args.step_deg))
    suite = default_suite(model)
    maps = {p: load_or_build(model, p, args.rule, step) for p in sorted({s.posture for s in suite})}
    table = run_suite(model, maps, suite)
    names = list(methods(model, maps))
    print(f"rule {args.rule!r}, map step {args.step_mm:g} mm / {args.step_deg:g} deg; branch errors per path")
    print(f"{'path':30s} {'ratio':>7s} {'res.':>4s} " + " ".join(f"{n:>16s}" for n in names))
    for p in suite:
        print(f"{p.name:30s} {p.ratio:7.3f} {'yes' if p.resolvable else 'no':>4s} "
              + " ".join(f"{table[p.name, n][0]:16d}" for n in names))
    print("\n| method | branch errors, resolvable paths | branch errors, all paths | largest error | "
          "ambiguous flags |")
    print("|---|---|---|---|---|")
    totals = {}
    for n in names:
        res = sum(table[p.name, n][0] for p in suite if p.resolvable)
        tot = sum(table[p.name, n][0] for p in suite)
        big = max(table[p.name, n][1] for p in suite)
        amb = sum(table[p.name, n][2] for p in suite)
        totals[n] = (res, tot)
        print(f"| {n} | {res} | {tot} | {big:.3g} | {amb} |")
    n_res = sum(p.resolvable for p in suite)
    print(f"\n{len(suite)} paths, {n_res} resolvable, {sum(len(p.X) for p in suite):,} steps")
    times = time_steps(model, maps)
    print("\n| method | median step time (us), paper circle, 1000 points |")
    print("|---|---|")
    for n in names:
        print(f"| {n} | {times[n]:.1f} |")
    print(f"\ndefault / newton time ratio: {times['default'] / times['newton']:.2f} (target <= 3); "
          f"default median {times['default']:.1f} us (target <= 50)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "tracker_suite.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["path", "posture", "points", "ratio", "resolvable", "method", "branch_errors", "max_error",
                    "ambiguous"])
        for p in suite:
            for n in names:
                e, big, amb = table[p.name, n]
                w.writerow([p.name, p.posture, len(p.X), f"{p.ratio:.6g}", int(p.resolvable), n, e, f"{big:.6g}",
                            amb])
    if not args.no_plot:
        plot(suite, table, names, out / "figures" / "tracker_errors.png", args.rule)


def plot(suite, table, names, path, rule):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    samplings = sorted({len(p.X) for p in suite}, reverse=True)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    for ax, only_res, title in ((axes[0], True, "resolvable paths (ratio < 0.5)"),
                                (axes[1], False, "all paths")):
        width = 0.8 / len(names)
        for i, n in enumerate(names):
            vals = [sum(table[p.name, n][0] for p in suite if len(p.X) == s and (p.resolvable or not only_res))
                    for s in samplings]
            ax.bar(np.arange(len(samplings)) + i * width, np.asarray(vals) + 0.5, width, label=n, bottom=0.5)
        ax.set_yscale("log")
        ax.set_xticks(np.arange(len(samplings)) + 0.4 - width / 2)
        ax.set_xticklabels([f"{s} points" for s in samplings])
        ax.set_ylabel("branch errors + 1 (log)")
        ax.set_title(title, fontsize=10)
    axes[1].legend(fontsize=8, ncol=2)
    fig.suptitle(f"Tracker vs baselines on the suite (map rule {rule!r})", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
