"""RRRPlant: the 3-RRR manipulator itself (the "real robot" of the paper's Fig. 2), as an FMU.

The plant integrates the task-space dynamics (:mod:`dynamics.model`, platform pose ``X`` and its
rate as state; no direct kinematics needed) with classic RK4, ``substeps`` steps per
communication step, the motor torques held constant over the step.  It reports what sensors
measure, the motor angles and rates, and, for validation only, the true pose.

Equations (see ``RRRPlant.md``): ``M_X(X) ddX + C_X(X, dX) dX + G_X(X) + F_X(X, dX) = J_q(X)^T tau``
with ``q = g_j(X)`` (inverse kinematics in the posture) and ``dq = J_q dX``.

Outputs depend on the state only (no direct feedthrough): a master may read ``q`` before it
knows ``tau``, and the closed loop DK -> controller -> plant has no algebraic loop.

Speed: a communication step is one compiled call (:class:`dynamics.PlantStepper`: the RK4
substeps, the same operations as :func:`dynamics.rk4_step`, then ``q`` with the operations of
:func:`solver.ik`, ``dq = J_q dX`` and the energy).  What it refuses (the platform leaves the tool
space, a non-finite value) raises :class:`dynamics.DynamicsError`, refused here as a step.
"""
# first: a host without the packages this FMU imports learns which and how to install them
# (fmu_src.requirements; the list is resources/requirements.txt)
from fmu_src.requirements import require
from fmu_src.wrapper_refs import hold_globals

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation
require(__file__)

from dataclasses import replace

import numpy as np

from fmu_src.table_slave import StepRefused, TableSlave, Var
from fmu_src.table_lane import TableLane

# Build constant: the robot (build_fmu.py --robot: name, description digest, geometry as
# Manipulator.to_dict(), [dynamics] as DynamicParameters.to_dict(), start pose and posture; None: the
# paper's robot with the default DynamicParameters).
BUILD_ROBOT = None
_START = tuple(BUILD_ROBOT["start"]) if BUILD_ROBOT else (0.5, 0.28867513459481287, 0.0)
_POSTURE = int(BUILD_ROBOT["posture"]) if BUILD_ROBOT else 1
_ABOUT = "" if BUILD_ROBOT is None else f"; robot {BUILD_ROBOT['name']!r} (description sha256 {BUILD_ROBOT['digest']})"


