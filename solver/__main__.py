"""Command line of the solver: ``python -m solver --help``.

Subcommands
-----------
dk Q1 Q2 Q3        all six direct-kinematics solutions of one joint vector (rad)
ik X Y PHI         the motor angles in each of the 8 postures
example            the paper's Fig. 11 experiment: a pose, its joints, all DK solutions back
build              procedure 1: map tensors into the map cache (built, or reused if there)
inspect FILE...    what map tensor files hold (regions, counts, size)

The map cache is ``$RRR_DK_CACHE/maps``, else ``~/.cache/rrr-dk/maps`` (``$XDG_CACHE_HOME``
replaces ``~/.cache``); ``build --out`` puts maps elsewhere.  Long work reports its phases and
a progress bar on stderr; ``RRR_DK_PROGRESS=0`` silences them.  The paper's figures and plots of
a map file are experiments on the library: ``python -m experiments --help``.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from . import (DEFAULT_RULE, DEFAULT_STEP, ORDERING_RULES, Manipulator, MapTensor, MapTensorFileError, cached_map,
               dk_all, ik, posture_of, singularity_measures)
from .mapcache import default_cache_dir, warm_up

DESCRIPTION = """\
Direct kinematics of the planar 3-RRR with basic regions: the kinematics of one pose or
joint vector, procedure 1's map tensors (build, inspect).  The paper's figures and plots of a
map file: python -m experiments."""
EPILOG = """\
maps are cached in $RRR_DK_CACHE/maps, else $XDG_CACHE_HOME/rrr-dk/maps, else ~/.cache/rrr-dk/maps
(build --out puts them elsewhere); long work reports its phases and a progress bar on stderr
(RRR_DK_PROGRESS=0 silences them).  Each command has its own --help."""

#: A pose of posture 1 whose joint vector has six real DK solutions (Fig. 11 style example).
EXAMPLE_POSE = (0.8, 0.0, float(np.deg2rad(15.0)))


def _fmt(z: complex) -> str:
    if z.imag == 0.0:
        return f"{z.real:+.9f}"
    return f"{z.real:+.6f}{z.imag:+.6f}j"


def print_solutions(model: Manipulator, q, rule: str, out=None) -> None:
    """A table of the six DK solutions of joints ``q`` (3,), rad, numbered by ``rule``, to ``out`` (stdout)."""
    out = sys.stdout if out is None else out
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


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m solver", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rule", default=DEFAULT_RULE, choices=sorted(ORDERING_RULES),
                        help=f"ordering rule that numbers the DK solutions (default {DEFAULT_RULE})")
    sub = parser.add_subparsers(dest="cmd", metavar="COMMAND")
    p = sub.add_parser("dk", help="all DK solutions of a joint vector")
    p.add_argument("q", nargs=3, type=float, metavar="Q", help="the motor angles q1 q2 q3, rad")
    p = sub.add_parser("ik", help="IK of a pose in all 8 postures")
    p.add_argument("X", nargs=3, type=float, metavar="X", help="the pose x y phi, m m rad")
    p = sub.add_parser("example", help="the paper's Fig. 11 experiment")
    p.add_argument("--pose", nargs=3, type=float, default=EXAMPLE_POSE, metavar=("X", "Y", "PHI"),
                   help="the pose, m m rad (default 0.8 0 0.2618: phi 15 deg)")
    p.add_argument("--posture", type=int, default=1, help="posture 1..8 of its joints (default 1)")
    p = sub.add_parser("build", help="procedure 1: map tensors into the map cache")
    p.add_argument("--posture", type=int, nargs="+", default=[1], metavar="J",
                   help="postures 1..8, one map each (default 1)")
    p.add_argument("--step-mm", type=float, default=DEFAULT_STEP[0] * 1e3,
                   help="x/y node spacing, mm (default %(default)g)")
    p.add_argument("--step-deg", type=float, default=float(np.rad2deg(DEFAULT_STEP[2])),
                   help="phi node spacing, degrees (default %(default)g)")
    p.add_argument("--out", default=None, help=f"the map cache folder (default {default_cache_dir()}; "
                                               f"file names: see solver.mapcache)")
    p = sub.add_parser("inspect", help="describe map tensor files")
    p.add_argument("file", nargs="+", help="map tensor files (.npz); each is described in turn")
    return parser


def _build(model, args) -> None:
    step = (args.step_mm / 1e3, args.step_mm / 1e3, float(np.deg2rad(args.step_deg)))
    for j in args.posture:            # the file on stdout; what is built, how fast, on stderr (solver.progress)
        cached_map(model, j, args.rule, step, args.out, log=print)


def _inspect(model, args) -> int:
    failed = 0
    for k, name in enumerate(args.file):
        if k:
            print()
        try:
            mt = MapTensor.load(name)
        except MapTensorFileError as exc:
            print(f"error: {exc}", file=sys.stderr)
            failed += 1
            continue
        print(f"{name}:\n{mt.summary()}")
        print(f"  file {Path(name).stat().st_size / 1e6:.3f} MB, labels sha256 {mt.checksum()[:16]}...")
        print(f"  near a label border (procedure 2, default radius): {100 * mt.border_fraction():.1f} % "
              f"of reachable nodes")
    return 2 if failed else 0


def _ik(model, args) -> None:
    X = np.array(args.X)
    for j in range(1, 9):
        print(f"posture {j}: q = {np.array2string(ik(model, X, j), precision=9)} rad")


def _example(model, args) -> int:
    X = np.array(getattr(args, "pose", EXAMPLE_POSE))
    j = getattr(args, "posture", 1)
    q = ik(model, X, j)
    print(f"{model.name}: pose X = {X.tolist()} (m, m, rad), posture {j}")
    if np.isnan(q[0]):
        print("the pose is outside the posture's tool space")
        return 1
    print_solutions(model, q, args.rule)
    return 0


COMMANDS = {"dk": lambda model, args: print_solutions(model, np.array(args.q), args.rule), "ik": _ik,
            "build": _build, "inspect": _inspect, "example": _example}


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 1 pose outside the tool space or output cut
    short, 2 an error)."""
    args = _parser().parse_args(argv)
    model = Manipulator.paper()
    try:
        if args.cmd not in ("build", "inspect"):            # build: cached_map does it when it builds
            warm_up(model, getattr(args, "posture", 1) if args.cmd == "example" else 1, args.rule)
        return COMMANDS.get(args.cmd, _example)(model, args) or 0
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:                      # stdout piped into a reader that stopped (``| head``)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())     # no second error at exit
        return 1


if __name__ == "__main__":
    sys.exit(main())
