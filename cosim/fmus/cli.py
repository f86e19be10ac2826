"""``python build_fmu.py`` (also ``python -m cosim.fmus.cli``): build the three FMUs and their reference CSVs.

    python build_fmu.py [--out build] [--posture 1 [2 ...]] [--resolution 10mm,2deg]
                        [--map FILE [FILE ...]] [--mode default|paper] [--rule real-phi]
                        [--only NAME [NAME ...]] [--no-reference] [--ssp]
    python build_fmu.py --write-reference      # regenerate fmu_src/reference/<FMU>.csv
    python build_fmu.py --manipulator 3rpr [--resolution 25mm,3deg] [--no-reference | --write-reference]
    python build_fmu.py --fmi 3 [--posture ...] [--resolution ...] [--mode ...] [--no-reference | --write-reference]
    python build_fmu.py --robot FILE [--posture ...] [--resolution ...] [--mode ...] [--out DIR]

1. The FMUs (:mod:`cosim.fmus.builds`) are built into ``--out`` and validated: ``RRRDirectKinematics``
   with the map tensor(s) of ``--posture`` at ``--resolution`` (cached in the project's map cache,
   ``solver.cache_dir("maps")``, which ``$RRR_DK_CACHE`` moves) or the
   ``--map`` files, ``--mode`` and ``--posture`` as start values of its parameters;
   ``ComputedTorqueController`` and ``RRRPlant``.  ``--only`` builds some of them.
2. The reference run of each FMU (:mod:`cosim.fmus.references`) is built into ``<out>/reference/`` (an
   FMU that step 1 built with the reference's options is run as it is: builds are deterministic) and
   written as ``<out>/reference/<FMU>.csv``; each is compared with the kept
   ``fmu_src/reference/<FMU>.csv`` (the tests compare with those).  ``--no-reference`` skips it.

3. ``--ssp``: the closed loop of the three FMUs in ``--out`` as the SSP 1.0 package
   ``<out>/RRRClosedLoop.ssp`` (the FMUs inside, the connections and the default scenario's start
   values; :func:`cosim.hosts.system_files.write_ssp_system`), checked against the SSP 1.0
   schemas when ``pyssp-standard`` is installed (:func:`cosim.hosts.ssp.schema_problems`).

``--manipulator 3rpr`` builds the cuspidal 3-RPR's DK FMU instead, ``RPRDirectKinematics``
(:mod:`cosim.fmus.rpr_build`; leg lengths in, pose out; map at ``--resolution``, default 25 mm, 3 deg),
and its reference run (the loop around a cusp) against ``fmu_src/reference/RPRDirectKinematics.csv``.

``--fmi 3`` builds the DK FMU for FMI 3.0 instead, ``<out>/fmi3/RRRDirectKinematics.fmu`` (modelIdentifier
``RRRDirectKinematics3``; :mod:`cosim.fmus.fmi3_build`, the same map options), and its reference run against
``fmu_src/reference/RRRDirectKinematics3.csv`` (:mod:`cosim.fmus.fmi3_reference`).

``--robot FILE`` builds the FMUs of the robot that ``FILE`` describes (a TOML file, docs/robots.md;
:func:`solver.robot.load_robot` checks it before any work and a bad file ends the command with the
reason, exit status 2): the DK FMU with maps of its geometry (cached by its digest) at
``--resolution`` (default the robot's) and start values from its home pose; the plant and the
controller with its ``[dynamics]`` (required for them) and its reference circle; each carries the
description in ``resources/``.  No reference runs (those are the paper robot's); ``--ssp`` writes the
loop of these FMUs.

``--write-reference`` does step 2 only and rewrites the kept CSVs.  Same options and the same map
files give byte-identical FMUs.  ``--resolution`` accepts ``"10mm,2deg"``, ``"0.04m 6deg"``,
``"1cm,0.035rad"`` or two bare numbers (mm, deg): ``40 6``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from solver import DEFAULT_RULE, ORDERING_RULES, MapTensorFileError

from .sources import REFERENCE_DIR
from .builds import DK_NAME, FMU_NAMES, MODES, build_dk, build_slave, parse_resolution
from .early_compile import lower_priority
from ..unit import exit_process

__all__ = ["main"]

_KEPT = REFERENCE_DIR


def _parser(default_out) -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python build_fmu.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(default_out), help=f"output folder (default {default_out})")
    ap.add_argument("--posture", type=int, nargs="+", default=None,
                    help="posture(s) 1..8 to embed; the first is the parameter's start value (default 1)")
    ap.add_argument("--resolution", nargs="+", default=None,
                    help="map node spacing: '10mm,2deg' (default), '0.04m 6deg' or two numbers in mm and deg")
    ap.add_argument("--map", nargs="+", default=(), metavar="FILE", help="embed these map files (no rebuild)")
    ap.add_argument("--mode", choices=MODES, default="default", help="start value of the parameter 'mode'")
    ap.add_argument("--rule", choices=sorted(ORDERING_RULES), default=DEFAULT_RULE,
                    help="ordering rule of maps built here")
    ap.add_argument("--only", nargs="+", choices=FMU_NAMES, default=FMU_NAMES, metavar="NAME",
                    help=f"build only these FMUs ({', '.join(FMU_NAMES)})")
    ap.add_argument("--no-reference", action="store_true", help="do not run and write the reference CSVs")
    ap.add_argument("--write-reference", action="store_true",
                    help="build the reference configurations and rewrite fmu_src/reference/<FMU>.csv")
    ap.add_argument("--ssp", action="store_true",
                    help="also write <out>/RRRClosedLoop.ssp, the closed loop of the three FMUs (SSP 1.0)")
    ap.add_argument("--manipulator", choices=("3rrr", "3rpr"), default="3rrr",
                    help="3rpr: build RPRDirectKinematics.fmu (the cuspidal 3-RPR's DK) instead of the three")
    ap.add_argument("--robot", metavar="FILE", default=None,
                    help="a robot description (TOML, docs/robots.md): build the DK FMU of that robot")
    ap.add_argument("--fmi", choices=("2", "3"), default="2",
                    help="3: build the DK FMU for FMI 3.0 instead, <out>/fmi3/RRRDirectKinematics.fmu (pythonfmu3)")
    ap.add_argument("--background", action="store_true",
                    help="a build beside the DK's early compile (what build_fmus runs): lower this process's "
                         "priority, a plant's or controller's build at once, the DK's once its compile has begun")
    return ap


def _rpr(args, robot=None) -> int:
    """``--manipulator 3rpr`` (or ``--robot`` of a 3-RPR): the 3-RPR's DK FMU and its reference run; the exit
    status."""
    from .rpr_build import (RPR_NAME, RPR_REFERENCE_RESOLUTION, RPR_RESOLUTION, build_rpr_dk, run_rpr_loop,
                            write_rpr_reference)

    given = [opt for opt, used in (("--posture", args.posture is not None), ("--map", bool(args.map)),
                                   ("--mode", args.mode != "default"), ("--only", list(args.only) != list(FMU_NAMES)),
                                   ("--ssp", args.ssp)) if used]
    if given:
        raise ValueError(f"--manipulator 3rpr: {', '.join(given)}: not for the 3-RPR (one posture, its own map, the "
                         "DK FMU alone; the closed loop is the 3-RRR's)")
    out = Path(args.out)
    if not args.write_reference:
        resolution = ((None if robot is not None else RPR_RESOLUTION) if args.resolution is None
                      else parse_resolution(args.resolution))
        result = build_rpr_dk(out, resolution=resolution, rule=args.rule, robot=robot)
        print(f"{result.fmu}: {result.size / 1e6:.3f} MB; built in {result.seconds:.1f} s "
              f"(map {result.map_seconds:.1f} s)")
        if result.problems:
            print("validation: FAILED\n  " + "\n  ".join(result.problems))
            return 1
        print("validation: OK (fmpy.validation + cosim.fmus.checks.validate report nothing)")
        if args.no_reference:
            return 0
    ref = build_rpr_dk(out / "reference", resolution=RPR_REFERENCE_RESOLUTION)
    if ref.problems:
        print("reference FMU validation: FAILED\n  " + "\n  ".join(ref.problems))
        return 1
    path = write_rpr_reference(run_rpr_loop(ref.fmu), None if args.write_reference else out / "reference"
                               / f"{RPR_NAME}.csv")
    kept = _KEPT / path.name
    same = path.resolve() == kept.resolve() or (kept.is_file() and kept.read_bytes() == path.read_bytes())
    print(f"{path}: {'equal to' if same else 'DIFFERS from'} the kept fmu_src/reference/{path.name}")
    return 0


def _robot(args):
    """``--robot FILE``: the checked description (None without it); refuses what it cannot build."""
    if args.robot is None:
        return None
    from solver.robot import load_robot

    robot = load_robot(args.robot)               # RobotDescriptionError (a ValueError): the reason, exit 2
    if args.write_reference:
        raise ValueError("--robot: --write-reference rewrites the shipped robots' kept reference runs only")
    args.manipulator = "3rpr" if robot.kind == "3-RPR" else "3rrr"      # the description says which
    if robot.kind == "3-RPR":
        args.no_reference = True
        return robot
    if any(n != DK_NAME for n in args.only):     # the plant and the controller need [dynamics]: checked now
        from dynamics import DynamicParameters

        DynamicParameters.from_robot(robot, "the plant and the controller FMUs (--only RRRDirectKinematics "
                                            "builds the DK FMU alone)")
    args.no_reference = True                     # the reference runs are the paper robot's
    return robot


def _build(args, robot=None) -> tuple[int, dict]:
    """Step 1 (see the module docstring); the exit status and what was built ({FMU name: the DK's
    :class:`BuildResult` or the path of the plant's or controller's FMU})."""
    status = 0
    built = {}
    for name in args.only:
        if name == DK_NAME:
            resolution = None if args.resolution is None else parse_resolution(args.resolution)
            postures = args.posture if args.posture is not None else ([] if args.map else
                                                                       [robot.home_posture if robot else 1])
            result = build_dk(args.out, postures=postures, resolution=resolution, map_files=args.map,
                              mode=args.mode, rule=args.rule, progress=None, robot=robot,
                              background=args.background)
            print(f"{result.fmu}: {result.size / 1e6:.3f} MB ({result.size:,} bytes), postures "
                  f"{sorted(result.maps)} (start {result.posture}), mode {result.mode}; built in "
                  f"{result.seconds:.1f} s (maps {result.map_seconds:.1f} s)")
            problems = result.problems
            built[name] = result
        else:
            t0 = time.perf_counter()
            if args.background:
                lower_priority()
            fmu = build_slave(name, args.out, robot=robot)
            built[name] = fmu
            print(f"{fmu}: {fmu.stat().st_size / 1e6:.3f} MB; built in {time.perf_counter() - t0:.1f} s")
            problems = []                          # build_slave validates (BuildError on a problem)
        if problems:
            print("validation: FAILED\n  " + "\n  ".join(problems))
            status = 1
        else:
            print("validation: OK (fmpy.validation + cosim.fmus.checks.validate report nothing)")
    return status, built


def _reusable(args, built: dict) -> dict:
    """Of ``built`` (step 1's), the FMUs built with the reference runs' options (the paper's robot; the DK of
    posture 1 alone at the reference resolution, mode and rule), which step 2 runs instead of building them
    again."""
    from .references import REFERENCE

    built = dict(built)
    dk = built.get(DK_NAME)
    if dk is not None:
        same = (not args.map and sorted(dk.maps) == [REFERENCE["posture"]] and dk.mode == REFERENCE["mode"] and args.rule == REFERENCE["rule"]
                and args.resolution is not None
                and all(abs(a - b) <= 1e-12 * b for a, b in zip(parse_resolution(args.resolution),
                                                                REFERENCE["resolution"])))
        if not same:
            del built[DK_NAME]
    return built


def _references(out, csv_dir, built=None) -> None:
    """Step 2 (see the module docstring)."""
    from .references import write_references

    t0 = time.perf_counter()
    paths = write_references(out, csv_dir, built=built)
    for path in paths.values():
        kept = _KEPT / path.name
        if path.resolve() == kept.resolve():
            note = ""
        elif kept.is_file() and kept.read_bytes() == path.read_bytes():
            note = f"; equal to the kept fmu_src/reference/{path.name}"
        else:
            note = f"; DIFFERS from the kept fmu_src/reference/{path.name}"
        print(f"{path}: {len(path.read_text().splitlines())} lines{note}")
    print(f"reference runs in {time.perf_counter() - t0:.1f} s")


def _ssp(out) -> int:
    """Step 3 (see the module docstring); the exit status."""
    from ..hosts.ssp import SchemaUnavailable, schema_problems
    from ..hosts.system_files import write_closed_loop_ssp

    path = Path(write_closed_loop_ssp(Path(out)))
    print(f"{path}: {path.stat().st_size / 1e6:.3f} MB")
    try:
        problems = schema_problems(path)
    except SchemaUnavailable as exc:
        print(f"SSP schema check skipped: {exc}")
        return 0
    if problems:
        print("SSP 1.0 schema: FAILED\n  " + "\n  ".join(problems))
        return 1
    print("SSP 1.0 schema: OK (SystemStructureDescription.xsd, SystemStructureParameterValues.xsd)")
    return 0


def main(argv=None, default_out="build") -> int:
    """The command line (see the module docstring); returns the exit status."""
    args = _parser(default_out).parse_args(argv)
    try:
        robot = _robot(args)                     # a bad description: refused before any work
        if args.fmi == "3":
            from .fmi3_reference import main3

            args.only_given = list(args.only) != list(FMU_NAMES) and list(args.only) != [DK_NAME]
            return main3(args, robot)
        if args.manipulator == "3rpr":
            return _rpr(args, robot)
        if args.write_reference:
            _references(args.out, _KEPT)
            return 0
        status, built = _build(args, robot)
        if status == 0 and not args.no_reference:
            _references(args.out, Path(args.out) / "reference", _reusable(args, built))
        if status == 0 and args.ssp:
            status = _ssp(args.out)
    except (ValueError, MapTensorFileError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return status


if __name__ == "__main__":
    exit_process(main())
