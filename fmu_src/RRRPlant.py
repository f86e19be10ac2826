"""RRRPlant: the 3-RRR manipulator itself (the "real robot" of the paper's Fig. 2), as an FMU.

The plant integrates the task-space dynamics (:mod:`dynamics.model`, platform pose ``X`` and its
rate as state; no direct kinematics needed) with classic RK4, ``substeps`` steps per
communication step, the motor torques held constant over the step.  It reports what sensors
measure, the motor angles and rates, and, for validation only, the true pose.

Equations (see ``RRRPlant.md``): ``M_X(X) ddX + C_X(X, dX) dX + G_X(X) + F_X(X, dX) = J_q(X)^T tau``
with ``q = g_j(X)`` (inverse kinematics in the posture) and ``dq = J_q dX``.

Outputs depend on the state only (no direct feedthrough): a master may read ``q`` before it
knows ``tau``, and the closed loop DK -> controller -> plant has no algebraic loop.

Speed: a communication step is one compiled call (:func:`dynamics._kernel.plant_step`: the RK4
substeps of :func:`dynamics._kernel.rk4_task`, the same operations as
:func:`dynamics.integrate.rk4_step`, then ``q`` with the operations of :func:`solver.ik`,
``dq = J_q dX`` and the energy).  Whatever it refuses (the platform leaves the tool space, a
non-finite value) is redone by the numpy code (``_reference_step`` / ``_reference_outputs``),
which raises the documented refusal.
"""
from dataclasses import replace

import numpy as np

from fmu_src.table_slave import StepRefused, TableSlave, Var


class RRRPlant(TableSlave):
    description = "Planar 3-RRR rigid-body dynamics (task-space form, RK4), motor torques in, joints out"
    author = "rrr-dk"

    VARIABLES = (
        Var("tau1", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 1"),
        Var("tau2", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 2"),
        Var("tau3", "Real", "input", start=0.0, unit="N.m", description="motor torque, leg 3"),
        Var("x0", "Real", "parameter", "fixed", start=0.5, unit="m", description="initial platform x"),
        Var("y0", "Real", "parameter", "fixed", start=0.28867513459481287, unit="m",
            description="initial platform y"),
        Var("phi0", "Real", "parameter", "fixed", start=0.0, unit="rad", description="initial orientation"),
        Var("posture", "Integer", "parameter", "fixed", start=1, min=1, max=8,
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
    # _kpack, _bits: packed constants and elbow bits of the compiled step; _kstep: its entry point
    CONSTANT = ("_model", "_params", "_rhs", "_kpack", "_bits", "_kstep")

    def setup(self):
        self._x = None
        self._model = self._params = self._rhs = None
        self._kpack = self._bits = self._kstep = None

    def on_initialized(self):
        from dynamics import _kernel
        from dynamics.integrate import task_space_rhs
        from dynamics.model import DynamicParameters, _plant_pack
        from solver import Manipulator

        self._model = Manipulator.paper()
        params = DynamicParameters().with_scaled_masses(float(self.mass_scale))
        changes = {"gravity": (float(self.gravity_x), float(self.gravity_y))}
        if not self.friction:
            changes.update(friction_active=0.0, friction_elbow=0.0, friction_platform=0.0)
        self._params = replace(params, **changes)
        self._rhs = task_space_rhs(self._params, self._model, int(self.posture), self._torque)
        self._kpack = _plant_pack(self._params, self._model)
        self._bits = int(self.posture) - 1
        self._kstep = _kernel.plant_step
        self._x = np.array([self.x0, self.y0, self.phi0, 0.0, 0.0, 0.0])
        self._outputs()

    def _torque(self, t, x):
        return np.array([self.tau1, self.tau2, self.tau3])

    def step(self, t, dt):
        n = int(self.substeps)
        out = np.empty(13)
        if self._kstep(self._kpack, self._bits, self.tau1, self.tau2, self.tau3, dt / n, n, self._x, out):
            return self._reference_step(t, dt)          # refused: the numpy code raises (or answers)
        self._publish(out)

    def _outputs(self):
        # the compiled step with no substep: the outputs of the state (and its machine code is loaded
        # now, at initialization, not in the first doStep)
        out = np.empty(13)
        if self._kstep(self._kpack, self._bits, self.tau1, self.tau2, self.tau3, 0.0, 0, self._x, out):
            return self._reference_outputs()
        self._publish(out)

    def _publish(self, out):
        """New state ``out[:6]`` and the outputs ``q = out[6:9]``, ``dq = out[9:12]``, energy ``out[12]``."""
        self._x = out[:6]
        (self.x_true, self.y_true, self.phi_true, _, _, _, self.q1, self.q2, self.q3,
         self.dq1, self.dq2, self.dq3, self.energy) = out.tolist()

    # numpy reference of the step (what the compiled step replaced; it raises the refusals)
    def _reference_step(self, t, dt):
        from dynamics.integrate import rk4_step

        n = int(self.substeps)
        h = dt / n
        x = self._x
        try:
            for k in range(n):
                x = rk4_step(self._rhs, t + k * h, x, h)
        except ValueError as exc:
            raise StepRefused(f"the platform left the tool space of posture {self.posture}: {exc}") from None
        self._x = np.asarray(x, dtype=float)
        self._reference_outputs()

    def _reference_outputs(self):
        from dynamics.model import joint_velocity_jacobian, total_energy
        from solver import ik

        X, dX = self._x[:3], self._x[3:]
        q = ik(self._model, X, int(self.posture))
        if np.isnan(q[0]):
            raise StepRefused(f"pose {X.tolist()} is outside the tool space of posture {self.posture}")
        dq = joint_velocity_jacobian(self._model, X, q) @ dX
        self.q1, self.q2, self.q3 = (float(v) for v in q)
        self.dq1, self.dq2, self.dq3 = (float(v) for v in dq)
        self.x_true, self.y_true, self.phi_true = (float(v) for v in X)
        self.energy = float(total_energy(self._params, self._model, X, dX, int(self.posture)))
