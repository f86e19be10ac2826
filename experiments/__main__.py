"""Command line of the experiments: ``python -m experiments --help``.

Subcommands
-----------
figures            the paper's Figs 13-18 as PNG (cross-sections with singular curves, the circle)
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
    sub = parser.add_subparsers(dest="cmd", metavar="COMMAND", required=True)
    p = sub.add_parser("figures", help="the paper's Figs 13-18")
    p.add_argument("--posture", type=int, default=1, help="posture of Figs 13-15 (default 1)")
    p.add_argument("--step-mm", type=float, default=4.0,
                   help="node spacing of Figs 13-15's cross-sections, mm (default %(default)g)")
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


def _figures(model, args) -> None:
    warm_up(model, args.posture, args.rule)
    for phd, (path, st) in plot_cross_sections(model, args.posture, out_dir=args.out,
                                               step=args.step_mm / 1e3, rule=args.rule).items():
        print(f"{path}: singular nodes within one cell of a border {100 * st['singular_near_border']:.1f} %, "
              f"border nodes singular {100 * st['border_singular']:.1f} %")
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
        {"figures": _figures, "plot": _plot}[args.cmd](Manipulator.paper(), args)
    except (ValueError, MapTensorFileError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
