"""The 3-RPR's DK FMU: its build and its reference run (host side; ``python build_fmu.py --manipulator 3rpr``).

``RPRDirectKinematics`` (:func:`build_rpr_dk`) bundles the slave ``fmu_src/RPRDirectKinematics.py``
(a subclass of the 3-RRR's slave), the ``solver`` modules it imports and the 3-RPR's map tensor of
its one posture over :data:`solver.rpr.RPR_WORK_BOUNDS`, as ``resources/maps/posture1.npz`` with
the same manifest as the 3-RRR's (size and SHA-256, checked at instantiation).  The map is cached in
the project's map cache (``solver.cache_dir("maps")``) under a name keyed by geometry, resolution,
rule and the labelling code.

The reference run (:func:`run_rpr_loop`): the legs go once round the 2 cm loop about cusp 1 of the
slice rho1 = 1.498 m (:func:`experiments.rpr_suite.cusp_loop_path`, 100 steps, h = 10 ms, ``rho[k]``
applied at ``t = k*h``); the platform ends in another assembly mode, certain all the way.  Its CSV
(:func:`write_rpr_reference`) is ``fmu_src/reference/RPRDirectKinematics.csv``.
"""
from __future__ import annotations

import hashlib
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.rpr_suite import cusp_loop_path
from solver import DEFAULT_RULE, MapTensor
from solver.mapcache import default_cache_dir, labelling_digest
from solver.rpr import RPR_WORK_BOUNDS, RPRManipulator

from .builds import DK_STORES, BuildResult, _stage_documentation, project_packages
from .checks import validate
from .kernels import Run, Scenario, warm_up
from .packaging import build_fmu
from .robot_build import robot_circle, robot_constant, stage_robot, with_robot_constant
from .references import read_csv, write_csv
from .sources import REFERENCE_DIR, slave_script
from ..simulation import input_table, simulate

__all__ = ["RPR_NAME", "RPR_RESOLUTION", "RPR_REFERENCE_RESOLUTION", "RPR_OUTPUTS", "build_rpr_dk", "rpr_map",
           "run_rpr_loop", "rpr_warm_up_scenario", "write_rpr_reference", "read_rpr_reference", "LOOP_N", "LOOP_H"]

RPR_NAME = "RPRDirectKinematics"
#: Default node spacing of the 3-RPR map: 25 mm, 3 degrees (3.5 million nodes over the work region).
RPR_RESOLUTION = (0.025, float(np.deg2rad(3.0)))
#: Output columns of the reference CSV (after time and the inputs rho1..rho3).
RPR_OUTPUTS = ("x", "y", "phi", "region", "n_real", "ambiguous", "status", "certain")
#: The reference run: steps round the loop and the communication step (s).
LOOP_N, LOOP_H = 100, 1e-2
#: The map of the reference run (coarse: quick to build in the tests): 100 mm, 6 degrees.
RPR_REFERENCE_RESOLUTION = (0.1, float(np.deg2rad(6.0)))
#: Integer (and Boolean, as 0/1) columns of the reference CSV.
RPR_INTS = ("region", "n_real", "ambiguous", "status", "certain")


def rpr_map(model: RPRManipulator, resolution=RPR_RESOLUTION, rule: str = DEFAULT_RULE, cache_dir=None,
            log=print, bounds=None) -> Path:
    """The 3-RPR's map over ``bounds`` (default :data:`RPR_WORK_BOUNDS`) at ``resolution`` (m, rad), from or
    into the map cache ``cache_dir`` (None: the project's, ``solver.cache_dir("maps")``)."""
    b = np.array(RPR_WORK_BOUNDS if bounds is None else bounds, dtype=float)
    step = float(resolution[0])
    shape = (int(round((b[0, 1] - b[0, 0]) / step)) + 1, int(round((b[1, 1] - b[1, 0]) / step)) + 1,
             int(round(2 * np.pi / float(resolution[1]))))
    key = [model.digest(), list(shape), rule, labelling_digest()] + ([] if bounds is None else [b.tolist()])
    key = hashlib.sha256(json.dumps(key).encode()).hexdigest()[:12]
    path = (default_cache_dir() if cache_dir is None else Path(cache_dir)) / f"rpr-posture1-{key}.npz"
    if path.is_file():
        try:
            MapTensor.load(path, model=model, posture=1)
            return path
        except Exception as exc:                    # noqa: BLE001 - a bad cache entry is rebuilt
            log(f"{path}: unusable ({exc}); rebuilding")
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    MapTensor.build(model, 1, bounds=b, shape=shape, rule=rule).save(path)
    log(f"3-RPR map {shape} built in {time.perf_counter() - t0:.1f} s: {path}")
    return path


