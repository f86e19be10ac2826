"""Time integration of the 3-RRR dynamics: fixed-step RK4, a DOP853 reference, the state-space forms.

Integrators share one calling convention: ``f(t, x) -> dx/dt`` with ``x`` a
1-D state array; they return the times ``t0 + k h`` (k = 0..n_steps, computed
from ``k``, never accumulated) and the states at those times.

State-space right-hand sides
----------------------------
* task space, state ``x = (X, dX)`` (6,): the validation reference; needs no
  direct kinematics (``q`` follows from ``X`` by inverse kinematics in a posture);
* joint space, state ``x = (q, dq)`` (6,): paper Fig. 3 / eq. 7; needs a pose
  supplier ``dk(q) -> X``.  In the co-simulation that supplier is the DK FMU;
  here :class:`NearestPoseDK` (all DK solutions by :func:`solver.dk_all`, keep
  the real one nearest to the previous pose) plays its part.

Speed
-----
The right-hand sides are callable objects that evaluate the compiled kernels
of :mod:`dynamics._kernel` for a single state (6,).  :func:`rk4_step` and
:func:`rk4` recognise the task-space right-hand side with constant torques and
then run the whole RK4 loop in one compiled call, with the same operations in
the same order as the generic loop (the results are the same to the last bit).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from solver import Manipulator, dk_all
from solver._checks import SolverInputError, as_array

from . import _kernel as _k
from .model import (ASSEMBLY_TOL, DynamicParameters, _check, _forward_joint, _forward_task, _ik, _kernel_model,
                    _kernel_params, _posture_bits, _single)

__all__ = ["rk4_step", "rk4", "solve_reference", "task_space_rhs", "joint_space_rhs", "NearestPoseDK"]


def _check_step(h, n_steps=None):
    if not (isinstance(h, (int, float, np.floating, np.integer)) and np.isfinite(h) and h > 0):
        raise SolverInputError(f"h: expected a positive finite step in s, got {h!r}")
    if n_steps is not None and not (isinstance(n_steps, (int, np.integer)) and n_steps >= 0):
        raise SolverInputError(f"n_steps: expected a non-negative integer, got {n_steps!r}")


def rk4_step(f: Callable, t: float, x, h: float) -> np.ndarray:
    """One classic fourth-order Runge-Kutta step.

    Parameters
    ----------
    f : callable ``f(t, x) -> dx/dt``
        Right-hand side; returns an array of the shape of ``x``.
    t : float
        Time at the start of the step, s.
    x : ndarray, shape (n,)
        State at ``t``.
    h : float
        Step, s.

    Returns
    -------
    ndarray, shape (n,)
        State at ``t + h``.
    """
    fast = _compiled_rk4(f, t, x, h, 1)
    return _rk4_generic(f, t, x, h) if fast is None else fast[1]


def _rk4_generic(f, t, x, h):
    k1 = f(t, x)
    k2 = f(t + 0.5 * h, x + (0.5 * h) * k1)
    k3 = f(t + 0.5 * h, x + (0.5 * h) * k2)
    k4 = f(t + h, x + h * k3)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _initial(f, t0, x0):
    x0 = as_array("x0", x0, trailing=(np.shape(x0)[0],)).copy()
    if not (isinstance(t0, (int, float, np.floating, np.integer)) and np.isfinite(t0)):
        raise SolverInputError(f"t0: expected a finite time in s, got {t0!r}")
    d = np.asarray(f(t0, x0))
    if d.shape != x0.shape:
        raise SolverInputError(f"f: expected f(t, x) of shape {x0.shape}, got {d.shape}")
    return x0


def rk4(f: Callable, t0: float, x0, h: float, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-step classic RK4 over ``n_steps`` steps.

    Parameters
    ----------
    f : callable ``f(t, x) -> dx/dt``
    t0 : float
        Initial time, s.
    x0 : array_like, shape (n,)
        Initial state.
    h : float
        Step, s (> 0).
    n_steps : int
        Number of steps (>= 0).

    Returns
    -------
    t : ndarray, shape (n_steps + 1,)
        ``t0 + k h``.
    x : ndarray, shape (n_steps + 1, n)
        States; ``x[0] = x0``.

    Raises
    ------
    SolverInputError
        Non-positive step, negative step count, a 1-D ``x0`` not given, or ``f``
        returning the wrong shape.
    """
    _check_step(h, n_steps)
    if np.ndim(x0) != 1:
        raise SolverInputError(f"x0: expected a state of shape (n,), got {np.shape(x0)}")
    x0 = _initial(f, t0, x0)
    t = t0 + h * np.arange(n_steps + 1)
    fast = _compiled_rk4(f, t0, x0, h, n_steps)
    if fast is not None:
        return t, fast
    xs = np.empty((n_steps + 1,) + x0.shape)
    xs[0] = x0
    for k in range(n_steps):
        xs[k + 1] = rk4_step(f, t[k], xs[k], h)
    return t, xs


