"""Cusps of the singular surface in the robots' tool spaces, and what finding them costs a build.

    python bench/bench_cusps.py [--robot FILE ...] [--step-mm 20] [--step-deg 3]

For each robot (default: ``robots/paper-3rrr.toml`` and ``robots/irregular-3rrr.toml``) and each of
its postures, :func:`solver.cusps.find_cusps` over the whole tool space (:func:`solver.default_bounds`)
at the given spacing (the build scans each map at half its resolution: 20 mm / 4 deg for a 10 mm / 2 deg
map): the grid cells flagged by the sign of g (``raw``), those confirmed (projected onto a cusp curve
with three coinciding DK solutions), the points of the singular surface sampled and the time; written as section ``cusps`` of
``docs/benchmarks.md``. Numbers, no assertions.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from solver import default_bounds  # noqa: E402
from solver.cusps import find_cusps  # noqa: E402
from solver.grid import grid_shape  # noqa: E402
from solver.robot import ROBOTS, load_robot  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", type=Path,
                    help="robot description (repeatable; default: the paper's and the irregular example)")
    ap.add_argument("--step-mm", type=float, default=20.0)
    ap.add_argument("--step-deg", type=float, default=3.0)
    args = ap.parse_args(argv)
    files = args.robot or [ROBOTS / "paper-3rrr.toml", ROBOTS / "irregular-3rrr.toml"]
    step = (args.step_mm * 1e-3, args.step_mm * 1e-3, float(np.deg2rad(args.step_deg)))
    print(f"grid {args.step_mm:g} mm / {args.step_deg:g} deg over each robot's whole tool space")
    print(f"{'robot':<16} {'posture':>7} {'nodes':>10} {'S points':>9} {'raw':>6} {'cusps':>6} {'time s':>7}  first cusp (m, m, rad)")
    rows = []
    for f in files:
        robot = load_robot(f)
        bounds = default_bounds(robot.model, step)
        shape = grid_shape(bounds, step)
        for posture in range(1, robot.model.n_postures + 1):
            t = time.perf_counter()
            scan = find_cusps(robot.model, posture, bounds, shape)
            dt = time.perf_counter() - t
            raw = find_cusps(robot.model, posture, bounds, shape, confirm=False).count
            first = np.array2string(scan.poses[0], precision=4) if scan.count else "-"
            print(f"{robot.name:<16} {posture:>7} {int(np.prod(shape)):>10} {scan.singular_points:>9} {raw:>6} "
                  f"{scan.count:>6} {dt:>7.2f}  {first}")
            rows.append([robot.name, posture, int(np.prod(shape)), scan.singular_points, raw, scan.count, f"{dt:.2f}",
                         first])
    from report import publish, table
    publish("cusps", table(["robot", "posture", "grid nodes", "singular-surface points", "flagged cells",
                            "cusp cells (confirmed)", "seconds", "first cusp (m, m, rad)"], rows),
            note=f"Cusps of the type-2 singular surface (solver.cusps.find_cusps) over each robot's whole tool space "
                 f"at {args.step_mm:g} mm / {args.step_deg:g} deg (docs/robots.md, 'Cusps').")


if __name__ == "__main__":
    main()
