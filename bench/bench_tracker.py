"""The tracker benchmark: branch errors, certainty and per-step time of every method on the suites.

    python bench/bench_tracker.py [--suite all|default|hard] [--rule aspect] [--step-mm 10 --step-deg 2]
                                  [--out results] [--robot FILE]

``--robot FILE`` (a robot description, docs/robots.md) runs the hard suite on that robot (the default
suite's paper circle and near-singular seeds are the paper robot's), with maps at its resolution, and
times the steps on its own circle (:func:`solver.robot.default_circle`, 1000 points); its section of
docs/benchmarks.md is ``tracker-<robot name>``, beside the paper robot's.

Suites (:mod:`experiments.suite`): ``default``, the paper circle and circles passing 20,
5 and 1 mm from a type-1 singularity in postures 1, 3, 5, sampled at 1000, 300,
100 and 30 points; ``hard``, all eight postures, circles, ellipses and Lissajous
figures passing 0.5 to 20 mm from a type-1 singularity or far from it, sampled at
30, 50, 100 and 200 points.  For every path and method (the tracker in default
and paper mode, the baselines) it counts, against the true poses of the path:

* errors: steps whose pose differs from the truth by more than 1e-6 (x, y, wrapped phi);
* silent errors: errors reported ``certain`` (baselines that never vouch: all their errors);
* false alarms: right steps not reported ``certain``, as a share of the steps
  (methods that never vouch: not applicable).

It prints the paths with any error or alarm, the totals per method and suite,
and the median step time of every method on the paper circle at 1000 points (all
timed in the same run, interleaved).  It writes ``<out>/tracker_suite.csv`` and
``<out>/figures/tracker_errors.png``.  Maps come from the map cache (:func:`solver.cached_map`,
in ``solver.cache_dir("maps")``).
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from experiments.suite import default_suite, hard_suite
from solver import DEFAULT_RULE, DEFAULT_STEP, Manipulator, Tracker, cached_map, circle_path, ik, wrap_angle
from solver.baselines import BASELINES


def pose_errors(X, truth):
    d = np.abs(X - truth)
    d[:, 2] = np.abs(wrap_angle(X[:, 2] - truth[:, 2]))
    return d.max(axis=1)


#: Methods that report ``certain`` themselves; the others never vouch.
VOUCHING = ("default", "paper", "newton-separation")


def methods(model, maps):
    exact = (1e-9, 1e-9, 1e-9)                       # the start poses are exact: a start tolerance of rounding
    out = {"default": lambda p: Tracker(model, maps[p], start_tolerance=exact),
           "paper": lambda p: Tracker(model, maps[p], mode="paper", start_tolerance=exact)}
    for name, cls in BASELINES.items():
        out[name] = (lambda c: (lambda p: c(model)))(cls)
    return out


def score(name, res, truth):
    """(errors, silent errors, false alarms, max error, steps) of one tracked stream (initial pose excluded)."""
    wrong = pose_errors(res.X, truth)[1:] > 1e-6
    certain = res.certain[1:] if name in VOUCHING else np.ones(len(wrong), dtype=bool)
    alarms = int(np.sum(~wrong & ~certain)) if name in VOUCHING else 0
    return (int(wrong.sum()), int(np.sum(wrong & certain)), alarms, float(pose_errors(res.X, truth).max()),
            len(wrong))


def run_suite(model, maps, suite):
    """Scores per (path, method): dict[(path.name, method)] -> score(...)."""
    table = {}
    makers = methods(model, maps)
    for path in suite:
        for name, make in makers.items():
            table[path.name, name] = score(name, make(path.posture).track(path.q, path.X[0]), path.X)
    return table


def time_steps(model, maps, n_repeat=5, circle=None):
    """Median single-step time (us) of every method on the paper circle (1000 points), or on ``circle``
    (``{"center", "radius", "phi", "posture"}``: another robot's, :func:`solver.robot.default_circle`)."""
    if circle is None:
        X, posture = circle_path(1000), 1
    else:
        X, posture = circle_path(1000, circle["center"], circle["radius"], circle["phi"]), circle["posture"]
    q = ik(model, X, posture)
    trackers = {name: make(posture) for name, make in methods(model, maps).items()}
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


def totals(table, suite, names):
    """Per method: errors on resolvable paths, errors, silent errors, false alarms, steps, largest error."""
    out = {}
    for n in names:
        rows = [table[p.name, n] for p in suite]
        out[n] = (sum(table[p.name, n][0] for p in suite if p.resolvable), sum(r[0] for r in rows),
                  sum(r[1] for r in rows), sum(r[2] for r in rows), sum(r[4] for r in rows),
                  max(r[3] for r in rows))
    return out


TOTALS_HEADER = ("method", "errors, resolvable paths", "errors", "silent errors", "false alarms", "largest error")


def totals_rows(tot, names):
    """The rows of :data:`TOTALS_HEADER` for the totals ``tot`` (from :func:`totals`)."""
    rows = []
    for n in names:
        res, err, silent, alarms, steps, big = tot[n]
        fa = f"{alarms} ({100 * alarms / steps:.2f} %)" if n in VOUCHING else "n/a (never vouches)"
        rows.append((n, res, err, silent, fa, f"{big:.3g}"))
    return rows


def print_totals(title, tot, names):
    print(f"\n{title}\n| " + " | ".join(TOTALS_HEADER) + " |")
    print("|---|---|---|---|---|---|")
    for row in totals_rows(tot, names):
        print("| " + " | ".join(str(c) for c in row) + " |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", choices=("all", "default", "hard"), default="all", help="which paths (default all)")
    ap.add_argument("--rule", default=DEFAULT_RULE, help="ordering rule of the maps (default %(default)s)")
    ap.add_argument("--step-mm", type=float, default=None,
                    help="map node spacing in x, y, mm (default 10, or the robot's resolution)")
    ap.add_argument("--step-deg", type=float, default=None,
                    help="map node spacing in phi, degrees (default 2, or the robot's resolution)")
    ap.add_argument("--out", default="results", help="folder of tracker_suite.csv and figures/ (default results)")
    ap.add_argument("--no-plot", action="store_true", help="no tracker_errors.png")
    ap.add_argument("--robot", metavar="FILE", help="a robot description (docs/robots.md): the hard suite on it")
    args = ap.parse_args(argv)
    robot, circle = None, None
    if args.robot:
        from solver.robot import default_circle, load_robot

        robot = load_robot(args.robot)
        model, circle = robot.model, {**default_circle(robot), "posture": robot.home_posture}
        default = (robot.resolution[0], robot.resolution[0], robot.resolution[1])
        args.suite = "hard"
    else:
        model, default = Manipulator.paper(), DEFAULT_STEP
    args.step_mm = default[0] * 1e3 if args.step_mm is None else args.step_mm
    args.step_deg = float(np.rad2deg(default[2])) if args.step_deg is None else args.step_deg
    step = (args.step_mm / 1e3, args.step_mm / 1e3, np.deg2rad(args.step_deg))
    suites = {}
    if args.suite in ("all", "default"):
        suites["default"] = default_suite(model)
    if args.suite in ("all", "hard"):
        suites["hard"] = hard_suite(model)
    suite = [p for ps in suites.values() for p in ps]
    maps = {p: cached_map(model, p, args.rule, step) for p in sorted({s.posture for s in suite})}
    t0 = time.perf_counter()
    table = run_suite(model, maps, suite)
    names = list(methods(model, maps))
    print(f"rule {args.rule!r}, map step {args.step_mm:g} mm / {args.step_deg:g} deg "
          f"({time.perf_counter() - t0:.0f} s); paths with an error or an alarm: errors/silent/alarms")
    print(f"{'path':32s} {'ratio':>7s} {'res.':>4s} " + " ".join(f"{n:>17s}" for n in names))
    for p in suite:
        if any(table[p.name, n][0] or table[p.name, n][2] for n in ("default", "paper")):
            print(f"{p.name:32s} {p.ratio:7.3f} {'yes' if p.resolvable else 'no':>4s} " + " ".join(
                f"{'/'.join(str(v) for v in table[p.name, n][:3]):>17s}" for n in names))
    all_tot = {}
    for key, ps in suites.items():
        tot = totals(table, ps, names)
        print_totals(f"suite {key!r}: {len(ps)} streams, {sum(p.resolvable for p in ps)} resolvable, "
                     f"{sum(len(p.X) - 1 for p in ps):,} steps", tot, names)
        all_tot[key] = tot
    times = time_steps(model, maps, circle=circle)
    where = "paper circle" if robot is None else f"{robot.name}'s circle"
    print(f"\n| method | median step time (us), {where}, 1000 points |")
    print("|---|---|")
    for n in names:
        print(f"| {n} | {times[n]:.1f} |")
    best = min((n for n in names if n not in ("default", "paper")), key=lambda n: sum(t[n][1] for t in all_tot.values()))
    d_err = sum(t["default"][1] for t in all_tot.values())
    b_err = sum(t[best][1] for t in all_tot.values())
    d_res = sum(t["default"][0] for t in all_tot.values())
    d_silent = sum(t["default"][2] for t in all_tot.values())
    d_alarm = sum(t["default"][3] for t in all_tot.values()) / sum(t["default"][4] for t in all_tot.values())
    print(f"\ntargets, default mode: errors on resolvable paths {d_res} (0); errors {d_err} vs best baseline "
          f"{best} {b_err} (<= half); silent errors {d_silent} (0); false alarms {100 * d_alarm:.2f} % of steps "
          f"(<= 3 %); step time {times['default'] / times['newton']:.2f}x newton (<= 3x)")
    _report(suites, all_tot, names, times, args, robot)
    out = Path(args.out) if robot is None else Path(args.out) / robot.name
    write_table(suite, table, names, out / "tracker_suite.csv")
    if not args.no_plot:
        plot(suite, table, names, out / "figures" / "tracker_errors.png", args.rule)


def write_table(suite, table, names, path: Path) -> None:
    """The per-path counts of every method as CSV."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["path", "posture", "points", "ratio", "resolvable", "method", "errors", "silent_errors",
                    "false_alarms", "max_error", "steps"])
        for p in suite:
            for n in names:
                e, silent, alarms, big, steps = table[p.name, n]
                w.writerow([p.name, p.posture, len(p.X), f"{p.ratio:.6g}", int(p.resolvable), n, e, silent, alarms,
                            f"{big:.6g}", steps])


def _report(suites, all_tot, names, times, args, robot=None):
    """The totals per suite and the step times into docs/benchmarks.md (bench/report.py): section
    ``tracker`` with the README's headline rows, or ``tracker-<name>`` for another robot (no headline)."""
    from report import publish, table
    parts = [] if robot is None else [f"Robot `{robot.name}` ({robot.source}, description sha256 {robot.digest}): "
                                      "the hard suite on its geometry, steps timed on its own circle."]
    where = "paper circle" if robot is None else f"{robot.name}'s circle"
    for key, ps in suites.items():
        parts.append(f"Suite `{key}`: {len(ps)} streams, {sum(p.resolvable for p in ps)} resolvable, "
                     f"{sum(len(p.X) - 1 for p in ps):,} steps; map rule `{args.rule}`, "
                     f"{args.step_mm:g} mm / {args.step_deg:g} deg.\n\n"
                     + table(TOTALS_HEADER, totals_rows(all_tot[key], names)))
    ratio = times["default"] / times["newton"]
    parts.append(table(["method", f"median step time, {where}, 1000 points"],
                       [(n, f"{times[n]:.1f} us") for n in names])
                 + f"\n\nDefault mode / Newton: {ratio:.2f}x (target <= 3x; timed interleaved in one run).")
    publish("tracker" if robot is None else f"tracker-{robot.name}", "\n\n".join(parts),
            headline=_headline(suites, all_tot, names, ratio) if robot is None else None,
            note="Errors: steps more than 1e-6 from the true pose; silent: wrong and `certain`; false alarms: "
                 "right and not `certain`, share of the steps. Per-path counts: `results/tracker_suite.csv`.")


def _headline(suites, all_tot, names, ratio):
    """The tracker's rows of the README's headline table: default mode against the best baseline."""
    from report import target
    tot = {n: [sum(t[n][i] for t in all_tot.values()) for i in range(5)] for n in names}
    base = [n for n in names if n not in ("default", "paper")]
    best = min(base, key=lambda n: tot[n][1])
    steps = sum(len(p.X) - 1 for ps in suites.values() for p in ps)
    res, err, silent, alarms, n_steps = tot["default"]
    return [(f"tracker, default mode: errors on resolvable paths / all ({', '.join(suites)} suites, {steps:,} steps)",
             f"{res} / {err:,} (best baseline, {best}: {tot[best][0]:,} / {tot[best][1]:,})",
             "0 / <= half the best baseline's"),
            ("tracker: silent errors (wrong and `certain`), default / paper mode",
             f"{silent} / {tot['paper'][2]}", "0"),
            ("tracker, default mode: false alarms (right, not `certain`)", f"{100 * alarms / n_steps:.2f} % of steps",
             "<= 3 %"),
            ("tracker step, default mode / Newton, medians", f"{ratio:.2f}x", target("<= 3x", ratio <= 3.0))]


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
