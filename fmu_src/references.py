"""Reference runs of the plant and controller FMUs (Reference-FMUs style), and their readme tables.

    python -m fmu_src.references [--build-dir build]     # rewrite fmu_src/reference/<FMU>.csv

Each FMU has one reference run, defined here once and used both to write the CSV kept in
``fmu_src/reference/`` and by the tests that simulate the built FMU and compare:

* ``RRRPlant``: from rest at the circle's first point, smooth motor torques
  ``tau(t) = (0.05 sin 3t, -0.04 cos 2t, 0.03 sin 5t)`` N m, 0.5 s at h = 1 ms;
* ``ComputedTorqueController``: fed its own reference (q = q_d, dq = dq_d, pose = X_d along the
  circle), so its torque is the inverse dynamics of the reference motion; 0.5 s at h = 1 ms.

The runs go through ``fmpy.simulate_fmu`` (:func:`fmu_src.fmi_build.simulate`).  This module runs
on the host (it is not bundled into the FMUs).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REFERENCE_DIR = HERE / "reference"
H = 1e-3
N = 500


def _plant_inputs():
    t = np.arange(N + 1) * H
    return t, {"tau1": 0.05 * np.sin(3 * t), "tau2": -0.04 * np.cos(2 * t), "tau3": 0.03 * np.sin(5 * t)}


def _controller_inputs():
    from dynamics.trajectory import CircleTrajectory
    from solver import Manipulator

    model = Manipulator.paper()
    traj = CircleTrajectory()
    t = np.arange(N + 1) * H
    X, _, _ = traj.task(t)
    q, dq, _ = traj.joint(model, t)
    names = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi")
    cols = np.concatenate([q, dq, X], axis=1)
    return t, {n: cols[:, i] for i, n in enumerate(names)}


def _start_values():
    from solver import PAPER_CIRCLE

    c, r, phi = PAPER_CIRCLE["center"], PAPER_CIRCLE["radius"], PAPER_CIRCLE["phi"]
    return {"x0": c[0] + r, "y0": c[1], "phi0": phi}


#: name -> (inputs(), start values(), description)
RUNS = {
    "RRRPlant": (_plant_inputs, _start_values,
                 "RRRPlant from rest at the circle's first point (x0, y0, phi0 = (0.70, 0.30, -pi/4)); "
                 "tau(t) = (0.05 sin 3t, -0.04 cos 2t, 0.03 sin 5t) N m"),
    "ComputedTorqueController": (_controller_inputs, dict,
                                 "ComputedTorqueController fed its own reference (q = q_d, dq = dq_d, "
                                 "pose = X_d on the circle): tau is the inverse dynamics of the reference"),
}


def run(name: str, fmu) -> np.ndarray:
    """Simulate the reference run of FMU ``name`` (the built file ``fmu``); fmpy's result array."""
    from fmu_src.fmi_build import input_table, simulate

    inputs, start, _ = RUNS[name]
    t, signals = inputs()
    return simulate(fmu, stop_time=N * H, step_size=H, inputs=input_table(t, **signals),
                    start_values=start())


def write(name: str, result: np.ndarray, path=None) -> Path:
    """Write ``result`` as the reference CSV of ``name`` (full precision, a commented header)."""
    path = Path(path) if path else REFERENCE_DIR / f"{name}.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    names = result.dtype.names
    lines = [f"# {RUNS[name][2]}", f"# h = {H!r} s, {N} steps, fmpy.simulate_fmu; regenerate: "
             f"python -m fmu_src.references", ",".join(names)]
    for row in result:
        lines.append(",".join(repr(float(row[n])) for n in names))
    path.write_text("\n".join(lines) + "\n")
    return path


def read(name: str, path=None) -> np.ndarray:
    """The reference CSV of ``name`` as a structured float array."""
    path = Path(path) if path else REFERENCE_DIR / f"{name}.csv"
    body = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    names = body[0].split(",")
    return np.array([tuple(float(c) for c in ln.split(",")) for ln in body[1:]],
                    dtype=[(n, np.float64) for n in names])


def variable_table(cls) -> str:
    """The Markdown table of a slave class's variables (the readmes embed it; a test compares)."""
    rows = ["| name | causality | type | variability | unit | start | depends on | description |",
            "|---|---|---|---|---|---|---|---|"]
    for v in getattr(cls, "_table", cls.VARIABLES):          # normalised by the base class
        deps = "" if v.causality != "output" else (", ".join(v.depends_on) if v.depends_on else "none")
        start = "" if v.start is None else f"{v.start:g}" if isinstance(v.start, float) else str(v.start)
        rows.append(f"| `{v.name}` | {v.causality} | {v.type} | {v.variability or ''} | {v.unit or ''} | "
                    f"{start} | {deps} | {v.description} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default="build")
    args = ap.parse_args(argv)
    import subprocess
    import sys

    from dynamics.cosim import build_fmus
    paths = build_fmus(args.build_dir)
    # each simulation in its own process: a process loads each FMU once (dynamics.cosim.FMUUnit)
    for name in RUNS:
        code = (f"from fmu_src import references as r; "
                f"print(r.write({name!r}, r.run({name!r}, {str(paths[name])!r})))")
        subprocess.run([sys.executable, "-c", code], check=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
