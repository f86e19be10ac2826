"""ComputedTorqueController: the model-based controller of the paper's Fig. 2, as an FMU.

A sampled-data computed-torque law.  In ``doStep(t, h)`` it samples its inputs at ``t`` (the
measured joints and rates from the robot, the pose from the direct-kinematics FMU), evaluates the
reference at ``t`` and holds

    tau = M(q_X, X) (ddq_d + Kd (dq_d - dq) + Kp (q_d - q)) + C(q_X, dq, X) dq + G(q_X, X) + F(...)

over ``[t, t + h)`` (zero-order hold).  The model terms are evaluated at the pose ``X`` that the
DK FMU delivered, with the joints it belongs to, ``q_X = g_j(X)`` (equal to ``q`` when the master
orders the loop DK -> controller; a Jacobi master delivers the previous step's pose and the law
then uses that consistently).  ``Kp``, ``Kd`` are designed with python-control for the requested
bandwidth and damping (:class:`dynamics.control.ComputedTorqueGains`).  The reference is the
circle of :class:`dynamics.trajectory.CircleTrajectory` (from rest).

Outputs are the held sample (no direct feedthrough at the communication point: what is read after
``doStep(t, h)`` was computed from the inputs at ``t``); see ``ComputedTorqueController.md``.

Speed: a step is one compiled call (:class:`dynamics.ControllerStepper`: the reference of
:meth:`CircleTrajectory.joint`, ``q_X`` with the operations of :func:`solver.ik` and the law of
:func:`dynamics.computed_torque`).  What it refuses (a pose outside the tool space, a reference
outside it...) raises :class:`dynamics.DynamicsError`, refused here as a step.
"""
# first: a host without the packages this FMU imports learns which and how to install them
# (fmu_src.requirements; the list is resources/requirements.txt)
from fmu_src.requirements import require
from fmu_src.wrapper_refs import hold_globals

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation
require(__file__)

import numpy as np

from fmu_src.table_slave import StepRefused, TableSlave, Var
from fmu_src.table_lane import TableLane

# Build constant: the robot (build_fmu.py --robot: name, description digest, geometry, [dynamics], start
# pose, posture and reference circle {"center", "radius", "phi"}; None: the paper's robot, its circle).
BUILD_ROBOT = None
_START = tuple(BUILD_ROBOT["start"]) if BUILD_ROBOT else (0.5, 0.28867513459481287, 0.0)
_POSTURE = int(BUILD_ROBOT["posture"]) if BUILD_ROBOT else 1
_CIRCLE = BUILD_ROBOT["circle"] if BUILD_ROBOT else {"center": (0.45, 0.30), "radius": 0.25,
                                                     "phi": -0.7853981633974483}
_ABOUT = "" if BUILD_ROBOT is None else f"; robot {BUILD_ROBOT['name']!r} (description sha256 {BUILD_ROBOT['digest']})"


