"""The tracker on robots as built: geometric tolerances in the certificates and the pose bound.

    python bench/bench_as_built.py [--robots paper irregular] [--tolerances 1e-5 5e-5 5e-4]
                                   [--grades exact 20-bit-2e-5 16-bit-1e-4] [--rate 500] [--every 4]
                                   [--fold-every 10] [--out results]

For each robot (the paper's, ``robots/irregular-3rrr.toml``), the hard suite's paths
(:func:`experiments.suite.hard_suite`: eight postures, three shapes, 0.5 to 20 mm from a type-1
singularity or far from it; every ``--every``-th path, ``--rate`` samples each, dt 1 ms), each tolerance
``t`` (m) and each draw of the robot as built:

* ``uniform``: every length and coordinate of the geometry moved by U(-t, t); ``corner``: by +-t (a
  corner of the tolerance box), a new robot per path;
* the built robot's joints along the path (its own inverse kinematics, same posture), read by the
  sensor grade (:data:`experiments.sensors.SENSOR_GRADES`, seeded per path);
* tracked by the *model* (nominal geometry) with ``joint_tolerance`` (3 noise sigmas plus half a step),
  a speed bound 1.25 times the path's fastest, a start tolerance of 1 mm and 0.01 rad (the model's DK
  solution at the built robot's start is about a tolerance off its pose), and ``geometry_tolerance = t``;
  and the same stream
  tracked without ``geometry_tolerance`` (what a user risks by leaving it out).

Truth: the built robot's pose (the path); its branch: the model's real DK solution of the measured
joints nearest that pose, counted where the second nearest is at least three times farther
(:func:`experiments.sensors.sensor_truth`). Per configuration:

* silent: certain steps whose pose box (pose +- pose_bound) misses the built robot's pose, or whose
  pose is on another branch (target 0);
* bound holds: share of certain steps whose box holds the built robot's pose (target 100 %);
* errors: counted steps off the truth branch; false alarms: right counted steps not certain;
* fold floor (geometry box): share of sampled counted steps (every ``--fold-every``-th) where
  ``bench/sensor_oracle.py``'s test finds a fold within the joint box widened by the step's geometry
  width (the joint width of the tolerance at the true configuration): no sound method vouches there;
* tightness: median over certain steps of pose_bound / |pose - built pose| (x, y, phi);
* step time: median step with the tolerance, beside the same tracker without it on the *model's*
  stream of the same path and sensor, and their ratio (the uncertain steps included).

``--only-timing``: the step time alone where both trackers are certain all the way (the paper circle),
with and without the tolerance (target: at most 1.3x), as section ``as-built-step``.

Writes ``<out>/as_built.csv`` (one row per configuration), prints the table and writes it as section
``as-built`` of ``docs/benchmarks.md`` (``bench/report.py``). Numbers, no assertions.
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_sensors import run_stream  # noqa: E402
from bench_tracker import pose_errors  # noqa: E402
from experiments.sensors import SENSOR_GRADES, sensor_truth  # noqa: E402
from experiments.suite import hard_suite  # noqa: E402
from sensor_oracle import foldable  # noqa: E402
from solver import Manipulator, Tracker, cached_map, ik  # noqa: E402
from solver.geometry_tolerance import built_robot, geometry_tolerance, joint_equivalent  # noqa: E402
from solver.robot import ROBOTS, load_robot  # noqa: E402
from solver.sensors import speed_bound  # noqa: E402

DT = 1e-3
#: The start: the built robot's pose is known, its model DK solution is off by the geometry's effect (about
#: a tolerance's worth): a start tolerance of a millimetre and 0.01 rad covers it at every tolerance run here.
START = (1e-3, 1e-3, 1e-2)
ROBOT_FILES = {"paper": ROBOTS / "paper-3rrr.toml", "irregular": ROBOTS / "irregular-3rrr.toml"}
HEADER = ["robot", "tolerance m", "draw", "sensor", "paths", "steps", "counted", "certain steps", "silent",
          "bound holds %", "errors", "false alarms %", "fold floor %", "silent without", "bound holds without %",
          "tightness x", "tightness y", "tightness phi", "median step us", "median step without us", "ratio"]


def misses(X, X_true, bound):
    d = np.abs(X - X_true)
    d[:, 2] = np.abs(np.angle(np.exp(1j * (X[:, 2] - X_true[:, 2]))))
    return np.any(d > bound, axis=1), d


def run_config(model, maps, paths, tol, draw, sensor, seed, fold_every):
    """One configuration's counts (dict)."""
    rng = np.random.default_rng(seed)
    geometry = geometry_tolerance(model, tol)
    jt = sensor.tolerance(3.0)
    acc = dict(paths=0, steps=0, counted=0, certain=0, silent=0, holds=0, errors=0, right=0, alarms=0,
               fold_n=0, fold=0, silent0=0, certain0=0, holds0=0)
    tight, secs, secs0 = [], [], []
    for i, path in enumerate(paths):
        built = built_robot(model, tol, rng, corner=draw == "corner")
        q_true = ik(built, path.X, path.posture)
        if not np.all(np.isfinite(q_true)):
            continue                                             # the built robot cannot follow this path
        stream = sensor.measure(q_true, seed + i)
        speed = speed_bound(path.X, DT)
        truth, counted = sensor_truth(model, stream.q, path.X, stream.glitch)
        counted = counted.copy()
        counted[0] = False
        n = len(path.X)
        results = {}
        for gt in (tol, 0.0):
            tracker = Tracker(model, maps[path.posture], joint_tolerance=jt, speed_bound=speed,
                              start_tolerance=START, geometry_tolerance=gt)
            bounds = np.full((n, 3), np.inf)
            X, certain, _, s = run_stream(tracker, stream.q, path.X[0], DT, bounds)
            results[gt] = (X, certain, bounds, s)
        X, certain, bounds, s = results[tol]
        miss, d = misses(X, path.X, bounds)
        wrong = counted & (pose_errors(X, truth) > 1e-6)
        acc["paths"] += 1
        acc["steps"] += n - 1
        acc["counted"] += int(counted.sum())
        c = certain.copy()
        c[0] = False
        acc["certain"] += int(c.sum())
        acc["silent"] += int((c & (miss | wrong)).sum())
        acc["holds"] += int((c & ~miss).sum())
        acc["errors"] += int(wrong.sum())
        acc["right"] += int((counted & ~wrong).sum())
        acc["alarms"] += int((counted & ~wrong & ~certain).sum())
        ok = c & ~miss & np.all(d > 0, axis=1)
        tight.append(bounds[ok] / d[ok])
        secs.append(s[1:])
        X0, certain0, bounds0, _ = results[0.0]
        miss0, _ = misses(X0, path.X, bounds0)
        wrong0 = counted & (pose_errors(X0, truth) > 1e-6)
        c0 = certain0.copy()
        c0[0] = False
        acc["certain0"] += int(c0.sum())
        acc["silent0"] += int((c0 & (miss0 | wrong0)).sum())
        acc["holds0"] += int((c0 & ~miss0).sum())
        # the same tracker without the tolerance on the model's own stream of this path: the same work
        q_model = sensor.measure(path.q, seed + i).q
        _, _, _, s0 = run_stream(Tracker(model, maps[path.posture], joint_tolerance=jt, speed_bound=speed,
                                         start_tolerance=START), q_model, path.X[0], DT)
        secs0.append(s0[1:])
        # fold floor with the geometry box: sampled counted steps
        frng = np.random.default_rng(seed + 7 * i)
        for k in np.nonzero(counted)[0][::fold_every]:
            w = joint_equivalent(model, geometry, path.X[k], path.X[k], stream.q[k] - jt, stream.q[k] + jt)
            qk = ik(model, path.X[k], path.posture)              # the model's configuration at the built pose
            if not (np.isfinite(w) and np.all(np.isfinite(qk))):
                acc["fold_n"] += 1
                acc["fold"] += 1
                continue
            acc["fold_n"] += 1
            acc["fold"] += bool(foldable(model, path.X[k], qk, stream.q[k], jt + w, frng))
    t = np.vstack(tight) if tight else np.full((1, 3), np.nan)
    med, med0 = float(np.median(np.concatenate(secs))), float(np.median(np.concatenate(secs0)))
    return dict(acc, tight=np.median(t, axis=0), median=med, median0=med0)


