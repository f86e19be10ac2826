"""Which noisy samples any sound certificate must leave unvouched: folds inside the sensor's tolerance box.

    python bench/sensor_oracle.py [--suite default|hard|all] [--grade 14-bit] [--sigmas 3] [--samples 24]

A tracker fed measured joints ``q_m`` may vouch for a pose only if, for every joint vector the robot
can have within the sensor's tolerance (the box ``q_m +- joint_tolerance``), the branch it is on
reaches that box without a fold (det J = 0): otherwise the measured joints can sit past a fold the
robot never crossed, and no proof from this sample can tell.  For each counted step of
``bench_sensors.py`` (same streams, same truth) this script continues the *true* configuration
(noise-free pose and joints) to the corners, the face centres and ``--samples`` random points of that
box along straight joint segments (RK-free: Euler predictor, Newton corrector, 16 substeps) and marks
the step *foldable* when det J changes sign or Newton fails on the way.  Sampling can miss a fold, so
the share of foldable steps is a lower bound on the false alarms of any method that vouches soundly
from one sample and the tolerance.

Prints per sensor grade: counted steps, foldable steps (share), and the default tracker's false
alarms over all counted steps and over the non-foldable ones.
"""
from __future__ import annotations

import argparse

import numpy as np

from bench_sensors import run_stream
from bench_tracker import pose_errors
from experiments.sensors import SENSOR_GRADES, sensor_truth
from experiments.suite import default_suite, hard_suite
from solver import DEFAULT_RULE, DEFAULT_STEP, Manipulator, Tracker, cached_map, constraints, jacobians


def foldable(model, X_true, q_true, q_meas, eps, rng, n_random=24, substeps=16):
    """True when the branch through (X_true, q_true) meets a fold (or cannot be followed) on the way
    to some sampled joint vector of the box ``q_meas +- eps`` (3,)."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    faces = np.vstack([np.eye(3), -np.eye(3)])
    unit = np.vstack([np.zeros((1, 3)), signs, faces, rng.uniform(-1, 1, (n_random, 3))])
    targets = q_meas + eps * unit                                   # (m, 3)
    X = np.repeat(X_true[None, :], len(targets), axis=0)
    dq = (targets - q_true) / substeps
    s0 = np.sign(np.linalg.det(jacobians(model, X_true, q_true)[0]))
    for k in range(1, substeps + 1):
        q = q_true + k * dq
        J, K = jacobians(model, X, q - dq)
        X = X - np.linalg.solve(J, np.einsum("nij,nj->ni", K, dq)[..., None])[..., 0]   # Euler predictor
        for _ in range(4):                                           # Newton corrector at q
            J, _ = jacobians(model, X, q)
            X = X - np.linalg.solve(J, constraints(model, X, q)[..., None])[..., 0]
        res = np.abs(constraints(model, X, q)).max(axis=1)
        det = np.linalg.det(jacobians(model, X, q)[0])
        if np.any(~(res < 1e-10)) or np.any(np.sign(det) != s0):
            return True
    return False


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", choices=("all", "default", "hard"), default="default")
    ap.add_argument("--grades", nargs="+", default=["16-bit", "14-bit", "12-bit"])
    ap.add_argument("--sigmas", type=float, default=3.0)
    ap.add_argument("--samples", type=int, default=24)
    ap.add_argument("--speed", type=float, nargs=2, default=(3.76, 1.10), metavar=("M_PER_S", "RAD_PER_S"))
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    suite = []
    if args.suite in ("all", "default"):
        suite += default_suite(model, samplings=(1000,))
    if args.suite in ("all", "hard"):
        suite += hard_suite(model, samplings=(1000,))
    maps = {p: cached_map(model, p, DEFAULT_RULE, DEFAULT_STEP) for p in sorted({s.posture for s in suite})}
    grades = {s.name: s for s in SENSOR_GRADES}
    rng = np.random.default_rng(7)
    print(f"{len(suite)} paths at 1 kHz; tolerance {args.sigmas:g} sigma + half a step; {args.samples} random "
          f"points + 14 corners/faces per box\n")
    print("| sensor | counted steps | foldable (no sound one-sample proof) | default: false alarms, all counted | "
          "false alarms on the non-foldable steps |")
    print("|---|---|---|---|---|")
    for g in args.grades:
        sensor = grades[g]
        eps = sensor.tolerance(args.sigmas)
        n_c = n_f = fa = fa_nf = 0
        for i, path in enumerate(suite):
            stream = sensor.measure(path.q, seed=1000 + i)
            q = stream.q.copy()
            q[0] = path.q[0]
            truth, counted = sensor_truth(model, q, path.X, stream.glitch)
            tr = Tracker(model, maps[path.posture], joint_tolerance=eps, speed_bound=tuple(args.speed),
                         stuck_after=sensor.stuck_after())
            X, certain, _, _ = run_stream(tr, q, path.X[0], 1e-3)
            right = pose_errors(X, truth) <= 1e-6
            for k in np.nonzero(counted)[0]:
                if k == 0:
                    continue
                f = foldable(model, path.X[k], path.q[k], q[k], eps, rng, args.samples)
                alarm = right[k] and not certain[k]
                n_c += 1
                n_f += f
                fa += alarm
                fa_nf += alarm and not f
        print(f"| {g} | {n_c:,} | {n_f:,} ({100 * n_f / n_c:.1f} %) | {fa:,} ({100 * fa / n_c:.1f} %) | "
              f"{fa_nf:,} ({100 * fa_nf / max(n_c - n_f, 1):.1f} % of {n_c - n_f:,}) |")


if __name__ == "__main__":
    main()
