"""Co-simulation of the paper's Figs 2 and 3 through fmpy: ``python -m dynamics.cosim``.

Three FMUs (FMI 2.0 Co-Simulation, built with pythonfmu from ``fmu_src/``):

* ``RRRDirectKinematics`` (DK): motor angles -> platform pose, the basic-regions tracker;
* ``ComputedTorqueController``: measured joints, rates and the DK pose -> motor torques (sampled
  at the start of each step, held over it);
* ``RRRPlant``: motor torques -> joints, rates and the true pose (task-space rigid-body dynamics).

The master knows them only through fmpy's ``FMU2Slave``.  Value references are looked up by name
once; time is ``t0 + k h``, never accumulated.

Closed loop (Fig. 2), :meth:`ClosedLoop.run`
--------------------------------------------
Initialization, in the FMI phases' order: instantiate, setupExperiment(t0), enterInitializationMode,
parameters and the inputs at ``t0`` (the plant starts at rest at the circle's first point; the DK
FMU gets that pose as ``x0, y0, phi0`` and the plant's initial joints as inputs; the controller the
plant's initial outputs), exitInitializationMode.

Each macro step ``[t_k, t_k + h)``, ``order="gauss-seidel"`` (the default)::

    q, dq, X_true   <- plant outputs at t_k                       (sensors)
    DK:         set q;            doStep(t_k, h);  X <- pose of q (t_k)
    controller: set q, dq, X;     doStep(t_k, h);  tau <- tau(t_k), held over the step
    plant:      set tau;          doStep(t_k, h);  state at t_k + h

Every link carries the value at ``t_k``: no delay beyond the controller's zero-order hold.
``order="jacobi"``: all inputs are set from the outputs available at ``t_k`` before any doStep,
so the DK pose and the torque each lag one step (the controller sees the pose of ``q_{k-1}``, the
plant gets ``tau_{k-1}``).  The ModelStructure of each FMU declares which outputs depend on which
inputs (the DK pose on q1..q3; the plant's outputs on no input; the controller's held torque on no
input at the communication point), so a master that sorts the graph finds no algebraic loop.

Dynamics simulation (Fig. 3), :func:`simulate_fig3`
--------------------------------------------------
The joint-space dynamics ``ddq = M^-1 (tau - C dq - G - F)`` (eq. 7) integrated by classic RK4 in
the master; at every Runge-Kutta stage the DK FMU turns the stage's joints into the pose that
``M, C, G`` need.  A stage must not advance the tracker: the master saves the FMU state at the
step's start (``getFMUstate``), evaluates each stage from it (``setFMUstate``, set q, ``doStep``
over the stage's time offset), and finally commits the step's end joints from the same saved state.
"""
from __future__ import annotations

import argparse
import csv
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

import dynamics  # noqa: F401  (imported before any FMU so the FMUs use the installed packages)
import solver
from solver import PAPER_CIRCLE, Manipulator, ik

__all__ = ["Scenario", "FMUUnit", "ClosedLoop", "ClosedLoopResult", "build_fmus", "simulate_fig3",
           "start_values", "write_osp_system", "CONNECTIONS", "write_csv", "plot_closed_loop", "main",
           "exit_process", "fmus_loaded", "remove_extracted"]

FMU_NAMES = ("RRRDirectKinematics", "ComputedTorqueController", "RRRPlant")
DK_STATUS = {0: "ok", 1: "unreachable", 2: "singular", 3: "rejected", 4: "diverged"}