def step_timing(repeats: int = 5, n: int = 1000, tol: float = 5e-5) -> list:
    """Median step (us) on the paper's robot, a 0.1 m circle whose orientation swings (exact joints of the
    model, joint_tolerance 1e-4: certain all the way), with and without ``geometry_tolerance``,
    interleaved ``repeats`` times: rows (what, us)."""
    model = Manipulator.paper()
    mt = cached_map(model, 1)
    t = np.linspace(0.0, 2.0 * np.pi, n)
    X = np.stack([0.5 + 0.1 * np.cos(t), 0.2887 + 0.1 * np.sin(t), 0.2 * np.sin(2.0 * t)], axis=-1)
    q = ik(model, X, 1)
    med = {0.0: [], tol: []}
    certain = {0.0: 0, tol: 0}
    for _ in range(repeats):
        for gt in (0.0, tol):
            tracker = Tracker(model, mt, joint_tolerance=1e-4, geometry_tolerance=gt)
            _, c, _, secs = run_stream(tracker, q, X[0], DT)
            med[gt].append(float(np.median(secs[1:])))
            certain[gt] = int(c[1:].sum())
    a, b = float(np.median(med[0.0])) * 1e6, float(np.median(med[tol])) * 1e6
    return [("median step without geometry_tolerance", f"{a:.1f} us ({certain[0.0]} of {n - 1} certain)"),
            (f"median step with geometry_tolerance = {tol:g} m", f"{b:.1f} us ({certain[tol]} of {n - 1} certain)"),
            ("ratio (target <= 1.3)", f"{b / a:.2f}")]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", nargs="+", default=list(ROBOT_FILES), choices=list(ROBOT_FILES))
    ap.add_argument("--tolerances", nargs="+", type=float, default=[1e-5, 5e-5, 5e-4])
    ap.add_argument("--grades", nargs="+", default=["exact", "20-bit-2e-5", "16-bit-1e-4"])
    ap.add_argument("--draws", nargs="+", default=["uniform", "corner"], choices=["uniform", "corner"])
    ap.add_argument("--rate", type=int, default=500, help="samples per path (dt 1 ms)")
    ap.add_argument("--every", type=int, default=4, help="every n-th path of the hard suite")
    ap.add_argument("--fold-every", type=int, default=10, help="fold test on every n-th counted step")
    ap.add_argument("--out", default="results")
    ap.add_argument("--only-timing", action="store_true",
                    help="only the step time with and without the tolerance on the paper circle (section as-built-step)")
    args = ap.parse_args(argv)
    if args.only_timing:
        from report import publish, table
        rows = step_timing()
        for what, value in rows:
            print(f"{what}: {value}")
        publish("as-built-step", table(["what", "measured"], rows),
                note="The paper's robot, a 0.1 m circle with a swinging orientation, 1,000 samples, exact joints of the "
                     "model, joint_tolerance 1e-4 rad; medians of 5 interleaved runs (bench/bench_as_built.py "
                     "--only-timing).")
        return
    grades = {g.name: g for g in SENSOR_GRADES}
    rows = []
    print(" | ".join(HEADER))
    for name in args.robots:
        robot = load_robot(ROBOT_FILES[name])
        model = robot.model
        step = (robot.resolution[0], robot.resolution[0], robot.resolution[1])
        paths = hard_suite(model, samplings=(args.rate,))[::args.every]
        maps = {p: cached_map(model, p, step=step) for p in sorted({p.posture for p in paths})}
        for tol in args.tolerances:
            for draw in args.draws:
                for g in args.grades:
                    t0 = time.perf_counter()
                    r = run_config(model, maps, paths, tol, draw, grades[g], 2026, args.fold_every)
                    pct = lambda a, b: 100.0 * a / b if b else float("nan")   # noqa: E731
                    row = [robot.name, f"{tol:g}", draw, g, r["paths"], r["steps"], r["counted"], r["certain"],
                           r["silent"], f"{pct(r['holds'], r['certain']):.2f}", r["errors"],
                           f"{pct(r['alarms'], r['right']):.2f}", f"{pct(r['fold'], r['fold_n']):.2f}",
                           r["silent0"], f"{pct(r['holds0'], r['certain0']):.2f}",
                           *(f"{v:.3g}" for v in r["tight"]), f"{1e6 * r['median']:.0f}",
                           f"{1e6 * r['median0']:.0f}", f"{r['median'] / r['median0']:.2f}"]
                    rows.append(row)
                    print(" | ".join(map(str, row)), f"({time.perf_counter() - t0:.0f} s)", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "as_built.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        w.writerows(rows)
    print(f"wrote {out / 'as_built.csv'}")
    from report import publish, table
    publish("as-built", table(HEADER, rows),
            note="The robot as built (docs/as_built.md): robots drawn inside the geometric tolerance box (uniform, "
                 "corner), their joints read by the sensor grade, tracked by the model with geometry_tolerance "
                 "(and without: 'silent without'). silent: certain steps whose box misses the built robot's pose or "
                 "that are off the truth branch; fold floor: share of sampled counted steps with a fold in the joint "
                 "box widened by the geometry width; tightness: median bound / actual error; ratio: median step "
                 "over the same tracker without the tolerance on the model's own stream.")


if __name__ == "__main__":
    main()
