"""``python -m cosim``: build the FMUs (if needed), run the closed loop, write results/.

The first run builds the three FMUs at once (the DK's map tensor and kernels; the controller's and
the plant's kernels beside them) and compiles their kernels once (the loop in this process then loads
the same ones, :mod:`solver.shared_kernels`): about 2.5 minutes on 2 cores, most of it the DK's
C entry point, compiled beside the map (:mod:`cosim.fmus.early_compile`); it says so, phase by phase,
on stderr.  Later runs reuse both and take a few seconds.

Runs the default scenario (the robot starts at rest on the circle and follows it for 2.5 s at a
1 ms step, Gauss-Seidel master; options below change it); ``--robot FILE`` runs the loop of the robot
that file describes (docs/robots.md) on its own reference circle, writes ``<out>/closed_loop.csv`` and the
plots in ``<out>/figures/``, and prints the tracking metrics.  The FMUs are built into
``--build-dir`` by :func:`cosim.fmus.fmu_set.build_fmus` when missing or stale, and packed with the
closed loop's system structure into ``<build-dir>/RRRClosedLoop.ssp``.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

from cosim.fmus.fmu_set import build_fmus
from cosim.fmus.robot_build import loop_robot
from solver.progress import phase
from cosim.unit import exit_process

from .loop.master import ClosedLoop
from .loop.results import plot_closed_loop, write_csv
from .loop.scenario import ORDERS, Scenario, robot_scenario
from .hosts.system_files import write_closed_loop_ssp


#: A closed-loop phase longer than this (s) compiled kernels: the default scenario runs in about 1 s.
_COMPILED_AFTER = 10.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cosim", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", metavar="FILE", default=None,
                    help="a robot description (TOML, docs/robots.md; with [dynamics]): the loop of that robot on "
                         "its reference circle (default: the paper's robot, robots/paper-3rrr.toml)")
    ap.add_argument("--build-dir", default=None, metavar="DIR",
                    help="folder of the FMUs, built there when missing or stale (default: build, or "
                         "build/robots/<name>-<digest> for --robot)")
    ap.add_argument("--out", default=None, metavar="DIR",
                    help="folder of closed_loop.csv and figures/ (default: results, or results/<name> for --robot)")
    ap.add_argument("--rebuild", action="store_true", help="rebuild the FMUs even if present")
    ap.add_argument("--h", type=float, default=Scenario.h, metavar="SECONDS",
                    help=f"communication step of the master, s (default {Scenario.h:g})")
    ap.add_argument("--t-end", type=float, default=Scenario.t_end, metavar="SECONDS",
                    help=f"simulated time, s (default {Scenario.t_end:g})")
    ap.add_argument("--order", default=Scenario.order, choices=ORDERS,
                    help="master algorithm: gauss-seidel (DK, controller, plant in turn; default), jacobi, "
                         "or omsimulator (OMSimulator's fixed-step master's order)")
    ap.add_argument("--plant-mass-scale", type=float, default=1.0, metavar="FACTOR",
                    help="factor on the plant's (the real robot's) default masses; the controller's model "
                         "keeps its own: a model error (default 1)")
    ap.add_argument("--no-plots", action="store_true", help="write the CSV only, no PNG plots")
    args = ap.parse_args(argv)
    try:
        robot = loop_robot(args.robot, "the closed loop (its plant and controller)")
    except ValueError as exc:                     # a bad description: the reason, no traceback, nothing built
        print(f"error: {exc}", file=sys.stderr)
        return 2
    build_dir = args.build_dir or ("build" if robot is None else f"build/robots/{robot.name}-{robot.digest}")
    paths = build_fmus(build_dir, force=args.rebuild, robot=robot)
    print(f"wrote {write_closed_loop_ssp(build_dir)} (the closed loop as SSP 1.0, for Ecos and SSP tools)")
    sc = robot_scenario(robot, h=args.h, t_end=args.t_end, order=args.order, plant_mass_scale=args.plant_mass_scale)
    with phase(f"simulating {sc.t_end:g} s of the closed loop", "the first run compiles the FMUs' kernels: "
               "about 1 min, once", after=2.0) as ran:
        with ClosedLoop(paths) as loop:
            res = loop.run(sc)
    out = Path(args.out or ("results" if robot is None else f"results/{robot.name}"))
    csv_path = write_csv(res, out / "closed_loop.csv")
    print(f"wrote {csv_path} ({len(res.t)} rows)")
    if not args.no_plots:
        for p in plot_closed_loop(res, out / "figures"):
            print(f"wrote {p}")
    m = res.metrics()
    print(f"scenario: {asdict(sc)}")
    print(f"RMS joint tracking error after 0.5 s: {m['rms_joint_error_after_0.5s']:.3e} rad")
    print(f"largest |DK pose - true pose|: {m['max_dk_vs_true']:.3e}; DK status not ok at "
          f"{m['dk_status_nonzero']} steps")
    compiled = ran.seconds > _COMPILED_AFTER
    print(f"closed loop: {sc.t_end:g} s simulated in {m['wall_seconds']:.2f} s wall "
          f"({m['realtime_factor']:.1f}x real time" + ("; this run compiled the FMUs' kernels: run it again "
                                                        "for the steady speed)" if compiled else ")"))
    return 0


if __name__ == "__main__":
    exit_process(main())
