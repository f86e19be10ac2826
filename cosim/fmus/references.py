"""Reference runs of the three FMUs (Reference-FMUs style) and their CSV files (host side).

Each FMU has one reference run, defined here once and used both to write the CSV kept in
``fmu_src/reference/`` (``python build_fmu.py --write-reference``; a plain ``python build_fmu.py``
writes them under ``<out>/reference/`` and says whether they equal the kept ones) and by the tests
that simulate the built FMU and compare:

* ``RRRDirectKinematics``: the paper's circle (``solver.circle_path(1000)`` mapped to joints by
  ``solver.ik`` in posture 1, ``q[k]`` applied at ``t = k*h``) through the reference configuration
  (:data:`REFERENCE`: posture 1, default mode, 40 mm / 6 deg map, default ordering rule);
* ``RRRPlant``: from rest at the circle's first point, smooth motor torques
  ``tau(t) = (0.05 sin 3t, -0.04 cos 2t, 0.03 sin 5t)`` N m, 0.5 s at h = 1 ms;
* ``ComputedTorqueController``: fed its own reference (q = q_d, dq = dq_d, pose = X_d along the
  circle), so its torque is the inverse dynamics of the reference motion; 0.5 s at h = 1 ms.

The runs go through ``fmpy.simulate_fmu`` (:func:`cosim.simulation.simulate`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

# the host's packages, imported before any FMU runs: the FMUs then use them (and their compiled code)
from dynamics import CircleTrajectory
from solver import DEFAULT_RULE, PAPER_CIRCLE, Manipulator, MapTensor, circle_path, ik

from .sources import REFERENCE_DIR
from .builds import DK_NAME, BuildResult, build_dk, build_slave
from ..simulation import input_table, simulate

__all__ = ["REFERENCE_DIR", "REFERENCE", "OUTPUTS", "H", "N", "RUNS", "circle_joints", "run_circle", "run",
           "start_values", "read_csv", "write_csv", "read", "write", "read_reference_csv",
           "write_references"]

#: The configuration of the DK reference run (coarse map: quick to build in the tests).
REFERENCE = {"posture": 1, "mode": "default", "resolution": (0.04, float(np.deg2rad(6.0))),
             "rule": DEFAULT_RULE, "n": 1000, "h": 1e-3}
#: Output columns of the DK reference CSV (after time and the inputs q1..q3).
OUTPUTS = ("x", "y", "phi", "region", "near_border", "n_real", "ambiguous", "status", "cond")
#: Integer (and Boolean, as 0/1) columns of each reference CSV; the others are floats.
INT_COLUMNS = {DK_NAME: ("region", "near_border", "n_real", "ambiguous", "status")}
#: Step and number of steps of the plant and controller runs.
H = 1e-3
N = 500


# ---------------------------------------------------------------------- the DK run
def circle_joints(n: int = 1000, posture: int = 1) -> np.ndarray:
    """The paper's circle (``solver.circle_path(n)``) mapped to joints by ``solver.ik`` in ``posture``."""
    q = ik(Manipulator.paper(), circle_path(n), posture)
    if np.isnan(q).any():
        raise RuntimeError("the circle leaves the tool space")
    return q


def run_circle(fmu, n: int = REFERENCE["n"], h: float = REFERENCE["h"], posture: int = 1):
    """The circle through ``fmu`` with :func:`cosim.simulation.simulate` (fmpy.simulate_fmu).

    q[k] is the input on [k*h, (k+1)*h]; result row 0 (t = 0) is the initial pose, row k + 1 the pose
    for q[k].  The initial pose is the first point of the circle.  Returns fmpy's structured array.
    """
    q = circle_joints(n, posture)
    X0 = circle_path(n)[0]
    t = np.arange(n) * h
    table = input_table(t, q1=q[:, 0], q2=q[:, 1], q3=q[:, 2])
    return simulate(fmu, stop_time=n * h, step_size=h, inputs=table,
                    start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": posture},
                    outputs=["q1", "q2", "q3", *OUTPUTS])


def _dk_header(result: BuildResult) -> list[str]:
    mt = MapTensor.load(result.maps[result.posture])
    return [
        "RRRDirectKinematics reference run: the paper's circle, solver.circle_path(1000) -> solver.ik posture 1,",
        "q[k] applied at t = k*h through fmpy.simulate_fmu; x0, y0, phi0 = circle_path(1000)[0].",
        "Row 0 is the initial pose; row k+1 the pose for q[k]; q1..q3 are the FMU's inputs when the row was sampled.",
        f"map: posture {mt.posture}, rule {mt.rule}, shape {list(mt.shape)}, "
        f"step {mt.step[0] * 1e3:g} mm {np.rad2deg(mt.step[2]):g} deg, labels_sha256 {mt.checksum()}",
        f"mode: {result.mode}; h = {REFERENCE['h']!r} s; n = {REFERENCE['n']}",
        "regenerate: python build_fmu.py --write-reference",
    ]


# ---------------------------------------------------------------------- the plant and controller runs
def _plant_inputs():
    t = np.arange(N + 1) * H
    return t, {"tau1": 0.05 * np.sin(3 * t), "tau2": -0.04 * np.cos(2 * t), "tau3": 0.03 * np.sin(5 * t)}


