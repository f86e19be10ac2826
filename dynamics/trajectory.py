r"""A smooth time law on the experiments' circle, starting from rest.

The geometry is :data:`solver.PAPER_CIRCLE` (centre (0.45, 0.30) m, radius
0.25 m, constant phi = -45 deg, posture 1; the path :func:`solver.circle_path`
samples).  The time law is on the polar angle ``theta`` of the circle:

.. math::

   \dot\theta(t) = \Omega\, s(t / T_r) \quad (0 \le t < T_r), \qquad
   \dot\theta(t) = \Omega \quad (t \ge T_r), \qquad
   s(u) = 10u^3 - 15u^4 + 6u^5,

``Omega = 2 pi / period``.  The quintic smoothstep ``s`` has ``s(0) = 0``,
``s(1) = 1`` and zero first and second derivatives at both ends, so the motion
starts from rest (zero velocity and acceleration at ``t = 0``) and velocity,
acceleration and jerk are continuous at ``T_r``.  Integrating,
``theta = theta_0 + Omega T_r (5u^4/2 - 3u^5 + u^6)`` during the ramp and
``theta = theta_0 + Omega (t - T_r / 2)`` after it.  Before ``t = 0`` the robot
rests at ``theta_0``.

Defaults: one revolution per 2 s (``Omega = pi`` rad/s, tool speed
``0.25 pi = 0.785`` m/s, centripetal acceleration 2.47 m/s^2) reached after a
0.5 s ramp (peak tangential acceleration ``1.875 Omega r / T_r = 2.95`` m/s^2).

The joint-space reference is exact: ``q_d = g_j(X)`` (inverse kinematics in the
posture), ``dq_d = J_q dX`` (eq. 3) and ``ddq_d = J_q ddX + ddq_0(X, dX)`` from
the loop constraints differentiated twice (:func:`dynamics.joint_accelerations`).

Implementation: :meth:`CircleTrajectory.polar_angle`, :meth:`CircleTrajectory.task` and
:meth:`CircleTrajectory.joint` run the one compiled time law and circle
(:mod:`dynamics._kernels.circle`: the formulas above with scalar code, and the kinematics core's
inverse kinematics, :func:`solver.ik`'s), a few microseconds per call.  A time
that is not finite, or a point outside the tool space, raises :class:`dynamics.DynamicsError`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver import PAPER_CIRCLE, Manipulator, SolverInputError, check_posture

from ._checks import check_model
from ._kernels.circle import circle_batch, polar_batch
from ._kernels.layout import BAD_INPUT, refusal
from ._packs import arm_pack, bodies_pack, circle_pack
from .errors import DynamicsError, refused
from .geometry import KINEMATIC_ONLY

__all__ = ["CircleTrajectory"]


def _positive(name, value, allow_zero=False):
    ok = isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and (
        value >= 0 if allow_zero else value > 0)
    if not ok:
        what = "non-negative" if allow_zero else "positive"
        raise SolverInputError(f"{name}: expected a {what} finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class CircleTrajectory:
    """Circle in the tool space at constant orientation, traversed counter-clockwise from rest.

    Parameters
    ----------
    center : (float, float)
        Centre, m.
    radius : float
        Radius, m.
    phi : float
        Constant platform orientation, rad.
    posture : int
        Posture 1..8 of the inverse kinematics.
    period : float
        Time per revolution at cruise speed, s.
    ramp_time : float
        Duration of the smoothstep speed ramp from rest, s (0: cruise speed at
        once, the motion then does not start from rest).
    start : float
        Polar angle of the start point, rad (0: the point ``center + (radius, 0)``).

    Examples
    --------
    >>> traj = CircleTrajectory()
    >>> X, dX, ddX = traj.task(0.0)
    >>> bool(np.all(dX == 0) and np.all(ddX == 0))
    True
    """

    center: tuple = field(default=tuple(PAPER_CIRCLE["center"]))
    radius: float = PAPER_CIRCLE["radius"]
    phi: float = PAPER_CIRCLE["phi"]
    posture: int = PAPER_CIRCLE["posture"]
    period: float = 2.0
    ramp_time: float = 0.5
    start: float = 0.0

    def __post_init__(self):
        c = np.asarray(self.center, dtype=float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise SolverInputError(f"center: expected two finite numbers in m, got {self.center!r}")
        object.__setattr__(self, "center", (float(c[0]), float(c[1])))
        object.__setattr__(self, "radius", _positive("radius", self.radius))
        object.__setattr__(self, "period", _positive("period", self.period))
        object.__setattr__(self, "ramp_time", _positive("ramp_time", self.ramp_time, allow_zero=True))
        for key in ("phi", "start"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v)):
                raise SolverInputError(f"{key}: expected a finite angle in rad, got {v!r}")
            object.__setattr__(self, key, float(v))
        object.__setattr__(self, "posture", int(check_posture(self.posture)))

    @property
    def angular_speed(self) -> float:
        """Cruise rate of the polar angle ``Omega = 2 pi / period``, rad/s."""
        return 2.0 * np.pi / self.period

    def polar_angle(self, t):
        """Polar angle of the circle and its first two time derivatives.

        Parameters
        ----------
        t : float or array_like, shape (...)
            Time, s.

        Returns
        -------
        theta, dtheta, ddtheta : ndarray, shape (...)
            rad, rad/s, rad/s^2.
        """
        t = np.asarray(t, dtype=float)
        if not np.all(np.isfinite(t)):
            raise SolverInputError(f"t: expected finite times in s, got {t!r}")
        out = np.empty(t.shape + (3,))
        polar_batch(circle_pack(self), np.ascontiguousarray(t.reshape(-1)), out.reshape(-1, 3))
        return out[..., 0], out[..., 1], out[..., 2]

    def task(self, t):
        """Tool-space reference at time ``t``.

        Parameters
        ----------
        t : float or array_like, shape (...)
            Time, s.

        Returns
        -------
        X, dX, ddX : ndarray, shape (..., 3)
            Pose (m, m, rad), rate (m/s, m/s, rad/s), acceleration (m/s^2, m/s^2, rad/s^2).
        """
        X, dX, ddX = self._compiled(None, t)
        return X, dX, ddX

    def joint(self, model: Manipulator, t):
        """Joint-space reference at time ``t`` (exact IK, velocity and acceleration models).

        Parameters
        ----------
        model : Manipulator
        t : float or array_like, shape (...)
            Time, s.

        Returns
        -------
        q_d, dq_d, ddq_d : ndarray, shape (..., 3)
            Motor angles in (-pi, pi] (rad), rates (rad/s), accelerations (rad/s^2).

        Raises
        ------
        SolverInputError
            If the circle leaves the posture's tool space for this geometry.
        """
        check_model(model)
        return tuple(self._compiled(model, t)[3:])

    def _compiled(self, model, t):
        """``[X, dX, ddX, q, dq, ddq]`` at the times ``t`` by the kernel (the last three only with
        a ``model``), each of shape ``t.shape + (3,)``."""
        tt = np.asarray(t, dtype=float)
        shape = tt.shape
        flat = np.ascontiguousarray(tt.reshape(-1))
        joint = model is not None
        buf = np.empty((6 if joint else 3, flat.shape[0], 3))
        circle = circle_pack(self)
        if joint:
            arm, bodies = arm_pack(model), bodies_pack(KINEMATIC_ONLY)
        else:
            arm = bodies = circle                         # unused without the joint part
        code = circle_batch(arm, bodies, circle, self.posture - 1, flat, joint, buf[0], buf[1], buf[2],
                            buf[3 if joint else 0], buf[4 if joint else 0], buf[5 if joint else 0])
        if code:
            raise self._refused(code, model, tt)
        return [b.reshape(shape + (3,)) for b in buf]

    def _refused(self, code, model, t):
        status, index = refusal(code)
        where = tuple(int(i) for i in np.unravel_index(index, t.shape)) if t.shape else None
        if status == BAD_INPUT:
            return DynamicsError(f"t: expected finite times in s, got {t!r}", "non-finite", where)
        X = self._compiled(None, t)[0]
        return refused(code, {"X": X}, model=model, posture=self.posture, lead=t.shape)