class ComputedTorqueController(TableLane, TableSlave):
    description = "Computed-torque control of the 3-RRR on a circle, model terms at the DK pose" + _ABOUT
    author = "rrr-dk"

    VARIABLES = (
        Var("q1", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 1"),
        Var("q2", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 2"),
        Var("q3", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 3"),
        Var("dq1", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 1"),
        Var("dq2", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 2"),
        Var("dq3", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 3"),
        Var("x", "Real", "input", start=_START[0], unit="m", description="platform x from the DK FMU"),
        Var("y", "Real", "input", start=_START[1], unit="m", description="platform y from the DK FMU"),
        Var("phi", "Real", "input", start=_START[2], unit="rad", description="orientation from the DK FMU"),
        Var("bandwidth", "Real", "parameter", "fixed", start=50.0, unit="rad/s", min=1e-3,
            description="closed-loop error bandwidth (natural frequency)"),
        Var("damping", "Real", "parameter", "fixed", start=1.0, unit="1", min=1e-3,
            description="closed-loop error damping ratio"),
        Var("mass_scale", "Real", "parameter", "fixed", start=1.0, unit="1", min=1e-3,
            description="the controller's belief of the masses (factor on the default model)"),
        Var("posture", "Integer", "parameter", "fixed", start=_POSTURE, min=1, max=8, description="posture"),
        Var("center_x", "Real", "parameter", "fixed", start=_CIRCLE["center"][0], unit="m",
            description="circle centre x"),
        Var("center_y", "Real", "parameter", "fixed", start=_CIRCLE["center"][1], unit="m",
            description="circle centre y"),
        Var("radius", "Real", "parameter", "fixed", start=_CIRCLE["radius"], unit="m", min=1e-6,
            description="circle radius"),
        Var("phi_ref", "Real", "parameter", "fixed", start=_CIRCLE["phi"], unit="rad",
            description="platform orientation along the circle"),
        Var("period", "Real", "parameter", "fixed", start=2.0, unit="s", min=1e-3,
            description="time per revolution at cruise speed"),
        Var("ramp_time", "Real", "parameter", "fixed", start=0.5, unit="s", min=0.0,
            description="smooth start from rest"),
        Var("tau1", "Real", "output", unit="N.m", depends_on=(), description="motor torque, leg 1 (held)"),
        Var("tau2", "Real", "output", unit="N.m", depends_on=(), description="motor torque, leg 2 (held)"),
        Var("tau3", "Real", "output", unit="N.m", depends_on=(), description="motor torque, leg 3 (held)"),
        Var("x_ref", "Real", "output", unit="m", depends_on=(), description="reference x at the sample"),
        Var("y_ref", "Real", "output", unit="m", depends_on=(), description="reference y at the sample"),
        Var("phi_ref_out", "Real", "output", unit="rad", depends_on=(),
            description="reference orientation at the sample"),
        Var("q1_ref", "Real", "output", unit="rad", depends_on=(), description="reference angle, leg 1"),
        Var("q2_ref", "Real", "output", unit="rad", depends_on=(), description="reference angle, leg 2"),
        Var("q3_ref", "Real", "output", unit="rad", depends_on=(), description="reference angle, leg 3"),
    )
    # _stepper: the compiled step (dynamics.ControllerStepper); _out: its result buffer (scratch,
    # read right after every call)
    # _lane, _lane_io: the loader's fast lane (fmu_src.table_lane)
    CONSTANT = ("_model", "_params", "_gains", "_traj", "_stepper", "_out", "_lane", "_lane_io")
    LANE_SLOTS = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi", "tau1", "tau2", "tau3", "x_ref", "y_ref",
                  "phi_ref_out", "q1_ref", "q2_ref", "q3_ref")
    # no STATE: a doStep's rollback is the table values (references)
    IMMUTABLE_STATE = True

    def setup(self):
        self._model = self._params = self._gains = self._traj = None
        self._stepper = self._out = None

    def on_initialized(self):
        from dynamics import CircleTrajectory, ComputedTorqueGains, ControllerStepper, DynamicParameters
        from solver import Manipulator

        self._model = Manipulator.from_dict(BUILD_ROBOT["geometry"]) if BUILD_ROBOT else Manipulator.paper()
        base = DynamicParameters.from_dict(BUILD_ROBOT["dynamics"]) if BUILD_ROBOT else DynamicParameters()
        self._params = base.with_scaled_masses(float(self.mass_scale))
        self._gains = ComputedTorqueGains.design(float(self.bandwidth), float(self.damping))
        self._traj = CircleTrajectory(center=(float(self.center_x), float(self.center_y)),
                                      radius=float(self.radius), phi=float(self.phi_ref),
                                      posture=int(self.posture), period=float(self.period),
                                      ramp_time=float(self.ramp_time))
        # (the stepper loads its compiled step now, not in the first doStep)
        self._stepper = ControllerStepper(self._params, self._model, self._gains, self._traj)
        self._out = np.empty(self._stepper.OUT_SIZE)
        self._reference(self.time_start())       # the outputs at initialization are the reference only
        if self._lane_wanted():                   # behind the C loader: the hot calls without Python
            try:
                from dynamics._kernels.c_entry import IO_SIZE, IO_STEPS, IO_TIME
                lane = self._lane_made()
                io, slots = np.zeros(IO_SIZE), self._lane_slots()
                step, table = self._stepper.c_step(io, lane.real, slots)
                self._lane_connect(step, table, io, IO_TIME, IO_STEPS, slots)
            except Exception as exc:  # noqa: BLE001 - no lane: every call on the Python path
                self._lane_failed(exc)

    def time_start(self):
        return float(getattr(self, "_time", 0.0) or 0.0)

    def _reference(self, t):
        """Set the reference outputs at ``t``."""
        X_d, _, _ = self._traj.task(t)
        q_d, _, _ = self._traj.joint(self._model, t)
        self.x_ref, self.y_ref, self.phi_ref_out = (float(v) for v in X_d)
        self.q1_ref, self.q2_ref, self.q3_ref = (float(v) for v in q_d)

    def step(self, t, dt):
        out = self._out
        try:
            self._stepper.step(t, self.q1, self.q2, self.q3, self.dq1, self.dq2, self.dq3, self.x, self.y,
                               self.phi, out)
        except ValueError as exc:                       # dynamics.DynamicsError: the step is refused
            if getattr(exc, "where", None) == "measurement" and getattr(exc, "reason", None) == "outside":
                raise StepRefused(f"pose (x, y, phi) = {[float(self.x), float(self.y), float(self.phi)]} from "
                                  f"the DK is outside the tool space of posture {self.posture}") from None
            raise StepRefused(str(exc)) from None
        (self.tau1, self.tau2, self.tau3, self.x_ref, self.y_ref, self.phi_ref_out,
         self.q1_ref, self.q2_ref, self.q3_ref) = out.tolist()
