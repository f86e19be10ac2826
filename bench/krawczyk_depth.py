"""How finely the joint box must be split before one Krawczyk box closes over it.

    python bench/krawczyk_depth.py [--paths p3-circle-far/1000 ...] [--grade 16-bit] [--every 25]

The tracker's one-sample certificate (:func:`solver._kernels.certify.prove_part`) proves that one
Krawczyk box about the measured solution holds exactly one solution for every joint vector of the
box ``q_m +- eps``.  On ill-conditioned stretches (1 mrad of joint noise moving phi by 0.05 rad and
more) it fails even where no fold is inside the box (``bench/sensor_oracle.py``).  For every
``--every``-th counted step of each path this script halves the joint box (``eps / 2^L``) until the
proof closes and prints how many halvings the steps needed (a box halved L times in each joint is
one of ``8^L`` parts), with the path's median and largest gain ``sum_j |J^-1 K|_phi,j`` (rad/rad)
and the smallest singular value of J along it.
"""
from __future__ import annotations

import argparse

import numpy as np

from experiments.sensors import SENSOR_GRADES, sensor_truth
from experiments.suite import default_suite, hard_suite
from solver import Manipulator, jacobians
from solver._kernels.certify import prove_part
from solver._kernels.kinematics import geometry
from solver._kernels.krawczyk import W_SIZE
from solver.direct_kinematics import kernel_constants

DEFAULT_PATHS = ("p3-circle-far/1000", "p3-circle-20mm/1000", "p1-ellipse-20mm/1000", "p4-circle-5mm/1000",
                 "p2-lissajous-2mm/1000", "paper-circle/1000")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--paths", nargs="+", default=list(DEFAULT_PATHS))
    ap.add_argument("--grade", default="16-bit")
    ap.add_argument("--every", type=int, default=25)
    ap.add_argument("--max-halvings", type=int, default=8)
    args = ap.parse_args(argv)
    model = Manipulator.paper()
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    suite = {p.name: (i, p) for i, p in enumerate(default_suite(model, samplings=(1000,))
                                                  + hard_suite(model, samplings=(1000,)))}
    sensor = {s.name: s for s in SENSOR_GRADES}[args.grade]
    eps = sensor.tolerance(3.0)
    w, xc, rho = np.empty(W_SIZE), np.empty(3), np.empty(3)
    print(f"{args.grade}, joint_tolerance {eps * 1e3:.2f} mrad; every {args.every}th counted step\n")
    print("| path | steps | halvings needed: steps | not within "
          f"{args.max_halvings} | gain phi, median / max | smallest singular value of J, median |")
    print("|---|---|---|---|---|---|")
    for name in args.paths:
        if name not in suite:
            raise SystemExit(f"--paths: no suite path {name!r}")
        i, path = suite[name]
        q = sensor.measure(path.q, seed=1000 + i).q.copy()
        q[0] = path.q[0]
        truth, counted = sensor_truth(model, q, path.X)
        need = {}
        for k in range(1, len(q), args.every):
            if not counted[k]:
                continue
            depth = None
            for L in range(args.max_halvings + 1):
                if prove_part(q[k], np.full(3, eps * 0.5 ** L), np.empty((1, 3)), np.empty((1, 3)), 0, truth[k],
                              M, l1, b, l2sq, w, xc, rho) == 1:
                    depth = L
                    break
            need[depth] = need.get(depth, 0) + 1
        J, K = jacobians(model, path.X, path.q)
        gain = np.abs(np.linalg.solve(J, K))[:, 2, :].sum(axis=1)
        smin = np.linalg.svd(J, compute_uv=False)[:, -1]
        hist = ", ".join(f"{L}: {n}" for L, n in sorted((L, n) for L, n in need.items() if L is not None))
        print(f"| {name} | {sum(need.values())} | {hist or '-'} | {need.get(None, 0)} | "
              f"{np.median(gain):.1f} / {gain.max():.1f} | {np.median(smin):.4f} |")


if __name__ == "__main__":
    main()