def _controller_inputs():
    model = Manipulator.paper()
    traj = CircleTrajectory()
    t = np.arange(N + 1) * H
    X, _, _ = traj.task(t)
    q, dq, _ = traj.joint(model, t)
    names = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi")
    cols = np.concatenate([q, dq, X], axis=1)
    return t, {n: cols[:, i] for i, n in enumerate(names)}


def start_values() -> dict:
    """Start values of the plant's reference run: at rest at the circle's first point."""
    c, r, phi = PAPER_CIRCLE["center"], PAPER_CIRCLE["radius"], PAPER_CIRCLE["phi"]
    return {"x0": c[0] + r, "y0": c[1], "phi0": phi}


#: name -> (inputs(), start values(), description) of the plant and controller runs
RUNS = {
    "RRRPlant": (_plant_inputs, start_values,
                 "RRRPlant from rest at the circle's first point (x0, y0, phi0 = (0.70, 0.30, -pi/4)); "
                 "tau(t) = (0.05 sin 3t, -0.04 cos 2t, 0.03 sin 5t) N m"),
    "ComputedTorqueController": (_controller_inputs, dict,
                                 "ComputedTorqueController fed its own reference (q = q_d, dq = dq_d, "
                                 "pose = X_d on the circle): tau is the inverse dynamics of the reference"),
}


def run(name: str, fmu) -> np.ndarray:
    """Simulate the reference run of FMU ``name`` (the built file ``fmu``); fmpy's result array."""
    if name == DK_NAME:
        return run_circle(fmu)
    inputs, start, _ = RUNS[name]
    t, signals = inputs()
    return simulate(fmu, stop_time=N * H, step_size=H, inputs=input_table(t, **signals),
                    start_values=start())


# ---------------------------------------------------------------------- the CSV files
def write_csv(path, rows, names, header_lines, ints=()) -> Path:
    """Rows (a structured array) as CSV: ``# `` header lines, the column names, full-precision floats."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {h}" for h in header_lines] + [",".join(names)]
    for row in rows:
        lines.append(",".join(str(int(row[n])) if n in ints else repr(float(row[n])) for n in names))
    path.write_text("\n".join(lines) + "\n")
    return path


def read_csv(path, ints=()) -> tuple[list[str], np.ndarray]:
    """``(header lines, structured array)`` of a reference CSV (``ints`` columns as integers)."""
    lines = Path(path).read_text().splitlines()
    header = [ln[2:] for ln in lines if ln.startswith("# ")]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    names = body[0].split(",")
    dtype = [(n, np.int64 if n in ints else np.float64) for n in names]
    data = np.array([tuple((int if n in ints else float)(c) for n, c in zip(names, ln.split(",")))
                     for ln in body[1:]], dtype=dtype)
    return header, data


def write(name: str, result: np.ndarray, path=None, header_lines=None) -> Path:
    """Write ``result`` as the reference CSV of ``name`` (default ``fmu_src/reference/<name>.csv``)."""
    path = Path(path) if path else REFERENCE_DIR / f"{name}.csv"
    if header_lines is None:
        header_lines = [RUNS[name][2], f"h = {H!r} s, {N} steps, fmpy.simulate_fmu; regenerate: "
                        "python build_fmu.py --write-reference"]
    names = ("time", "q1", "q2", "q3", *OUTPUTS) if name == DK_NAME else result.dtype.names
    return write_csv(path, result, names, header_lines, INT_COLUMNS.get(name, ()))


def read(name: str, path=None) -> np.ndarray:
    """The reference CSV of ``name`` as a structured array."""
    path = Path(path) if path else REFERENCE_DIR / f"{name}.csv"
    return read_csv(path, INT_COLUMNS.get(name, ()))[1]


def read_reference_csv(path=REFERENCE_DIR / f"{DK_NAME}.csv") -> tuple[list[str], np.ndarray]:
    """``(header lines, structured array)`` of the DK reference CSV (Boolean columns as 0/1 integers)."""
    return read_csv(path, INT_COLUMNS[DK_NAME])


# ---------------------------------------------------------------------- all three
def write_references(out_dir="build", csv_dir=REFERENCE_DIR, log=print, built=None) -> dict[str, Path]:
    """Build the reference FMUs into ``<out_dir>/reference``, run them, write ``<csv_dir>/<name>.csv``.

    ``built``: {FMU name: :class:`BuildResult` (the DK) or path (the plant, the controller)} of FMUs
    just built with the reference's options (builds are byte for byte deterministic), run instead of
    building them again.
    """
    built = built or {}
    folder = Path(out_dir) / "reference"
    dk = built.get(DK_NAME) or build_dk(folder, postures=(REFERENCE["posture"],), resolution=REFERENCE["resolution"],
                                        mode=REFERENCE["mode"], rule=REFERENCE["rule"],
                                        cache_dir=Path(out_dir) / "maps", log=log)
    if dk.problems:
        raise RuntimeError("reference FMU does not validate: " + "; ".join(dk.problems))
    paths = {DK_NAME: write(DK_NAME, run_circle(dk.fmu), Path(csv_dir) / f"{DK_NAME}.csv", _dk_header(dk))}
    for name in RUNS:
        fmu = built.get(name) or build_slave(name, folder)
        paths[name] = write(name, run(name, fmu), Path(csv_dir) / f"{name}.csv")
    return paths