# ----------------------------------------------------------------------------- scenario
@dataclass(frozen=True)
class Scenario:
    """Everything a closed-loop run depends on (parameters of the three FMUs and of the master).

    Attributes
    ----------
    t_end : float
        Simulated time, s.
    h : float
        Communication (and control) step, s.
    order : {"gauss-seidel", "jacobi"}
        Master algorithm (see the module docstring).
    posture : int
        Posture of the robot, its DK map and its reference.
    bandwidth, damping : float
        Requested closed-loop error dynamics (rad/s, 1).
    plant_mass_scale, controller_mass_scale : float
        Factors on the default masses of the plant (the real robot) and of the controller's model.
    tracker_mode : {"default", "paper"}
        Mode of the DK FMU's tracker.
    period, ramp_time : float
        Circle: seconds per revolution at cruise speed, duration of the start from rest.
    center, radius, phi : circle geometry (m, m, rad); default :data:`solver.PAPER_CIRCLE`.
    plant_substeps : int
        RK4 steps of the plant per communication step.
    """

    t_end: float = 2.5
    h: float = 1e-3
    order: str = "gauss-seidel"
    posture: int = 1
    bandwidth: float = 50.0
    damping: float = 1.0
    plant_mass_scale: float = 1.0
    controller_mass_scale: float = 1.0
    tracker_mode: str = "default"
    period: float = 2.0
    ramp_time: float = 0.5
    center: tuple = field(default=tuple(PAPER_CIRCLE["center"]))
    radius: float = PAPER_CIRCLE["radius"]
    phi: float = PAPER_CIRCLE["phi"]
    plant_substeps: int = 1

    def __post_init__(self):
        if self.order not in ("gauss-seidel", "jacobi"):
            raise ValueError(f"order: expected 'gauss-seidel' or 'jacobi', got {self.order!r}")
        if self.tracker_mode not in ("default", "paper"):
            raise ValueError(f"tracker_mode: expected 'default' or 'paper', got {self.tracker_mode!r}")
        for key in ("t_end", "h", "bandwidth", "damping", "plant_mass_scale", "controller_mass_scale",
                    "period", "radius"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"{key}: expected a positive number, got {v!r}")
        if self.h > self.t_end:
            raise ValueError(f"h: expected a step no longer than t_end = {self.t_end}, got {self.h}")

    @property
    def n_steps(self) -> int:
        return int(round(self.t_end / self.h))

    @property
    def start_pose(self) -> np.ndarray:
        """The circle's first point (polar angle 0), m, m, rad."""
        return np.array([self.center[0] + self.radius, self.center[1], self.phi])


# ----------------------------------------------------------------------------- one FMU
#: FMUs extracted in this process: (path, mtime, guid) -> folder.  Each FMU file is extracted once
#: and every instance loads the same copy of its shared library (see :meth:`FMUUnit.close`).
_EXTRACTED: dict = {}


def remove_extracted() -> None:
    """Delete the folders this process extracted FMUs into (also done at exit)."""
    for folder in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)


_remove_extracted = remove_extracted   # the name batch.py used first


def fmus_loaded() -> bool:
    """Whether this process has loaded a pythonfmu FMU (see :func:`exit_process`)."""
    try:
        with open("/proc/self/maps") as f:
            return any("/binaries/linux64/" in line for line in f)
    except OSError:
        return bool(_EXTRACTED)


def exit_process(code: int = 0):
    """End a process that ran pythonfmu FMUs: clean up, flush, and ``os._exit(code)``.

    pythonfmu 0.7's shared library finalizes its Python state when it is unloaded at process
    exit; with several of its FMUs loaded in one process that finalizer reads freed memory and
    the process may abort ("corrupted double-linked list", NTNU-IHB/PythonFMU#228, fixed
    upstream but unreleased).  Everything is written by then, but the exit status would say
    134.  ``os._exit`` skips the libraries' finalizers.  The project's command lines and its
    test session end this way when FMUs were loaded.
    """
    import os

    remove_extracted()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream must not change the exit status
            pass
    os._exit(int(code))


import atexit  # noqa: E402

atexit.register(remove_extracted)


