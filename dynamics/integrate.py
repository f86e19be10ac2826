"""Time integration of the 3-RRR dynamics: fixed-step RK4, a DOP853 reference, the state-space forms.

Integrators share one calling convention: ``f(t, x) -> dx/dt`` with ``x`` a 1-D state array;
they return the times ``t0 + k h`` (k = 0..n_steps, computed from ``k``, never accumulated) and
the states at those times.

RK4 is written once (:func:`dynamics._kernels.rk4.make_rk4_step`).  :func:`rk4_step` and
:func:`rk4` run it as Python around any ``f``; on the task-space right-hand side with constant
torques (and a single state (6,)) they run the same step compiled, the whole loop in one call,
with the same operations in the same order (the results are the same to the last bit).

State-space right-hand sides
----------------------------
* task space, state ``x = (X, dX)`` (6,): the validation reference; needs no direct kinematics
  (``q`` follows from ``X`` by inverse kinematics in a posture);
* joint space, state ``x = (q, dq)`` (6,): paper Fig. 3 / eq. 7; needs a pose supplier
  ``dk(q) -> X``.  In the co-simulation that supplier is the DK FMU; here :class:`NearestPoseDK`
  (all DK solutions by :func:`solver.dk_all`, keep the real one nearest to the previous pose)
  plays its part.

Both evaluate a compiled kernel for a single state (6,) and the checked batch route otherwise; a
refusal (the pose left the tool space...) raises :class:`dynamics.DynamicsError`.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from solver import Manipulator, SolverInputError, as_array
from solver.direct_kinematics import nearest_solution

from ._checks import broadcast, check_model, check_pair, ik_or_raise, is_single, posture_bits
from ._evaluate import evaluate_joint, evaluate_task
from ._kernels import rows as _rows
from ._kernels.layout import FORWARD, refusal
from ._kernels.rk4 import PYTHON_STAGES, make_rk4_step, rk4_task
from ._packs import arm_pack, bodies_pack
from .errors import refused
from .geometry import ASSEMBLY_TOL
from .parameters import DynamicParameters

__all__ = ["rk4_step", "rk4", "solve_reference", "task_space_rhs", "joint_space_rhs", "NearestPoseDK"]


def _call(f, t, x, slot):
    return 0, f(t, x)


#: the RK4 step around a Python ``f(t, x)`` (``ctx`` is ``f``)
_rk4_python = make_rk4_step(_call)


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
    if _compiled(f, x, h):
        return _rk4_task(f, x, h, 1)[1]
    return _rk4_python(f, t, np.asarray(x), h, None, PYTHON_STAGES)[1]


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
        Non-positive step, negative step count, a 1-D ``x0`` not given, or ``f`` returning the
        wrong shape.
    DynamicsError
        The right-hand side refused a state (e.g. the pose left the tool space).
    """
    _check_step(h, n_steps)
    if np.ndim(x0) != 1:
        raise SolverInputError(f"x0: expected a state of shape (n,), got {np.shape(x0)}")
    x0 = _initial(f, t0, x0)
    t = t0 + h * np.arange(n_steps + 1)
    if _compiled(f, x0, h):
        return t, _rk4_task(f, x0, h, n_steps)
    xs = np.empty((n_steps + 1,) + x0.shape)
    xs[0] = x0
    for k in range(n_steps):
        _rk4_python(f, t[k], xs[k], h, xs[k + 1], PYTHON_STAGES)
    return t, xs


def _compiled(f, x, h) -> bool:
    """Whether the compiled RK4 applies: the task-space right-hand side with constant torques, a
    single float64 state (6,) and a real step."""
    return (type(f) is _TaskSpaceRHS and f.tau is not None and f.bits >= 0 and is_single((x,), 6)
            and isinstance(h, (int, float, np.floating, np.integer)) and not isinstance(h, bool))


def _rk4_task(f, x0, h, n_steps):
    """States (n_steps + 1, 6) by the compiled RK4 loop; a refused step raises."""
    xs = np.empty((n_steps + 1, 6))
    xs[0] = x0
    code = rk4_task(arm_pack(f.model), bodies_pack(f.params), f.bits, f.tau, float(h), xs)
    if code:
        status, k = refusal(code)
        raise f.refused(status, xs[k + 1], f.tau)      # row k + 1 holds the stage state refused
    return xs