def _compiled_rk4(f, t0, x0, h, n_steps):
    """States (n_steps + 1, 6) by the compiled RK4 loop, or None where it does not apply.

    It applies to the task-space right-hand side with constant torques, a
    single float64 state (6,) and a float step.  If a right-hand side is
    refused on the way (the pose left the tool space...), the generic loop
    redoes that step from the last state computed, and raises as it does.
    """
    if type(f) is not _TaskSpaceRHS or f.tau is None or f.bits < 0 or not _single((x0,), 6):
        return None
    if not (isinstance(h, (int, float, np.floating, np.integer)) and not isinstance(h, bool)):
        return None
    xs = np.empty((n_steps + 1, 6))
    xs[0] = x0
    done = _k.rk4_task(_kernel_model(f.model), _kernel_params(f.params), f.bits, f.tau, float(h), xs)
    for k in range(done, n_steps):      # the generic step raises (or, at an edge of the kernel, goes on)
        xs[k + 1] = _rk4_generic(f, t0 + h * k, xs[k], h)
    return xs


def solve_reference(f: Callable, t0: float, x0, h: float, n_steps: int, *, rtol: float = 1e-12,
                    atol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Reference solution by :func:`scipy.integrate.solve_ivp` (DOP853, adaptive, tight tolerances).

    Same calling convention and outputs as :func:`rk4`: the states are reported
    at ``t0 + k h`` (dense output of the adaptive method, not its steps).

    Parameters
    ----------
    f, t0, x0, h, n_steps
        As in :func:`rk4`.
    rtol, atol : float
        Tolerances of DOP853.

    Returns
    -------
    t : ndarray, shape (n_steps + 1,)
    x : ndarray, shape (n_steps + 1, n)

    Raises
    ------
    SolverInputError
        Bad arguments, or the integration failed (the message of solve_ivp is kept).
    """
    from scipy.integrate import solve_ivp

    _check_step(h, n_steps)
    if np.ndim(x0) != 1:
        raise SolverInputError(f"x0: expected a state of shape (n,), got {np.shape(x0)}")
    x0 = _initial(f, t0, x0)
    t = t0 + h * np.arange(n_steps + 1)
    if n_steps == 0:
        return t, x0[None].copy()
    sol = solve_ivp(f, (t[0], t[-1]), x0, method="DOP853", t_eval=t, rtol=rtol, atol=atol)
    if not sol.success:
        raise SolverInputError(f"f: solve_ivp failed: {sol.message}")
    return t, sol.y.T


def _torque_source(tau):
    """Turn ``tau`` (None, a constant (3,) array or a callable ``tau(t, x)``) into a callable."""
    if tau is None:
        zero = np.zeros(3)
        return lambda t, x: zero
    if callable(tau):
        return tau
    const = as_array("tau", tau)
    if const.shape != (3,):
        raise SolverInputError(f"tau: expected shape (3,) or a callable tau(t, x), got {const.shape}")
    return lambda t, x: const


def task_space_rhs(params: DynamicParameters, model: Manipulator, posture=1, tau=None) -> Callable:
    """Right-hand side of the task-space dynamics, state ``x = (X, dX)``.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    posture : int
        Posture 1..8 (motor angles by inverse kinematics).
    tau : None, array_like (3,) or callable ``tau(t, x) -> (3,)``
        Motor torques, N m (None: zero).

    Returns
    -------
    callable ``f(t, x) -> dx/dt``
        ``x`` of shape (..., 6): ``(x, y, phi, dx, dy, dphi)`` in m, rad and per s;
        ``dx/dt = (dX, ddX)``.  Raises :class:`SolverInputError` if the pose
        leaves the posture's tool space.
    """
    _check(params, model)
    return _TaskSpaceRHS(params, model, posture, tau)


def joint_space_rhs(params: DynamicParameters, model: Manipulator, dk: Callable, tau=None) -> Callable:
    """Right-hand side of the joint-space dynamics (eq. 7), state ``x = (q, dq)``.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    dk : callable ``dk(q) -> X``
        Pose supplier: the direct kinematics of the motor angles ``q`` (3,), m, m, rad.
    tau : None, array_like (3,) or callable ``tau(t, x) -> (3,)``
        Motor torques, N m (None: zero).

    Returns
    -------
    callable ``f(t, x) -> dx/dt``
        ``x`` = ``(q, dq)`` (6,) in rad and rad/s; ``dx/dt = (dq, ddq)``.
    """
    _check(params, model)
    if not callable(dk):
        raise SolverInputError(f"dk: expected a callable dk(q) -> X, got {type(dk).__name__}")
    return _JointSpaceRHS(params, model, dk, tau)


class _TaskSpaceRHS:
    """``f(t, x)`` of :func:`task_space_rhs`: compiled for a single state (6,) and an integer posture.

    ``tau`` is the constant torque (3,) (zeros for None) or None for a
    callable torque; ``bits`` the posture's elbow bits (-1: not a plain integer
    posture, the numpy route checks it at each call).
    """

    __slots__ = ("params", "model", "posture", "torque", "tau", "bits")

    def __init__(self, params, model, posture, tau):
        self.params, self.model, self.posture = params, model, posture
        self.torque = _torque_source(tau)
        self.tau = None if callable(tau) else self.torque(0.0, None)    # the checked array itself, as before
        self.bits = _posture_bits(posture)

    def __call__(self, t, x):
        tau = self.tau
        if self.bits >= 0 and _single((x,), 6):
            if tau is None:
                tau = np.asarray(self.torque(t, x))
            if _single((tau,)):
                out = np.empty(6)
                st = _k.task_rhs_batch(_kernel_model(self.model), _kernel_params(self.params), x.reshape(1, 6),
                                       tau.reshape(1, 3), self.bits, out.reshape(1, 6))
                if st == _k.OK:
                    return out
        X, dX = x[..., :3], x[..., 3:]
        q = _ik(self.model, X, self.posture)
        if tau is None:
            tau = np.asarray(self.torque(t, x))
        ddX = _forward_task(self.params, self.model, X, q, dX, tau)
        return np.concatenate([dX, ddX], axis=-1)


class _JointSpaceRHS:
    """``f(t, x)`` of :func:`joint_space_rhs`: compiled for a single state (6,) with a pose (3,)."""

    __slots__ = ("params", "model", "dk", "torque")

    def __init__(self, params, model, dk, tau):
        self.params, self.model, self.dk = params, model, dk
        self.torque = _torque_source(tau)

    def __call__(self, t, x):
        q, dq = x[..., :3], x[..., 3:]
        X = np.asarray(self.dk(q), dtype=float)
        tau = np.asarray(self.torque(t, x))
        if _single((x,), 6) and _single((X, tau)):
            out = np.empty(6)
            st = _k.joint_rhs_batch(_kernel_model(self.model), _kernel_params(self.params), x.reshape(1, 6),
                                    X.reshape(1, 3), tau.reshape(1, 3), ASSEMBLY_TOL, out.reshape(1, 6))
            if st == _k.OK:
                return out
        ddq = _forward_joint(self.params, self.model, q, dq, X, tau)
        return np.concatenate([dq, ddq], axis=-1)


class NearestPoseDK:
    """Pose supplier ``q -> X``: the real DK solution nearest to the previous pose.

    Stands in for the DK FMU.  Every call solves all six DK solutions
    (:func:`solver.dk_all`) and returns the real one nearest to the pose
    returned last (distance ``|dP|^2 + (r dphi)^2`` with ``r`` the mean platform
    radius and ``dphi`` wrapped), then remembers it.  Valid while the steps are
    small compared with the distance between assembly modes, i.e. away from
    type-1 singularities.

    Parameters
    ----------
    model : Manipulator
    X0 : array_like, shape (3,)
        The initial pose (the assembly mode of the robot), m, m, rad.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        The last pose returned.
    """

    def __init__(self, model: Manipulator, X0):
        if not isinstance(model, Manipulator):
            raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")
        X0 = as_array("X0", X0)
        if X0.shape != (3,):
            raise SolverInputError(f"X0: expected shape (3,), got {X0.shape}")
        self.model = model
        self.pose = X0.copy()
        self._r2 = float(np.mean(model.platform_radius)) ** 2

    def __call__(self, q) -> np.ndarray:
        """Pose (3,) of the motor angles ``q`` (3,), m, m, rad."""
        sol = dk_all(self.model, q)
        cand = sol.poses.real[sol.real]
        if len(cand) == 0:
            raise SolverInputError(f"q: expected joints with a real DK solution, got {np.asarray(q).tolist()}")
        d = cand - self.pose
        dphi = np.angle(np.exp(1j * d[:, 2]))
        k = int(np.argmin(d[:, 0] ** 2 + d[:, 1] ** 2 + self._r2 * dphi ** 2))
        self.pose = cand[k]
        return self.pose.copy()