class FMUUnit:
    """One FMU instance driven through fmpy's ``FMU2Slave`` (extracted once, reusable by reset).

    Parameters
    ----------
    path : str or Path
        The ``.fmu`` file.
    name : str
        Instance name.
    unzip_dir : str or Path, optional
        Where to extract (default: a folder shared by all instances of this FMU file in the
        process, removed at exit).
    """

    def __init__(self, path, name: str, unzip_dir=None, logging_on: bool = False):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such FMU (build it with `python -m dynamics.cosim --build`)")
        self.md = read_model_description(str(self.path))
        self._own_dir = False
        if unzip_dir is None:
            key = (str(self.path.resolve()), self.path.stat().st_mtime_ns, self.md.guid)
            if key not in _EXTRACTED:
                _EXTRACTED[key] = extract(str(self.path))
            self.unzip_dir = _EXTRACTED[key]
        else:
            self.unzip_dir = extract(str(self.path), unzipdir=str(unzip_dir))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self._logging_on = logging_on
        self.name = name
        self._instantiate()

    def _instantiate(self):
        """fmi2Instantiate, leaving ``sys.path`` and ``sys.modules`` as they were.

        pythonfmu's wrapper puts the FMU's resources folder first on ``sys.path`` and imports the
        slave module by name at every instantiation; left there, a later FMU with a module of the
        same name (another build of it) would get this one.  The live instance keeps what it uses.
        """
        from fmu_src.fmi_build import import_hygiene

        with import_hygiene():
            self.fmu.instantiate(loggingOn=self._logging_on)

    def vr(self, *names) -> list[int]:
        """Value references of ``names`` (looked up once by the caller)."""
        try:
            return [self.vars[n].valueReference for n in names]
        except KeyError as exc:
            raise KeyError(f"{self.name}: no variable {exc.args[0]!r} in {self.path.name}") from None

    def initialize(self, t0: float, start_values: dict) -> None:
        """setupExperiment, enterInitializationMode, start values, exitInitializationMode."""
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        self.set_values(start_values)
        self.fmu.exitInitializationMode()

    def set_values(self, values: dict) -> None:
        """Set variables of any type by name (initialization; not the hot path)."""
        for name, value in values.items():
            v = self.vars[name]
            if v.type == "Real":
                self.fmu.setReal([v.valueReference], [float(value)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            elif v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            else:
                raise TypeError(f"{self.name}.{name}: unsupported type {v.type}")

    def reset(self) -> None:
        """Back to the state after instantiation (then :meth:`initialize` again).

        Done by fmi2FreeInstance + fmi2Instantiate from the already loaded library, not by
        fmi2Reset: with our pythonfmu 0.7 FMUs, three or more fmi2Reset calls in one process leave
        the heap corrupted and the process aborts at exit (reproduced; a fresh instance does not).
        """
        self.fmu.fmi2FreeInstance(self.fmu.component)
        self._instantiate()

    def close(self) -> None:
        """fmi2Terminate and fmi2FreeInstance; the shared library stays loaded.

        fmpy's ``freeInstance`` also unloads the FMU's shared library.  With several pythonfmu
        FMUs in one process, unloading one of them, or loading a second extracted copy of the
        same FMU, corrupts the heap and the process aborts at exit ("corrupted double-linked
        list", reproduced here).  So every FMU file is extracted once per process, its library
        loaded once and never unloaded; instances are freed.
        """
        if self.fmu is None:
            return
        try:
            self.fmu.terminate()
        except Exception:  # noqa: BLE001 - terminate after an error may be refused; free anyway
            pass
        self.fmu.fmi2FreeInstance(self.fmu.component)
        self.fmu = None
        if self._own_dir:
            shutil.rmtree(self.unzip_dir, ignore_errors=True)


# ----------------------------------------------------------------------------- build
def build_fmus(out_dir="build", resolution=None, force: bool = False, log=print) -> dict:
    """Build (or reuse) the three FMUs in ``out_dir``; returns {name: path}.

    The DK FMU comes from ``build_fmu.py`` (map tensor of posture 1 at the default resolution, or
    ``resolution`` = (m, rad), cached in ``<out_dir>/maps``); the plant and the controller from
    ``fmu_src`` with the ``solver`` and ``dynamics`` packages as resources.  Each build runs in a
    child process: building validates and test-runs the FMU, and a process that later runs FMUs
    must load each FMU only once (see :meth:`FMUUnit.close`).
    """
    import subprocess

    root = Path(__file__).resolve().parent.parent
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    jobs = []
    # every FMU bundles fmu_src/table_slave.py, and the first FMU loaded provides it to all three
    runtime = (root / "fmu_src" / "table_slave.py").stat().st_mtime
    dk = out / "RRRDirectKinematics.fmu"
    if force or not dk.exists() or dk.stat().st_mtime < runtime:
        res = "None" if resolution is None else repr(tuple(float(v) for v in resolution))
        jobs.append((dk, "import sys; sys.path.insert(0, {root!r}); import build_fmu; "
                         "kw = {{}} if {res} is None else {{'resolution': {res}}}; "
                         "build_fmu.build(out_dir={out!r}, log=lambda *a: None, **kw)".format(
                             root=str(root), res=res, out=str(out))))
    for name in ("ComputedTorqueController", "RRRPlant"):
        path = out / f"{name}.fmu"
        src = root / "fmu_src" / f"{name}.py"
        if force or not path.exists() or path.stat().st_mtime < max(src.stat().st_mtime, runtime):
            jobs.append((path, "from fmu_src.fmi_build import build_fmu; build_fmu({src!r}, {out!r}, "
                               "project_packages=[{s!r}, {d!r}])".format(src=str(src), out=str(out),
                                                                         s=str(root / "solver"),
                                                                         d=str(root / "dynamics"))))
    for path, code in jobs:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", code], cwd=str(root), capture_output=True, text=True)
        if proc.returncode != 0 or not path.exists():
            raise RuntimeError(f"building {path.name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
        log(f"built {path} in {time.perf_counter() - t0:.1f} s")
    return {name: out / f"{name}.fmu" for name in FMU_NAMES}


# ----------------------------------------------------------------------------- closed loop
@dataclass
class ClosedLoopResult:
    """Time series of a closed-loop run (row ``k`` is time ``t0 + k h``) and its metrics."""

    scenario: Scenario
    columns: dict
    wall_seconds: float

    def __getitem__(self, key):
        return self.columns[key]

    @property
    def t(self) -> np.ndarray:
        return self.columns["time"]

    def joint_error(self) -> np.ndarray:
        """q - q_ref, wrapped, (n, 3) rad."""
        e = np.stack([self.columns[f"q{i}"] - self.columns[f"q{i}_ref"] for i in (1, 2, 3)], axis=1)
        return solver.wrap_angle(e)

    def rms_joint_error(self, t_from: float = 0.5) -> float:
        """RMS over time and joints of the joint tracking error after ``t_from`` s, rad."""
        e = self.joint_error()[self.t >= t_from - 1e-12]
        return float(np.sqrt(np.mean(e * e)))

    def max_dk_error(self) -> float:
        """Largest |DK pose - true pose| (m or rad, phi wrapped) over the run."""
        d = np.stack([self.columns["x"] - self.columns["x_true"], self.columns["y"] - self.columns["y_true"],
                      solver.wrap_angle(self.columns["phi"] - self.columns["phi_true"])], axis=1)
        return float(np.max(np.abs(d)))

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.scenario.t_end / self.wall_seconds

    def metrics(self) -> dict:
        return {"rms_joint_error_after_0.5s": self.rms_joint_error(0.5), "max_dk_vs_true": self.max_dk_error(),
                "dk_status_nonzero": int(np.count_nonzero(self.columns["dk_status"])),
                "wall_seconds": self.wall_seconds, "realtime_factor": self.realtime_factor}


#: Columns of :meth:`ClosedLoop.run`'s result, in the order of :func:`fill_row`.
COLUMNS = (["time"] + [f"q{i}" for i in (1, 2, 3)] + [f"dq{i}" for i in (1, 2, 3)]
           + [f"tau{i}" for i in (1, 2, 3)] + ["x", "y", "phi", "x_true", "y_true", "phi_true",
                                              "x_ref", "y_ref", "phi_ref", "q1_ref", "q2_ref", "q3_ref",
                                              "dk_status", "region", "n_real", "near_border", "ambiguous"])


def fill_row(row, t, sens, ctrl, pose, status, flags) -> None:
    """One result row (:data:`COLUMNS`) from the values read at ``t``: plant outputs ``sens`` (q, dq,
    true pose), controller outputs ``ctrl`` (tau, references), DK ``pose``, ``status`` (region,
    n_real, status) and ``flags`` (near_border, ambiguous)."""
    row[0] = t
    row[1:7] = sens[0:6]
    row[7:10] = ctrl[0:3]
    row[10:13] = pose[0:3]
    row[13:16] = sens[6:9]
    row[16:22] = ctrl[3:9]
    row[22], row[23], row[24] = status[2], status[0], status[1]
    row[25], row[26] = flags[0], flags[1]


class ClosedLoop:
    """The Fig. 2 loop of three FMUs driven by fmpy (see the module docstring).

    Instances are reusable: :meth:`run` resets the FMUs (fmi2Reset) and initializes them for the
    scenario, so a batch can run many scenarios without extracting the FMUs again.

    Parameters
    ----------
    fmus : dict
        {"RRRDirectKinematics": path, "ComputedTorqueController": path, "RRRPlant": path}.
    """

    def __init__(self, fmus: dict):
        self.units = {}
        try:
            for name in FMU_NAMES:
                self.units[name] = FMUUnit(fmus[name], name)
        except Exception:
            self.close()
            raise
        dk, ct, pl = (self.units[n] for n in FMU_NAMES)
        # value references, once
        self.vr = {
            "dk_in": dk.vr("q1", "q2", "q3"), "dk_out": dk.vr("x", "y", "phi"),
            "dk_int": dk.vr("region", "n_real", "status"), "dk_bool": dk.vr("near_border", "ambiguous"),
            "ct_in": ct.vr("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi"),
            "ct_out": ct.vr("tau1", "tau2", "tau3", "x_ref", "y_ref", "phi_ref_out", "q1_ref", "q2_ref", "q3_ref"),
            "pl_in": pl.vr("tau1", "tau2", "tau3"),
            "pl_out": pl.vr("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true"),
        }
        self._fresh = True

    def close(self):
        for unit in self.units.values():
            unit.close()
        self.units = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _initialize(self, sc: Scenario, t0: float):
        values = start_values(sc)
        dk, ct, pl = (self.units[n] for n in FMU_NAMES)
        if not self._fresh:
            for unit in self.units.values():
                unit.reset()
        self._fresh = False
        pl.initialize(t0, values["plant"])
        dk.initialize(t0, values["dk"])
        ct.initialize(t0, values["controller"])

    def run(self, scenario: Scenario | None = None, t0: float = 0.0) -> ClosedLoopResult:
        """Run one scenario from ``t0``; returns the time series (one row per communication point)."""
        sc = Scenario() if scenario is None else scenario
        self._initialize(sc, t0)
        dk, ct, pl = (self.units[n].fmu for n in FMU_NAMES)
        vr = self.vr
        n = sc.n_steps
        h = sc.h
        names = COLUMNS
        out = np.zeros((n, len(names)))
        gauss_seidel = sc.order == "gauss-seidel"
        # fmpy's getReal/setReal build two ctypes arrays per call (~1.5 us each): the value references
        # and the value buffers are ctypes arrays made once; the fmi2* calls check the status as before
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real, fmi2True, fmi2ValueReference

        def refs(key):
            return (fmi2ValueReference * len(vr[key]))(*vr[key])
        dk_in, dk_out, dk_int, dk_bool = refs("dk_in"), refs("dk_out"), refs("dk_int"), refs("dk_bool")
        ct_in, ct_out, pl_in, pl_out = refs("ct_in"), refs("ct_out"), refs("pl_in"), refs("pl_out")
        sens, pose, ctrl = (fmi2Real * 9)(), (fmi2Real * 3)(), (fmi2Real * 9)()
        x_ct, status, flags = (fmi2Real * 9)(), (fmi2Integer * 3)(), (fmi2Boolean * 2)()
        dkc, ctc, plc = dk.component, ct.component, pl.component
        pl.fmi2GetReal(plc, pl_out, 9, sens)
        dk.fmi2GetReal(dkc, dk_out, 3, pose)
        ct.fmi2GetReal(ctc, ct_out, 9, ctrl)
        wall = time.perf_counter()
        for k in range(n):
            t = t0 + k * h
            x_ct[0:6] = sens[0:6]                           # q, dq
            if gauss_seidel:
                dk.fmi2SetReal(dkc, dk_in, 3, sens)         # q = sens[0:3]
                dk.fmi2DoStep(dkc, t, h, fmi2True)
                dk.fmi2GetReal(dkc, dk_out, 3, pose)
                x_ct[6:9] = pose[0:3]
                ct.fmi2SetReal(ctc, ct_in, 9, x_ct)
                ct.fmi2DoStep(ctc, t, h, fmi2True)
                ct.fmi2GetReal(ctc, ct_out, 9, ctrl)
                pl.fmi2SetReal(plc, pl_in, 3, ctrl)         # tau = ctrl[0:3]
                pl.fmi2DoStep(plc, t, h, fmi2True)
            else:
                x_ct[6:9] = pose[0:3]
                dk.fmi2SetReal(dkc, dk_in, 3, sens)
                ct.fmi2SetReal(ctc, ct_in, 9, x_ct)
                pl.fmi2SetReal(plc, pl_in, 3, ctrl)
                dk.fmi2DoStep(dkc, t, h, fmi2True)
                ct.fmi2DoStep(ctc, t, h, fmi2True)
                pl.fmi2DoStep(plc, t, h, fmi2True)
                dk.fmi2GetReal(dkc, dk_out, 3, pose)
                ct.fmi2GetReal(ctc, ct_out, 9, ctrl)
            dk.fmi2GetInteger(dkc, dk_int, 3, status)
            dk.fmi2GetBoolean(dkc, dk_bool, 2, flags)
            fill_row(out[k], t, sens, ctrl, pose, status, flags)
            pl.fmi2GetReal(plc, pl_out, 9, sens)
        wall = time.perf_counter() - wall
        return ClosedLoopResult(sc, {name: out[:, i] for i, name in enumerate(names)}, wall)


# ----------------------------------------------------------------------------- system structure
#: The closed loop's connections, "instance.output" -> "instance.input" (OSP / SSP style).
CONNECTIONS = (
    [(f"plant.q{i}", f"dk.q{i}") for i in (1, 2, 3)]
    + [(f"plant.q{i}", f"controller.q{i}") for i in (1, 2, 3)]
    + [(f"plant.dq{i}", f"controller.dq{i}") for i in (1, 2, 3)]
    + [(f"dk.{v}", f"controller.{v}") for v in ("x", "y", "phi")]
    + [(f"controller.tau{i}", f"plant.tau{i}") for i in (1, 2, 3)]
)


def start_values(sc: Scenario) -> dict:
    """Parameters and initial inputs of the three FMUs for a scenario: {instance: {variable: value}}."""
    X0 = sc.start_pose
    q0 = ik(Manipulator.paper(), X0, sc.posture)
    if np.isnan(q0[0]):
        raise ValueError(f"scenario: the start pose {X0.tolist()} is outside posture {sc.posture}")
    return {
        "plant": {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": sc.posture,
                  "mass_scale": sc.plant_mass_scale, "substeps": sc.plant_substeps},
        "dk": {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": sc.posture,
               "mode": 0 if sc.tracker_mode == "default" else 1, "q1": q0[0], "q2": q0[1], "q3": q0[2]},
        "controller": {"bandwidth": sc.bandwidth, "damping": sc.damping, "mass_scale": sc.controller_mass_scale,
                       "posture": sc.posture, "center_x": sc.center[0], "center_y": sc.center[1],
                       "radius": sc.radius, "phi_ref": sc.phi, "period": sc.period, "ramp_time": sc.ramp_time,
                       "q1": q0[0], "q2": q0[1], "q3": q0[2], "dq1": 0.0, "dq2": 0.0, "dq3": 0.0,
                       "x": X0[0], "y": X0[1], "phi": X0[2]},
    }


def write_osp_system(paths: dict, folder, scenario: Scenario | None = None) -> Path:
    """The closed loop as libcosim's OspSystemStructure.xml (instances dk, controller, plant).

    libcosim's fixed-step algorithm steps all FMUs from the same inputs and then moves the
    outputs along the connections: the ``order="jacobi"`` scheme of :class:`ClosedLoop`.
    """
    from fmu_src.fmi_build import write_osp_system_structure

    sc = Scenario() if scenario is None else scenario
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return write_osp_system_structure(
        folder / "OspSystemStructure.xml",
        {"dk": paths["RRRDirectKinematics"], "controller": paths["ComputedTorqueController"],
         "plant": paths["RRRPlant"]},
        base_step_size=sc.h, connections=CONNECTIONS,
        initial_values={k: {n: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for n, v in d.items()}
                        for k, d in start_values(sc).items()})


# ----------------------------------------------------------------------------- Fig. 3
def simulate_fig3(dk_fmu, params, q0, dq0, t_end: float, h: float, tau=None, X0=None, posture: int = 1,
                  mode: str = "default"):
    """Joint-space dynamics (eq. 7) by RK4 in the master, the DK FMU at every stage (Fig. 3).

    Parameters
    ----------
    dk_fmu : path
        The DK FMU.
    params : dynamics.model.DynamicParameters
    q0, dq0 : array_like (3,)
        Initial joints (rad) and rates (rad/s).
    t_end, h : float
        Duration and step, s.
    tau : None or callable ``tau(t, q, dq) -> (3,)``
        Motor torques (None: zero).
    X0 : array_like (3,), optional
        Pose at ``q0`` (the DK FMU's initial pose); default from the FMU's own initialization.

    Returns
    -------
    t : ndarray (n+1,)
    q, dq, X : ndarray (n+1, 3)
        Joints, rates and the DK FMU's pose at every step.
    """
    from dynamics.model import forward_dynamics

    model = Manipulator.paper()
    unit = FMUUnit(dk_fmu, "dk-fig3")
    try:
        q0 = np.asarray(q0, float)
        start = {"q1": q0[0], "q2": q0[1], "q3": q0[2], "posture": posture, "mode": 0 if mode == "default" else 1}
        if X0 is not None:
            start.update(x0=X0[0], y0=X0[1], phi0=X0[2])
        unit.initialize(0.0, start)
        fmu = unit.fmu
        vin, vout = unit.vr("q1", "q2", "q3"), unit.vr("x", "y", "phi")
        n = int(round(t_end / h))
        t = np.arange(n + 1) * h
        Q, DQ, XX = np.zeros((n + 1, 3)), np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
        fmu.setReal(vin, q0)
        Q[0], DQ[0] = q0, dq0
        XX[0] = fmu.getReal(vout)

        def pose(saved, t_n, q, dt):
            fmu.setFMUstate(saved)
            fmu.setReal(vin, q)
            fmu.doStep(t_n, dt)
            return np.array(fmu.getReal(vout))

        def rhs(t_s, q, dq, X):
            u = np.zeros(3) if tau is None else np.asarray(tau(t_s, q, dq), float)
            return dq, forward_dynamics(params, model, q, dq, X, u)

        for k in range(n):
            tk = t[k]
            saved = fmu.getFMUstate()
            q, dq = Q[k], DQ[k]
            k1q, k1v = rhs(tk, q, dq, XX[k])
            q2, v2 = q + 0.5 * h * k1q, dq + 0.5 * h * k1v
            k2q, k2v = rhs(tk + 0.5 * h, q2, v2, pose(saved, tk, q2, 0.5 * h))
            q3, v3 = q + 0.5 * h * k2q, dq + 0.5 * h * k2v
            k3q, k3v = rhs(tk + 0.5 * h, q3, v3, pose(saved, tk, q3, 0.5 * h))
            q4, v4 = q + h * k3q, dq + h * k3v
            k4q, k4v = rhs(tk + h, q4, v4, pose(saved, tk, q4, h))
            Q[k + 1] = q + h / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q)
            DQ[k + 1] = dq + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            XX[k + 1] = pose(saved, tk, Q[k + 1], h)          # commit the step's end
            fmu.freeFMUstate(saved)
        return t, Q, DQ, XX
    finally:
        unit.close()


# ----------------------------------------------------------------------------- output
def write_csv(result: ClosedLoopResult, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(result.columns)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for row in zip(*(result.columns[n] for n in names)):
            w.writerow([f"{v:.17g}" if isinstance(v, float) else v for v in row])
    return path


def plot_closed_loop(result: ClosedLoopResult, out_dir) -> list[Path]:
    """PNG plots: pose vs reference, joint errors, torques, DK status."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    c, t = result.columns, result.t
    sc = result.scenario
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), dpi=110)
    axes[0].plot(c["x_ref"], c["y_ref"], "k:", lw=1.5, label="reference")
    axes[0].plot(c["x"], c["y"], "-", color="tab:blue", lw=1.0, label="DK FMU pose")
    axes[0].plot(c["x_true"], c["y_true"], "--", color="tab:orange", lw=0.8, label="true pose (plant)")
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(fontsize=8)
    for key, col in (("x", "tab:blue"), ("y", "tab:green"), ("phi", "tab:red")):
        ref = c["phi_ref"] if key == "phi" else c[f"{key}_ref"]
        axes[1].plot(t, c[key] - ref, color=col, label=f"{key} - {key}_ref [{'rad' if key == 'phi' else 'm'}]")
    axes[1].set_xlabel("t [s]")
    axes[1].legend(fontsize=8)
    axes[1].set_title("pose error (DK pose - reference)", fontsize=9)
    fig.suptitle(f"Closed loop (Fig. 2): computed torque on the circle, h = {sc.h * 1e3:g} ms, {sc.order}",
                 fontsize=10)
    fig.tight_layout()
    paths.append(out / "closed_loop_pose.png")
    fig.savefig(paths[-1])
    plt.close(fig)

    e = result.joint_error()
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), dpi=110, sharex=True)
    for i in range(3):
        axes[0].plot(t, e[:, i], label=f"q{i + 1} - q{i + 1}_ref")
        axes[1].plot(t, c[f"tau{i + 1}"], label=f"tau{i + 1}")
    axes[0].set_ylabel("joint error [rad]")
    axes[0].set_yscale("symlog", linthresh=1e-6)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"RMS joint error after 0.5 s: {result.rms_joint_error(0.5):.3g} rad", fontsize=9)
    axes[1].set_ylabel("torque [N m]")
    axes[1].set_xlabel("t [s]")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    paths.append(out / "closed_loop_joints_torques.png")
    fig.savefig(paths[-1])
    plt.close(fig)

    fig, axes = plt.subplots(3, 1, figsize=(8, 5), dpi=110, sharex=True)
    axes[0].step(t, c["dk_status"], where="post")
    axes[0].set_yticks(sorted(DK_STATUS))
    axes[0].set_yticklabels([DK_STATUS[k] for k in sorted(DK_STATUS)], fontsize=7)
    axes[0].set_title("DK FMU: status, region used, real solutions, flags", fontsize=9)
    axes[1].step(t, c["region"], where="post", label="region")
    axes[1].step(t, c["n_real"], where="post", label="n_real")
    axes[1].legend(fontsize=8)
    axes[2].step(t, c["near_border"], where="post", label="near_border")
    axes[2].step(t, c["ambiguous"] * 0.5, where="post", label="ambiguous (x0.5)")
    axes[2].legend(fontsize=8)
    axes[2].set_xlabel("t [s]")
    fig.tight_layout()
    paths.append(out / "closed_loop_dk_status.png")
    fig.savefig(paths[-1])
    plt.close(fig)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m dynamics.cosim", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default="build")
    ap.add_argument("--out", default="results")
    ap.add_argument("--rebuild", action="store_true", help="rebuild the FMUs even if present")
    ap.add_argument("--h", type=float, default=Scenario.h)
    ap.add_argument("--t-end", type=float, default=Scenario.t_end)
    ap.add_argument("--order", default=Scenario.order, choices=("gauss-seidel", "jacobi"))
    ap.add_argument("--plant-mass-scale", type=float, default=1.0)
    ap.add_argument("--no-plots", action="store_true")
    args = ap.parse_args(argv)
    paths = build_fmus(args.build_dir, force=args.rebuild)
    sc = Scenario(h=args.h, t_end=args.t_end, order=args.order, plant_mass_scale=args.plant_mass_scale)
    with ClosedLoop(paths) as loop:
        res = loop.run(sc)
    out = Path(args.out)
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
    print(f"closed loop: {sc.t_end:g} s simulated in {m['wall_seconds']:.2f} s wall "
          f"({m['realtime_factor']:.1f}x real time)")
    return 0


if __name__ == "__main__":
    exit_process(main())
