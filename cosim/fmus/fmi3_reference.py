"""The FMI 3.0 DK FMU's reference run and CSV, and ``python build_fmu.py --fmi 3`` (host side).

The run is the FMI 2.0 DK FMU's (:mod:`cosim.fmus.references`: the paper's circle in posture 1 through
the reference configuration, 40 mm / 6 deg map) with the joints as the array input ``q`` of one
``fmpy.simulate_fmu`` input table; its CSV, ``fmu_src/reference/RRRDirectKinematics3.csv``, has the
array elements as columns ``q[1]``..``q[3]``, ``pose[1]``..``pose[3]`` (Reference-FMUs style) and
the scalar outputs of the FMI 2.0 CSV.  Its numbers are those of the FMI 2.0 CSV (the tests check it).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from solver import circle_path

from ..unit import import_hygiene
from .builds import parse_resolution
from .fmi3_build import DK3_NAME, build_dk3
from .references import INT_COLUMNS, OUTPUTS, REFERENCE, circle_joints, write_csv
from .sources import REFERENCE_DIR

__all__ = ["SCALARS", "COLUMNS", "run_circle3", "write_reference3", "main3"]

#: the scalar outputs of the reference CSV (those of the FMI 2.0 CSV but the pose)
SCALARS = tuple(n for n in OUTPUTS if n not in ("x", "y", "phi"))
#: the CSV columns
COLUMNS = ("time", "q[1]", "q[2]", "q[3]", "pose[1]", "pose[2]", "pose[3]", *SCALARS)


def run_circle3(fmu, n: int = REFERENCE["n"], h: float = REFERENCE["h"], posture: int = 1, outputs=None):
    """The circle through the FMI 3.0 ``fmu`` with ``fmpy.simulate_fmu``: ``q`` an array column of
    the input table, ``pose0`` the circle's first point.  Row 0 is the initial pose, row k + 1 the
    pose for q[k].  Raises RuntimeError when the result stops early.  fmpy's structured array."""
    import fmpy

    q = circle_joints(n, posture)
    table = np.zeros(n, dtype=[("time", np.float64), ("q", np.float64, (3,))])
    table["time"] = np.arange(n) * h
    table["q"] = q
    X0 = circle_path(n)[0]
    with import_hygiene():
        result = fmpy.simulate_fmu(str(fmu), stop_time=n * h, step_size=h, output_interval=h, input=table,
                                   start_values={"pose0": [float(v) for v in X0], "posture": posture},
                                   output=list(outputs or ("q", "pose", *SCALARS)), fmi_type="CoSimulation")
    if len(result) != n + 1:
        raise RuntimeError(f"{Path(fmu).name}: the circle stopped at t={float(result['time'][-1])!r} of {n * h!r}")
    return result


def _flat(result: np.ndarray) -> np.ndarray:
    """The result with the array fields as columns ``name[i]`` (1-based)."""
    rows = np.zeros(len(result), dtype=[(c, np.float64) for c in COLUMNS])
    for c in COLUMNS:
        name, _, index = c.partition("[")
        rows[c] = result[name][:, int(index[:-1]) - 1] if index else result[name]
    return rows


def write_reference3(result: np.ndarray, path=None) -> Path:
    """Write the reference CSV (default ``fmu_src/reference/RRRDirectKinematics3.csv``)."""
    path = Path(path) if path else REFERENCE_DIR / f"{DK3_NAME}.csv"
    header = [
        "RRRDirectKinematics3 (FMI 3.0) reference run: the paper's circle, solver.circle_path(1000) -> solver.ik "
        "posture 1, as the array input q,",
        "q[k] applied at t = k*h through fmpy.simulate_fmu; pose0 = circle_path(1000)[0]; map 40 mm / 6 deg, "
        f"posture 1, mode default; h = {REFERENCE['h']!r} s; n = {REFERENCE['n']}.",
        "The numbers equal those of RRRDirectKinematics.csv (the FMI 2.0 FMU); regenerate: "
        "python build_fmu.py --fmi 3 --write-reference",
    ]
    return write_csv(path, _flat(result), COLUMNS, header, INT_COLUMNS["RRRDirectKinematics"])


def main3(args, robot=None) -> int:
    """``python build_fmu.py --fmi 3 [...]``: build ``<out>/fmi3/RRRDirectKinematics.fmu``, validate it and
    run the reference (``--no-reference`` skips it; ``--write-reference`` rewrites the kept CSV only)."""
    unsupported = [o for o, used in (("--only", args.only_given), ("--ssp", args.ssp),
                                     ("--manipulator 3rpr", args.manipulator != "3rrr")) if used]
    if unsupported:
        raise ValueError(f"--fmi 3: {', '.join(unsupported)}: the FMI 3.0 build is the 3-RRR's DK FMU alone")
    out = Path(args.out) / "fmi3"
    if not args.write_reference:
        resolution = None if args.resolution is None else parse_resolution(args.resolution)
        postures = args.posture if args.posture is not None else ([] if args.map else
                                                                   [robot.home_posture if robot else 1])
        result = build_dk3(out, postures=postures, resolution=resolution, map_files=args.map, mode=args.mode,
                           rule=args.rule, progress=None, robot=robot)
        print(f"{result.fmu}: {result.size / 1e6:.3f} MB ({result.size:,} bytes), FMI 3.0, postures "
              f"{sorted(result.maps)} (start {result.posture}), mode {result.mode}; built in {result.seconds:.1f} s")
        if result.problems:
            print("validation: FAILED\n  " + "\n  ".join(result.problems))
            return 1
        print("validation: OK (fmpy.validation reports nothing)")
        if args.no_reference:
            return 0
    t0 = time.perf_counter()
    ref = build_dk3(out / "reference", postures=(REFERENCE["posture"],), resolution=REFERENCE["resolution"],
                    mode=REFERENCE["mode"], rule=REFERENCE["rule"], cache_dir=Path(args.out) / "maps",
                    log=lambda m: print(m, file=sys.stderr))
    if ref.problems:
        print("reference FMU validation: FAILED\n  " + "\n  ".join(ref.problems))
        return 1
    path = write_reference3(run_circle3(ref.fmu), None if args.write_reference else out / "reference"
                            / f"{DK3_NAME}.csv")
    kept = REFERENCE_DIR / path.name
    same = path.resolve() == kept.resolve() or (kept.is_file() and kept.read_bytes() == path.read_bytes())
    print(f"{path}: {'equal to' if same else 'DIFFERS from'} the kept fmu_src/reference/{path.name} "
          f"(reference run {time.perf_counter() - t0:.1f} s)")
    return 0