def rpr_warm_up_scenario(n: int = LOOP_N, h: float = LOOP_H, cusp: int = 1) -> Scenario:
    """The runs that compile the kernels the 3-RPR's DK FMU ships: its reference run round the cusp loop
    (:func:`run_rpr_loop`), in the default mode and, for a fifth of it, the paper's."""
    path = cusp_loop_path(RPRManipulator.zein_wenger_chablat(), cusp, n)
    start = dict(zip(("x0", "y0", "phi0"), (float(v) for v in path.X[0])))
    inputs = {f"rho{j + 1}": path.q[:, j] for j in range(3)}
    return Scenario([Run(len(path.q), h, {**start, "mode": 0}, inputs),
                     Run(len(path.q) // 5, h, {**start, "mode": 1}, {k: v[:len(path.q) // 5] for k, v in inputs.items()})])


def build_rpr_dk(out_dir="build", resolution=None, rule: str = DEFAULT_RULE, cache_dir=None,
                 check: bool = True, log=print, kernels: bool = True, robot=None) -> BuildResult:
    """Build ``<out_dir>/RPRDirectKinematics.fmu`` (see the module docstring); ``kernels``: ship the
    kernels compiled along :func:`rpr_warm_up_scenario` (:mod:`cosim.fmus.kernels`), so a host starts it
    in seconds and compiles nothing.  ``robot``: a 3-RPR description (:class:`solver.robot.Robot`; None:
    Zein, Wenger and Chablat's): its map over its whole tool space (:func:`solver.default_bounds`) at
    ``resolution`` (None: the robot's, else :data:`RPR_RESOLUTION`), its start pose, its description
    carried (``resources/robot.json``, ``robot.toml``), warmed up along a circle about its start."""
    t0 = time.perf_counter()
    if robot is not None and robot.kind != "3-RPR":
        raise ValueError(f"robot: {robot.source} describes a {robot.kind}; this is the 3-RPR's DK FMU")
    model = RPRManipulator.zein_wenger_chablat() if robot is None else robot.model
    if resolution is None:
        resolution = RPR_RESOLUTION if robot is None else robot.resolution
    out_dir = Path(out_dir)
    bounds = None
    if robot is not None:
        from solver import default_bounds

        bounds = default_bounds(model, (resolution[0], resolution[0], resolution[1]))
    map_file = rpr_map(model, resolution, rule, cache_dir, log, bounds)
    map_seconds = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="build_fmu_") as tmp:
        tmp = Path(tmp)
        data = map_file.read_bytes()
        manifest = tmp / "manifest.json"
        manifest.write_text(json.dumps({"model": RPR_NAME, "maps": [
            {"posture": 1, "file": "maps/posture1.npz", "bytes": len(data),
             "sha256": hashlib.sha256(data).hexdigest()}]}, indent=1, sort_keys=True) + "\n")
        script = slave_script(RPR_NAME)
        if robot is not None:
            script = tmp / script.name
            script.write_text(with_robot_constant(slave_script(RPR_NAME).read_text(), robot_constant(robot, 1),
                                                  slave_script(RPR_NAME)))
        scenario = rpr_warm_up_scenario() if robot is None else _robot_warm_up(robot)
        fmu = build_fmu(script, out_dir, project_packages=project_packages(),
                        data_files={"maps/posture1.npz": map_file, "maps/manifest.json": manifest,
                                    **stage_robot(tmp, robot)},
                        documentation_dir=_stage_documentation(tmp, RPR_NAME), check=check,
                        kernels=warm_up(scenario, seeds=DK_STORES) if kernels else None)
    problems = validate(fmu) if check else []
    return BuildResult(fmu, {1: map_file}, 1, "default", time.perf_counter() - t0, map_seconds, problems)


def _robot_warm_up(robot, n: int = LOOP_N, h: float = LOOP_H) -> Scenario:
    """A 3-RPR robot's warm-up: a circle about its start pose (:func:`cosim.fmus.robot_build.robot_circle`),
    or 10 steps at rest there when that circle meets a singularity."""
    X, q = robot_circle(robot, 1, n)
    start = dict(zip(("x0", "y0", "phi0"), (float(v) for v in X[0])))
    if q is None:
        return Scenario([Run(10, h, {**start, "mode": m}) for m in (0, 1)])
    inputs = {f"rho{j + 1}": q[:, j] for j in range(3)}
    return Scenario([Run(n, h, {**start, "mode": 0}, inputs),
                     Run(n // 5, h, {**start, "mode": 1}, {k: v[:n // 5] for k, v in inputs.items()})])


def run_rpr_loop(fmu, n: int = LOOP_N, h: float = LOOP_H, cusp: int = 1):
    """The cusp loop through ``fmu`` with fmpy.simulate_fmu: ``rho[k]`` (k = 0..n, ``rho[n] = rho[0]`` the
    start) on [k h, (k+1) h]; row 0 is the initial pose, row k + 1 the pose for ``rho[k]`` (fmpy records
    after each doStep).  Returns fmpy's result array."""
    path = cusp_loop_path(RPRManipulator.zein_wenger_chablat(), cusp, n)
    q = path.q
    t = np.arange(len(q)) * h
    table = input_table(t, rho1=q[:, 0], rho2=q[:, 1], rho3=q[:, 2])
    X0 = path.X[0]
    return simulate(fmu, stop_time=len(q) * h, step_size=h, inputs=table,
                    start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]},
                    outputs=["rho1", "rho2", "rho3", *RPR_OUTPUTS])


def write_rpr_reference(result, path=None) -> Path:
    """Write a :func:`run_rpr_loop` result as the reference CSV (default ``fmu_src/reference/``)."""
    path = Path(path) if path else REFERENCE_DIR / f"{RPR_NAME}.csv"
    names = ["time", "rho1", "rho2", "rho3", *RPR_OUTPUTS]
    header = [f"{RPR_NAME} reference run: the legs once round the 2 cm loop about cusp 1 of the slice",
              f"rho1 = 1.498 m (experiments.rpr_suite.cusp_loop_path(model, 1, {LOOP_N})), rho[k] at t = k*h, "
              f"h = {LOOP_H!r} s, fmpy.simulate_fmu; map {RPR_REFERENCE_RESOLUTION[0] * 1e3:g} mm "
              f"{np.rad2deg(RPR_REFERENCE_RESOLUTION[1]):g} deg, default mode.",
              "regenerate: python build_fmu.py --manipulator 3rpr --write-reference"]
    return write_csv(path, result, names, header, RPR_INTS)


def read_rpr_reference(path=None) -> np.ndarray:
    """The reference CSV as a structured array (the columns of :func:`write_rpr_reference`)."""
    path = Path(path) if path else REFERENCE_DIR / f"{RPR_NAME}.csv"
    return read_csv(path, RPR_INTS)[1]