class RRRPlant(TableLane, TableSlave):
    description = "Planar 3-RRR rigid-body dynamics (task-space form, RK4), motor torques in, joints out" + _ABOUT
    author = "rrr-dk"

    VARIABLES = (
        Var("tau1", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 1"),
        Var("tau2", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 2"),
        Var("tau3", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 3"),
        Var("x0", "Real", "parameter", "fixed", start=_START[0], unit="m", description="initial platform x"),
        Var("y0", "Real", "parameter", "fixed", start=_START[1], unit="m",
            description="initial platform y"),
        Var("phi0", "Real", "parameter", "fixed", start=_START[2], unit="rad", description="initial orientation"),
        Var("posture", "Integer", "parameter", "fixed", start=_POSTURE, min=1, max=8,
            description="posture (inverse-kinematics branch) of the robot"),
        Var("mass_scale", "Real", "parameter", "fixed", start=1.0, unit="1", min=1e-3,
            description="factor on every link and platform mass and inertia (model error studies)"),
        Var("gravity_x", "Real", "parameter", "fixed", start=0.0, unit="m/s2", description="gravity, x"),
        Var("gravity_y", "Real", "parameter", "fixed", start=0.0, unit="m/s2",
            description="gravity, y (0: horizontal robot)"),
        Var("friction", "Boolean", "parameter", "fixed", start=True, description="viscous joint friction on"),
        Var("substeps", "Integer", "parameter", "fixed", start=1, min=1, max=1000,
            description="RK4 steps per communication step"),
        Var("q1", "Real", "output", unit="rad", depends_on=(), description="motor angle, leg 1"),
        Var("q2", "Real", "output", unit="rad", depends_on=(), description="motor angle, leg 2"),
        Var("q3", "Real", "output", unit="rad", depends_on=(), description="motor angle, leg 3"),
        Var("dq1", "Real", "output", unit="rad/s", depends_on=(), description="motor rate, leg 1"),
        Var("dq2", "Real", "output", unit="rad/s", depends_on=(), description="motor rate, leg 2"),
        Var("dq3", "Real", "output", unit="rad/s", depends_on=(), description="motor rate, leg 3"),
        Var("x_true", "Real", "output", unit="m", depends_on=(), description="true platform x"),
        Var("y_true", "Real", "output", unit="m", depends_on=(), description="true platform y"),
        Var("phi_true", "Real", "output", unit="rad", depends_on=(), description="true orientation"),
        Var("energy", "Real", "output", unit="J", depends_on=(),
            description="kinetic + potential energy"),
    )
    UNITS = {"J": {"kg": 1, "m": 2, "s": -2}}
    STATE = ("_x",)
    # _stepper: the compiled step (dynamics.PlantStepper); _bufs: two result buffers the steps write
    # in turn, _views: their first six values (the state after the step)
    # _lane, _lane_io, _lane_x: the loader's fast lane (fmu_src.table_lane) and the state it advances
    CONSTANT = ("_model", "_params", "_stepper", "_bufs", "_views", "_lane", "_lane_io", "_lane_x")
    LANE_SLOTS = ("tau1", "tau2", "tau3", "q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true",
                  "energy")
    # a doStep's rollback keeps a reference to _x: a step writes the buffer _x does not view and then
    # makes _x that buffer's view (the compiled step never writes its input state)
    IMMUTABLE_STATE = True

    def setup(self):
        self._x = None
        self._model = self._params = self._stepper = None
        self._bufs = self._views = None

    def on_initialized(self):
        from dynamics import DynamicParameters, PlantStepper
        from solver import Manipulator

        self._model = Manipulator.from_dict(BUILD_ROBOT["geometry"]) if BUILD_ROBOT else Manipulator.paper()
        base = DynamicParameters.from_dict(BUILD_ROBOT["dynamics"]) if BUILD_ROBOT else DynamicParameters()
        params = base.with_scaled_masses(float(self.mass_scale))
        changes = {"gravity": (float(self.gravity_x), float(self.gravity_y))}
        if not self.friction:
            changes.update(friction_active=0.0, friction_elbow=0.0, friction_platform=0.0)
        self._params = replace(params, **changes)
        self._stepper = PlantStepper(self._params, self._model, int(self.posture))
        self._bufs = (np.empty(self._stepper.OUT_SIZE), np.empty(self._stepper.OUT_SIZE))
        self._views = (self._bufs[0][:6], self._bufs[1][:6])
        self._x = np.array([self.x0, self.y0, self.phi0, 0.0, 0.0, 0.0])
        self._outputs()
        if self._lane_wanted() and not self._init_mode:   # behind the C loader: the hot calls without Python
            try:
                from dynamics._kernels.c_entry import IO_SIZE, IO_STEPS, IO_SUBSTEPS, IO_TIME
                lane = self._lane_made()
                self._lane_x, io = np.empty(6), np.zeros(IO_SIZE)
                io[IO_SUBSTEPS] = int(self.substeps)
                slots = self._lane_slots()
                step, table = self._stepper.c_step(self._lane_x, io, lane.real, slots)
                self._lane_connect(step, table, io, IO_TIME, IO_STEPS, slots)
            except Exception as exc:  # noqa: BLE001 - no lane: every call on the Python path
                self._lane_failed(exc)

    def initial_outputs(self):
        """In Initialization Mode: q, dq, the true pose and the energy of the initial state (what a
        host passes on to the DK FMU before exitInitializationMode)."""
        self.on_initialized()

    def _lane_after_steps(self):
        self._x = self._lane_x.copy()                   # the state the lane advanced (a new array: rollbacks)

    def _lane_before_steps(self):
        from dynamics._kernels.c_entry import IO_SUBSTEPS

        self._lane_x[:] = self._x
        self._lane_io[0][IO_SUBSTEPS] = int(self.substeps)      # (a set FMU state may carry another)

    def _free(self):
        """Index of the result buffer that ``_x`` does not view (the next step writes it)."""
        return 1 if self._x is self._views[0] else 0

    def step(self, t, dt):
        n = int(self.substeps)
        i = self._free()
        try:
            self._stepper.step(self.tau1, self.tau2, self.tau3, dt / n, n, self._x, self._bufs[i])
        except ValueError as exc:                       # dynamics.DynamicsError: the step is refused
            raise StepRefused(f"the platform left the tool space of posture {self.posture}: {exc}") from None
        self._publish(i)

    def _outputs(self):
        # the compiled step with no substep: the outputs of the state (and its machine code is loaded
        # now, at initialization, not in the first doStep)
        i = self._free()
        try:
            self._stepper.outputs(self._x, self._bufs[i])
        except ValueError as exc:                       # dynamics.DynamicsError
            if getattr(exc, "reason", None) != "outside":
                raise StepRefused(f"the outputs of the state {self._x.tolist()} are refused: {exc}") from None
            raise StepRefused(f"pose {self._x[:3].tolist()} is outside the tool space of posture "
                              f"{self.posture}") from None
        self._publish(i)

    def _publish(self, i):
        """From result buffer ``i``: the new state ``[:6]`` and the outputs ``q = [6:9]``, ``dq = [9:12]``,
        energy ``[12]``."""
        self._x = self._views[i]
        (self.x_true, self.y_true, self.phi_true, _, _, _, self.q1, self.q2, self.q3,
         self.dq1, self.dq2, self.dq3, self.energy) = self._bufs[i].tolist()
