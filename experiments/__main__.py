"""Command line of the experiments: ``python -m experiments --help``.

Subcommands
-----------
figures            the paper's Figs 13-18 as PNG (cross-sections with singular curves, the circle);
                   with --robot FILE, Figs 13-15 and 16-18 of that robot (its own circle)
plot FILE          slices of a map tensor file as PNG

Both use matplotlib and the map cache of :func:`solver.cached_map` (built there when missing,
with its progress on stderr).
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from solver import DEFAULT_RULE, ORDERING_RULES, Manipulator, MapTensor, MapTensorFileError, cached_map, circle_path
from solver.mapcache import warm_up

from .figures import plot_circle_experiment, plot_cross_sections, plot_map_slice
from .suite import NEAR_SINGULAR_SEEDS, make_path, near_singular_circle


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m experiments", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rule", default=DEFAULT_RULE, choices=sorted(ORDERING_RULES),
                        help="ordering rule that numbers the DK solutions (default %(default)s)")
    parser.add_argument("--robot", metavar="FILE", default=None,
                        help="a robot description (TOML, docs/robots.md): its figures (default the paper's robot)")
    sub = parser.add_subparsers(dest="cmd", metavar="COMMAND", required=True)
    p = sub.add_parser("figures", help="the paper's Figs 13-18")
    p.add_argument("--posture", type=int, default=None, help="posture of Figs 13-15 (default 1, or the robot's "
                                                              "home posture)")
    p.add_argument("--step-mm", type=float, default=None,
                   help="node spacing of Figs 13-15's cross-sections, mm (default 4, or the robot's longest leg "
                        "reach / 300)")
    p.add_argument("--out", default="results/figures", help="folder of the PNG files (default %(default)s)")
    p = sub.add_parser("plot", help="plot slices of a map tensor file")
    p.add_argument("file", help="a map tensor file (.npz)")
    p.add_argument("--phi", type=float, nargs="+", default=[-60.0, 0.0, 60.0],
                   help="orientations of the slices, degrees; the nearest stored slice is drawn "
                        "(default -60 0 60)")
    p.add_argument("--out", default="results/figures", help="folder of the PNG files (default %(default)s)")
    return parser


def _plot(model, args) -> None:
    mt = MapTensor.load(args.file)
    for phd in args.phi:
        print(plot_map_slice(mt, phd, args.out))


def _figures(model, args, robot=None) -> None:
    posture = args.posture or (robot.home_posture if robot is not None else 1)
    step_mm = args.step_mm or (4.0 if robot is None else float(np.max(model.l1 + model.l2)) / 300.0 * 1e3)
    warm_up(model, posture, args.rule)
    for phd, (path, st) in plot_cross_sections(model, posture, out_dir=args.out,
                                               step=step_mm / 1e3, rule=args.rule).items():
        print(f"{path}: singular nodes within one cell of a border {100 * st['singular_near_border']:.1f} %, "
              f"border nodes singular {100 * st['border_singular']:.1f} %")
    if robot is not None:                  # its own circle (the near-singular path is the paper robot's)
        from solver.robot import default_circle

        step = (robot.resolution[0], robot.resolution[0], robot.resolution[1])
        circle = {**default_circle(robot), "posture": robot.home_posture}
        for path in plot_circle_experiment(model, cached_map(model, robot.home_posture, args.rule, step), args.out,
                                           circle=circle):
            print(path)
        return
    mt = cached_map(model, 1, args.rule)
    post, centre, phd = NEAR_SINGULAR_SEEDS[0]
    radius, _ = near_singular_circle(model, post, centre, phd, 0.005)
    hard = make_path(model, f"p{post}-near-sing-5mm", post, circle_path(300, centre, radius, float(np.deg2rad(phd))))
    hard_map = mt if post == 1 else cached_map(model, post, args.rule)
    for path in plot_circle_experiment(model, mt, args.out, hard_path=hard, hard_map=hard_map):
        print(path)


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 an error)."""
    args = _parser().parse_args(argv)
    try:
        robot = None
        if args.robot is not None:
            from solver.robot import load_robot

            robot = load_robot(args.robot)         # RobotDescriptionError (a ValueError): the reason, exit 2
            if robot.kind != "3-RRR":
                raise ValueError(f"--robot: {args.robot} describes a {robot.kind}; the figures are a 3-RRR's")
        model = robot.model if robot is not None else Manipulator.paper()
        if args.cmd == "figures":
            _figures(model, args, robot)
        else:
            _plot(model, args)
    except (ValueError, MapTensorFileError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
