"""Command line of the solver: ``python -m solver --help``.

Subcommands
-----------
dk Q1 Q2 Q3        all six direct-kinematics solutions of one joint vector (rad)
ik X Y PHI         the motor angles in each of the 8 postures
example            the paper's Fig. 11 experiment: a pose, its joints, all DK solutions back
build              procedure 1: map tensors into the map cache (built, or reused if there)
inspect FILE       what a map tensor file holds (regions, counts, size)
plot FILE          slices of a map tensor file as PNG
figures            the paper's Figs 13-18 as PNG (cross-sections with singular curves, the circle)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from . import (DEFAULT_RULE, DEFAULT_STEP, ORDERING_RULES, Manipulator, MapTensor, cached_map, dk_all, ik,
               posture_of, singularity_measures)
from .mapcache import DEFAULT_CACHE_DIR

#: A pose of posture 1 whose joint vector has six real DK solutions (Fig. 11 style example).
EXAMPLE_POSE = (0.8, 0.0, float(np.deg2rad(15.0)))


def _fmt(z: complex) -> str:
    if z.imag == 0.0:
        return f"{z.real:+.9f}"
    return f"{z.real:+.6f}{z.imag:+.6f}j"


def print_solutions(model: Manipulator, q, rule: str, out=sys.stdout) -> None:
    sol = dk_all(model, q, rule=rule)
    print(f"q = ({q[0]:+.9f}, {q[1]:+.9f}, {q[2]:+.9f}) rad; rule {rule!r}: "
          f"{int(sol.n_real)} real, {6 - int(sol.n_real)} complex", file=out)
    print(f"{'#':>2}  {'kind':7} {'x [m]':>24} {'y [m]':>24} {'phi [rad]':>24}  posture  type1", file=out)
    for k in range(6):
        X = sol.poses[k]
        kind = "real" if sol.real[k] else "complex"
        extra = ""
        if sol.real[k]:
            Xr = X.real
            extra = (f"  {int(posture_of(model, Xr, q)):7d}  "
                     f"{float(singularity_measures(model, Xr, q).type1):.3g}")
        print(f"{k + 1:>2}  {kind:7} {_fmt(X[0]):>24} {_fmt(X[1]):>24} {_fmt(X[2]):>24}{extra}", file=out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m solver", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rule", default=DEFAULT_RULE, choices=sorted(ORDERING_RULES),
                        help="ordering rule that numbers the DK solutions")
    sub = parser.add_subparsers(dest="cmd")
    p = sub.add_parser("dk", help="all DK solutions of a joint vector")
    p.add_argument("q", nargs=3, type=float, metavar="Q")
    p = sub.add_parser("ik", help="IK of a pose in all 8 postures")
    p.add_argument("X", nargs=3, type=float, metavar="X")
    p = sub.add_parser("build", help="procedure 1: map tensors into the map cache")
    p.add_argument("--posture", type=int, nargs="+", default=[1], help="postures 1..8 (default 1)")
    p.add_argument("--step-mm", type=float, default=DEFAULT_STEP[0] * 1e3, help="x/y node spacing, mm")
    p.add_argument("--step-deg", type=float, default=float(np.rad2deg(DEFAULT_STEP[2])),
                   help="phi node spacing, degrees")
    p.add_argument("--out", default=str(DEFAULT_CACHE_DIR),
                   help=f"the map cache folder (default {DEFAULT_CACHE_DIR}; file names: solver.mapcache)")
    p = sub.add_parser("inspect", help="describe a map tensor file")
    p.add_argument("file")
    p = sub.add_parser("plot", help="plot slices of a map tensor file")
    p.add_argument("file")
    p.add_argument("--phi", type=float, nargs="+", default=[-60.0, 0.0, 60.0], help="degrees")
    p.add_argument("--out", default="results/figures")
    p = sub.add_parser("figures", help="the paper's Figs 13-18")
    p.add_argument("--posture", type=int, default=1)
    p.add_argument("--step-mm", type=float, default=4.0)
    p.add_argument("--out", default="results/figures")
    p = sub.add_parser("example", help="the paper's Fig. 11 experiment")
    p.add_argument("--pose", nargs=3, type=float, default=EXAMPLE_POSE, metavar=("X", "Y", "PHI"))
    p.add_argument("--posture", type=int, default=1)
    args = parser.parse_args(argv)
    model = Manipulator.paper()
    try:
        if args.cmd == "dk":
            print_solutions(model, np.array(args.q), args.rule)
        elif args.cmd == "ik":
            X = np.array(args.X)
            for j in range(1, 9):
                q = ik(model, X, j)
                print(f"posture {j}: q = {np.array2string(q, precision=9)} rad")
        elif args.cmd == "build":
            step = (args.step_mm / 1e3, args.step_mm / 1e3, float(np.deg2rad(args.step_deg)))
            for j in args.posture:
                mt = cached_map(model, j, args.rule, step, args.out, progress=sys.stderr.isatty(), log=print)
                print(f"  {mt.stats['nodes']:,} nodes built in {mt.stats['build_seconds']:.1f} s "
                      f"({mt.stats['nodes'] / mt.stats['build_seconds']:,.0f} nodes/s)")
        elif args.cmd == "inspect":
            mt = MapTensor.load(args.file)
            print(mt.summary())
            print(f"  file {Path(args.file).stat().st_size / 1e6:.3f} MB, labels sha256 {mt.checksum()[:16]}...")
            print(f"  near a label border (procedure 2, default radius): {100 * mt.border_fraction():.1f} % "
                  f"of reachable nodes")
        elif args.cmd == "plot":
            from experiments.figures import plot_map_slice
            mt = MapTensor.load(args.file)
            for phd in args.phi:
                print(plot_map_slice(mt, phd, args.out))
        elif args.cmd == "figures":
            from experiments.figures import plot_circle_experiment, plot_cross_sections
            from experiments.suite import NEAR_SINGULAR_SEEDS, make_path, near_singular_circle
            from .trajectories import circle_path
            for phd, (path, st) in plot_cross_sections(model, args.posture, out_dir=args.out,
                                                       step=args.step_mm / 1e3, rule=args.rule).items():
                print(f"{path}: singular nodes within one cell of a border "
                      f"{100 * st['singular_near_border']:.1f} %, border nodes singular "
                      f"{100 * st['border_singular']:.1f} %")
            mt = cached_map(model, 1, args.rule, progress=sys.stderr.isatty())
            post, centre, phd = NEAR_SINGULAR_SEEDS[0]
            radius, _ = near_singular_circle(model, post, centre, phd, 0.005)
            hard = make_path(model, f"p{post}-near-sing-5mm", post,
                             circle_path(300, centre, radius, float(np.deg2rad(phd))))
            hard_map = mt if post == 1 else cached_map(model, post, args.rule)
            for path in plot_circle_experiment(model, mt, args.out, hard_path=hard, hard_map=hard_map):
                print(path)
        else:
            X = np.array(getattr(args, "pose", EXAMPLE_POSE))
            j = getattr(args, "posture", 1)
            q = ik(model, X, j)
            print(f"{model.name}: pose X = {X.tolist()} (m, m, rad), posture {j}")
            if np.isnan(q[0]):
                print("the pose is outside the posture's tool space")
                return 1
            print_solutions(model, q, args.rule)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
