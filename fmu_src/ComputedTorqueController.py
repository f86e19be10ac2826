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

Speed: a step is one compiled call (:func:`dynamics._kernel.controller_step`: the reference of
:meth:`CircleTrajectory.joint`, ``q_X`` with the operations of :func:`solver.ik` and the law of
:func:`dynamics.model.inverse_dynamics`).  Whatever it refuses (a pose outside the tool space, a
pose that does not close the loops of ``q_X``...) is redone by the numpy code
(``_reference_step``), which raises the documented refusal.
"""
import numpy as np

from fmu_src.table_slave import StepRefused, TableSlave, Var


class ComputedTorqueController(TableSlave):
    description = "Computed-torque control of the 3-RRR on a circle, model terms at the DK pose"
    author = "rrr-dk"

    VARIABLES = (
        Var("q1", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 1"),
        Var("q2", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 2"),
        Var("q3", "Real", "input", start=0.0, unit="rad", description="measured motor angle, leg 3"),
        Var("dq1", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 1"),
        Var("dq2", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 2"),
        Var("dq3", "Real", "input", start=0.0, unit="rad/s", description="measured motor rate, leg 3"),
        Var("x", "Real", "input", start=0.5, unit="m", description="platform x from the DK FMU"),
        Var("y", "Real", "input", start=0.28867513459481287, unit="m", description="platform y from the DK FMU"),
        Var("phi", "Real", "input", start=0.0, unit="rad", description="orientation from the DK FMU"),
        Var("bandwidth", "Real", "parameter", "fixed", start=50.0, unit="rad/s", min=1e-3,
            description="closed-loop error bandwidth (natural frequency)"),
        Var("damping", "Real", "parameter", "fixed", start=1.0, unit="1", min=1e-3,
            description="closed-loop error damping ratio"),
        Var("mass_scale", "Real", "parameter", "fixed", start=1.0, unit="1", min=1e-3,
            description="the controller's belief of the masses (factor on the default model)"),
        Var("posture", "Integer", "parameter", "fixed", start=1, min=1, max=8, description="posture"),
        Var("center_x", "Real", "parameter", "fixed", start=0.45, unit="m", description="circle centre x"),
        Var("center_y", "Real", "parameter", "fixed", start=0.30, unit="m", description="circle centre y"),
        Var("radius", "Real", "parameter", "fixed", start=0.25, unit="m", min=1e-6, description="circle radius"),
        Var("phi_ref", "Real", "parameter", "fixed", start=-0.7853981633974483, unit="rad",
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
    # _kpack, _bits, _tol: packed constants, elbow bits and loop tolerance of the compiled step;
    # _kstep: its entry point; _out: its result buffer (scratch, read right after every call)
    CONSTANT = ("_model", "_params", "_gains", "_traj", "_kpack", "_bits", "_tol", "_kstep", "_out")

    def setup(self):
        self._model = self._params = self._gains = self._traj = None
        self._kpack = self._bits = self._tol = self._kstep = self._out = None

    def on_initialized(self):
        from dynamics import _kernel
        from dynamics.control import ComputedTorqueGains, _controller_pack
        from dynamics.model import ASSEMBLY_TOL, DynamicParameters
        from dynamics.trajectory import CircleTrajectory
        from solver import Manipulator

        self._model = Manipulator.paper()
        self._params = DynamicParameters().with_scaled_masses(float(self.mass_scale))
        self._gains = ComputedTorqueGains.design(float(self.bandwidth), float(self.damping))
        self._traj = CircleTrajectory(center=(float(self.center_x), float(self.center_y)),
                                      radius=float(self.radius), phi=float(self.phi_ref),
                                      posture=int(self.posture), period=float(self.period),
                                      ramp_time=float(self.ramp_time))
        self._kpack = _controller_pack(self._params, self._model, self._gains, self._traj)
        self._bits, self._tol = int(self.posture) - 1, ASSEMBLY_TOL
        self._kstep, self._out = _kernel.controller_step, np.empty(9)
        self._reference(self.time_start())
        # load the compiled step's machine code now, not in the first doStep (result unused: the
        # outputs at initialization are the reference only, as before)
        self._kstep(self._kpack, self._bits, self.time_start(), self.q1, self.q2, self.q3, self.dq1, self.dq2,
                    self.dq3, self.x, self.y, self.phi, self._tol, self._out)

    def time_start(self):
        return float(getattr(self, "_time", 0.0) or 0.0)

    def _reference(self, t, numpy=False):
        """Set the reference outputs at ``t`` (compiled, or by the numpy reference); returns
        ``q_d, dq_d, ddq_d``."""
        traj = self._traj
        task, joint = (traj._reference_task, traj._reference_joint) if numpy else (traj.task, traj.joint)
        X_d, _, _ = task(t)
        q_d, dq_d, ddq_d = joint(self._model, t)
        self.x_ref, self.y_ref, self.phi_ref_out = (float(v) for v in X_d)
        self.q1_ref, self.q2_ref, self.q3_ref = (float(v) for v in q_d)
        return q_d, dq_d, ddq_d

    def step(self, t, dt):
        out = self._out
        if self._kstep(self._kpack, self._bits, t, self.q1, self.q2, self.q3, self.dq1, self.dq2, self.dq3,
                       self.x, self.y, self.phi, self._tol, out):
            return self._reference_step(t, dt)          # refused: the numpy code raises (or answers)
        (self.tau1, self.tau2, self.tau3, self.x_ref, self.y_ref, self.phi_ref_out,
         self.q1_ref, self.q2_ref, self.q3_ref) = out.tolist()

    # numpy reference of the step (what the compiled step replaced; it raises the refusals)
    def _reference_step(self, t, dt):
        from dynamics.control import wrap
        from dynamics.model import inverse_dynamics
        from solver import ik

        q_d, dq_d, ddq_d = self._reference(t, numpy=True)
        q = np.array([self.q1, self.q2, self.q3])
        dq = np.array([self.dq1, self.dq2, self.dq3])
        X = np.array([self.x, self.y, self.phi])
        q_X = ik(self._model, X, int(self.posture))
        if np.isnan(q_X[0]):
            raise StepRefused(f"pose (x, y, phi) = {X.tolist()} from the DK is outside the tool space of "
                              f"posture {self.posture}")
        # q_X equals q up to 2 pi turns when the pose belongs to the measured joints
        q_X = q + wrap(q_X - q)
        ddq = ddq_d + self._gains.kd * (dq_d - dq) + self._gains.kp * wrap(q_d - q)
        tau = inverse_dynamics(self._params, self._model, q_X, dq, ddq, X)
        self.tau1, self.tau2, self.tau3 = (float(v) for v in tau)