def solve_reference(f: Callable, t0: float, x0, h: float, n_steps: int, *, rtol: float = 1e-12,
                    atol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Reference solution by :func:`scipy.integrate.solve_ivp` (DOP853, adaptive, tight tolerances).

    Same calling convention and outputs as :func:`rk4`: the states are reported at ``t0 + k h``
    (dense output of the adaptive method, not its steps).

    Parameters
    ----------
    f, t0, x0, h, n_steps
        As in :func:`rk4`.
    rtol, atol : float
        Tolerances of DOP853.

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
        ``dx/dt = (dX, ddX)``.  Raises :class:`DynamicsError` if the pose leaves the posture's
        tool space.
    """
    check_pair(params, model)
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
    check_pair(params, model)
    if not callable(dk):
        raise SolverInputError(f"dk: expected a callable dk(q) -> X, got {type(dk).__name__}")
    return _JointSpaceRHS(params, model, dk, tau)


class _TaskSpaceRHS:
    """``f(t, x)`` of :func:`task_space_rhs`: compiled for a single state (6,) and an integer posture.

    ``tau`` is the constant torque (3,) (zeros for None) or None for a callable torque; ``bits``
    the posture's elbow bits (-1: not a plain integer posture, checked at each call).
    """

    __slots__ = ("params", "model", "posture", "torque", "tau", "bits")

    def __init__(self, params, model, posture, tau):
        self.params, self.model, self.posture = params, model, posture
        self.torque = _torque_source(tau)
        self.tau = None if callable(tau) else self.torque(0.0, None)    # the checked array itself
        self.bits = posture_bits(posture)

    def refused(self, code, x, tau):
        return refused(code, {"X": x[:3], "dX": x[3:], "tau": tau}, model=self.model, posture=self.posture)

    def __call__(self, t, x):
        tau = self.tau if self.tau is not None else np.asarray(self.torque(t, x))
        if self.bits >= 0 and is_single((x,), 6) and is_single((tau,)):
            out = np.empty(6)
            code = _rows.task_rhs_batch(arm_pack(self.model), bodies_pack(self.params), x.reshape(1, 6),
                                        tau.reshape(1, 3), self.bits, out.reshape(1, 6))
            if code:
                raise self.refused(code, x, tau)
            return out
        X, dX, tau = broadcast(X=as_array("X", x[..., :3]), dX=as_array("dX", x[..., 3:]),
                               tau=as_array("tau", tau))
        q = ik_or_raise(self.model, X, self.posture)
        ddX = evaluate_task(self.params, self.model, FORWARD, self.posture, {"X": X, "dX": dX, "tau": tau}, q)
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
        if is_single((x,), 6) and is_single((X, tau)):
            out = np.empty(6)
            code = _rows.joint_rhs_batch(arm_pack(self.model), bodies_pack(self.params), x.reshape(1, 6),
                                         X.reshape(1, 3), tau.reshape(1, 3), ASSEMBLY_TOL, out.reshape(1, 6))
            if code:
                raise refused(code, {"q": q, "dq": dq, "X": X, "tau": tau}, model=self.model)
            return out
        arrays = dict(q=as_array("q", q), dq=as_array("dq", dq), X=as_array("X", X), tau=as_array("tau", tau))
        arrays = dict(zip(arrays, broadcast(**arrays)))
        ddq = evaluate_joint(self.params, self.model, FORWARD, arrays)
        return np.concatenate([arrays["dq"], ddq], axis=-1)


class NearestPoseDK:
    """Pose supplier ``q -> X``: the real DK solution nearest to the previous pose.

    Stands in for the DK FMU.  Every call returns the real DK solution nearest to the pose returned
    last (:func:`solver.direct_kinematics.nearest_solution`: the eq. 19 distance with weights
    ``(1, 1, r^2)``, ``r`` the mean platform radius, ``dphi`` wrapped), then remembers it.  Valid while the
    steps are small compared with the distance between assembly modes, i.e. away from type-1
    singularities.

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
        check_model(model)
        X0 = as_array("X0", X0)
        if X0.shape != (3,):
            raise SolverInputError(f"X0: expected shape (3,), got {X0.shape}")
        self.model = model
        self.pose = X0.copy()
        self._w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])

    def __call__(self, q) -> np.ndarray:
        """Pose (3,) of the motor angles ``q`` (3,), m, m, rad."""
        X = nearest_solution(self.model, q, self.pose, self._w)
        if np.isnan(X[0]):
            raise SolverInputError(f"q: expected joints with a real DK solution, got {np.asarray(q).tolist()}")
        self.pose = X
        return X.copy()
