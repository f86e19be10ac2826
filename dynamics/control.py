r"""Computed-torque control of the 3-RRR (paper Fig. 2) and an in-process closed loop.

Control law (Modern Robotics' computed torque: the mass matrix times the
desired acceleration plus PD, plus the rest of the inverse dynamics):

.. math::

   \tau = M(q)\,(\ddot q_d + K_d \dot e + K_p e) + C(q, \dot q)\dot q + G(q) + F(q, \dot q),
   \qquad e = q_d - q,

with ``M, C, G, F`` evaluated at the pose ``X`` the direct kinematics returns
for the measured joints (:func:`dynamics.inverse_dynamics`).  ``e`` is
wrapped to (-pi, pi]: motor angles that differ by 2 pi are the same input.
With an exact model the error obeys ``de'' + K_d de' + K_p e = 0`` per joint,
a double integrator ``[0 1; 0 0]`` under state feedback ``[K_p K_d]``; the
gains come from pole placement with python-control on that model
(:meth:`ComputedTorqueGains.design`).

The law is built from the lower-level terms: ``v = ddq_d + K_d de + K_p e`` is the commanded
acceleration and ``tau`` the inverse dynamics at ``v``, ``M v + (C dq + G + F)``
(:func:`dynamics.inverse_dynamics`); one compiled kernel evaluates both
(:func:`dynamics._kernels.control.computed_torque_batch`).  The FMU controller runs the same law
through :class:`dynamics.ControllerStepper`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from solver import Manipulator, SolverInputError, as_array, cache_dir, wrap_angle
from solver.checks import check_instance

from ._checks import broadcast, check_pair, is_single
from ._evaluate import evaluate_computed_torque
from .integrate import NearestPoseDK, joint_space_rhs, rk4_step
from .parameters import DynamicParameters
from .trajectory import CircleTrajectory

__all__ = ["ComputedTorqueGains", "ComputedTorqueController", "computed_torque", "TrackingResult",
           "simulate_tracking", "wrap"]


#: Angles (rad) wrapped to (-pi, pi], elementwise: :func:`solver.wrap_angle`, the one wrap of the numpy side.
wrap = wrap_angle


def _double_integrator():
    return np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])


@dataclass(frozen=True, eq=False)
class ComputedTorqueGains:
    """PD gains of the computed-torque law, per joint.

    Parameters
    ----------
    kp : array_like (3,) or float
        Proportional gains, 1/s^2 (> 0).
    kd : array_like (3,) or float
        Derivative gains, 1/s (> 0).

    Use :meth:`design` to get them from a bandwidth and a damping ratio.
    """

    kp: np.ndarray
    kd: np.ndarray

    def __post_init__(self):
        for key, unit in (("kp", "1/s^2"), ("kd", "1/s")):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.ndim == 0:
                arr = np.full(3, float(arr))
            if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                raise SolverInputError(f"{key}: expected three positive finite gains in {unit}, "
                                       f"got {getattr(self, key)!r}")
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)

    @staticmethod
    def requested_poles(bandwidth: float, damping: float) -> np.ndarray:
        """The two error-dynamics poles ``-zeta w +- w sqrt(zeta^2 - 1)`` (complex if zeta < 1), 1/s."""
        for key, v in (("bandwidth", bandwidth), ("damping", damping)):
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v) and v > 0):
                raise SolverInputError(f"{key}: expected a positive finite number, got {v!r}")
        root = np.sqrt(complex(damping ** 2 - 1.0))
        p = bandwidth * np.array([-damping + root, -damping - root])
        return p.real if damping >= 1.0 else p

    @classmethod
    def design(cls, bandwidth: float = 50.0, damping: float = 1.0) -> "ComputedTorqueGains":
        """Place the poles of each joint's error dynamics.

        The error of joint ``i`` is a double integrator ``x' = A x + B v``,
        ``x = (e, de)``, ``A = [[0, 1], [0, 0]]``, ``B = [[0], [1]]``; the law
        ``v = -[K_p K_d] x`` puts its poles at ``requested_poles(bandwidth, damping)``.
        Distinct poles are placed with :func:`control.place`; a double pole
        (``damping = 1``) with Ackermann's formula (:func:`control.place_acker`),
        since ``place`` refuses poles repeated more often than the input count.

        Parameters
        ----------
        bandwidth : float
            Natural frequency ``w`` of the error dynamics, rad/s (> 0).  With
            ``damping = 1`` the closed loop from reference to position has its
            -3 dB point at ``0.64 w``.  Keep ``w h << 1`` for a controller period ``h``.
        damping : float
            Damping ratio ``zeta`` (> 0); 1 (default) is critically damped.

        Returns
        -------
        ComputedTorqueGains
            With ``kp = w^2`` and ``kd = 2 zeta w`` up to rounding.

        Notes
        -----
        Importing python-control takes ~0.8 s (it imports scipy.signal and matplotlib), more than
        a whole closed-loop run: the placed gains are kept, per python-control and numpy version,
        in memory and in ``designed-gains.json`` of the cache root (:func:`_designed_gains`), and a
        process imports python-control only for a design it has never seen.
        """
        cls.requested_poles(bandwidth, damping)                  # checks the arguments
        kp, kd = _designed_gains(bandwidth, damping)
        return cls(kp=np.full(3, kp), kd=np.full(3, kd))

    @staticmethod
    def place(bandwidth: float, damping: float) -> tuple[float, float]:
        """``(K_p, K_d)`` placed by python-control (what :meth:`design` returns, without its cache)."""
        import control

        poles = ComputedTorqueGains.requested_poles(bandwidth, damping)
        A, B = _double_integrator()
        if abs(poles[0] - poles[1]) <= 1e-9 * abs(poles[0]):
            acker = getattr(control, "place_acker", None) or control.acker
            K = np.asarray(acker(A, B, poles), dtype=float).reshape(2)
        else:
            K = np.asarray(control.place(A, B, poles), dtype=float).reshape(2)
        return float(K[0]), float(K[1])

    def error_dynamics(self):
        """Closed-loop error dynamics of the three joints as a :class:`control.StateSpace`.

        State ``(e_1, e_2, e_3, de_1, de_2, de_3)``, input an acceleration
        disturbance (rad/s^2), output ``e`` (rad):
        ``A = [[0, I], [-diag(kp), -diag(kd)]]``.
        """
        import control

        Z, I = np.zeros((3, 3)), np.eye(3)
        A = np.block([[Z, I], [-np.diag(self.kp), -np.diag(self.kd)]])
        return control.ss(A, np.vstack([Z, I]), np.hstack([I, Z]), np.zeros((3, 3)))


def gains_cache_file() -> Path:
    """The file of designed gains: ``designed-gains.json`` under the project's one cache root
    (:func:`solver.cache_dir`: ``$RRR_DK_CACHE``, else ``$XDG_CACHE_HOME/rrr-dk``, else ``~/.cache/rrr-dk``)."""
    return cache_dir() / "designed-gains.json"


def _gains_key(bandwidth, damping) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        control_version = version("control")
    except PackageNotFoundError:
        control_version = "none"
    return (f"control {control_version}, numpy {np.__version__}: "
            f"{type(bandwidth).__name__} {bandwidth!r}, {type(damping).__name__} {damping!r}")


def _places(kp, kd, bandwidth, damping) -> bool:
    """Whether ``s^2 + kd s + kp`` has the requested poles (to 1e-9): a cached entry is sound."""
    p = ComputedTorqueGains.requested_poles(bandwidth, damping)
    scale = 1.0 + abs(p[0] * p[1]) + abs(p[0] + p[1])
    return (isinstance(kp, float) and isinstance(kd, float) and kp > 0 and kd > 0
            and abs(kp - (p[0] * p[1]).real) <= 1e-9 * scale and abs(kd + (p[0] + p[1]).real) <= 1e-9 * scale)


def _read_gains(path: Path) -> dict:
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return table if isinstance(table, dict) else {}


@lru_cache(maxsize=64, typed=True)
def _designed_gains(bandwidth, damping) -> tuple[float, float]:
    """``(K_p, K_d)`` of :meth:`ComputedTorqueGains.place`, from the cache file when it has them
    for these python-control and numpy versions (bit for bit what they computed, checked against
    the requested poles), else placed now and added to the file.  A file that cannot be read or
    written is ignored."""
    path = gains_cache_file()
    key = _gains_key(bandwidth, damping)
    table = _read_gains(path)
    entry = table.get(key)
    if isinstance(entry, list) and len(entry) == 2 and _places(*entry, bandwidth, damping):
        return entry[0], entry[1]
    kp, kd = ComputedTorqueGains.place(bandwidth, damping)
    table[key] = [kp, kd]
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(table, indent=0, sort_keys=True))     # floats as repr: exact
        os.replace(tmp, path)
    except OSError:
        pass
    return kp, kd


def computed_torque(params: DynamicParameters, model: Manipulator, gains: ComputedTorqueGains,
                    q, dq, X, q_d, dq_d, ddq_d) -> np.ndarray:
    """Motor torques of the computed-torque law.

    Parameters
    ----------
    params : DynamicParameters
        The controller's model of the robot (may differ from the real one).
    model : Manipulator
    gains : ComputedTorqueGains
    q, dq : array_like, shape (..., 3)
        Measured motor angles (rad) and rates (rad/s).
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics, m, m, rad.
    q_d, dq_d, ddq_d : array_like, shape (..., 3)
        Desired motor angles, rates, accelerations (rad, rad/s, rad/s^2).

    Returns
    -------
    ndarray, shape (..., 3)
        ``tau`` in N m.
    """
    check_pair(params, model)
    _check_gains(gains)
    arrays = {"q": q, "dq": dq, "X": X, "q_d": q_d, "dq_d": dq_d, "ddq_d": ddq_d}
    single = is_single(arrays.values())
    if not single:
        arrays = dict(zip(arrays, broadcast(**{k: as_array(k, v) for k, v in arrays.items()})))
    return evaluate_computed_torque(params, model, gains, arrays, single)


def _check_gains(gains):
    if not isinstance(gains, ComputedTorqueGains):   # isinstance first: the fast path of every call
        check_instance("gains", gains, ComputedTorqueGains, "a ComputedTorqueGains")


@dataclass(frozen=True, eq=False)
class ComputedTorqueController:
    """A computed-torque controller: the robot model it believes in, and its gains.

    Parameters
    ----------
    params : DynamicParameters
        The controller's dynamic model.
    model : Manipulator
        Geometry.
    gains : ComputedTorqueGains

    Calling it, ``controller(q, dq, X, q_d, dq_d, ddq_d)``, is :func:`computed_torque`.
    """

    params: DynamicParameters
    model: Manipulator
    gains: ComputedTorqueGains

    def __post_init__(self):
        check_pair(self.params, self.model)
        _check_gains(self.gains)

    def __call__(self, q, dq, X, q_d, dq_d, ddq_d) -> np.ndarray:
        """Motor torques (..., 3), N m; arguments as in :func:`computed_torque`."""
        return computed_torque(self.params, self.model, self.gains, q, dq, X, q_d, dq_d, ddq_d)


class TrackingResult(NamedTuple):
    """Samples of a closed-loop run at the controller instants ``t_k = k h``.

    Attributes
    ----------
    t : ndarray (n + 1,)
        Time, s.
    q, dq : ndarray (n + 1, 3)
        Plant motor angles (rad, unwrapped as integrated) and rates (rad/s).
    X : ndarray (n + 1, 3)
        Pose from the direct kinematics of ``q``, m, m, rad.
    tau : ndarray (n + 1, 3)
        Torque applied (held) from ``t_k`` to ``t_k + h``, N m.
    q_d, dq_d : ndarray (n + 1, 3)
        Reference.
    error : ndarray (n + 1, 3)
        ``wrap(q_d - q)``, rad.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    X: np.ndarray
    tau: np.ndarray
    q_d: np.ndarray
    dq_d: np.ndarray
    error: np.ndarray

    def rms_error(self, t_from: float = 0.0) -> float:
        """RMS of the joint error over the three joints and the samples with ``t >= t_from``, rad."""
        e = self.error[self.t >= t_from - 1e-12]
        return float(np.sqrt(np.mean(e * e)))

    def max_error(self, t_from: float = 0.0) -> float:
        """Largest ``|e_i|`` over the samples with ``t >= t_from``, rad."""
        return float(np.max(np.abs(self.error[self.t >= t_from - 1e-12])))


def _check_loop(controller, plant, trajectory, t_end, h):
    """The argument checks of :func:`simulate_tracking` (:class:`SolverInputError` naming the argument)."""
    check_instance("controller", controller, ComputedTorqueController, "a ComputedTorqueController")
    check_pair(plant, controller.model)
    check_instance("trajectory", trajectory, CircleTrajectory, "a CircleTrajectory")
    for key, v in (("t_end", t_end), ("h", h)):
        if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v) and v > 0):
            raise SolverInputError(f"{key}: expected a positive finite time in s, got {v!r}")


def simulate_tracking(controller: ComputedTorqueController, plant: DynamicParameters,
                      trajectory: CircleTrajectory, t_end: float, h: float = 1e-3, *,
                      dk_plant: Callable | None = None, dk_controller: Callable | None = None,
                      q0=None, dq0=None) -> TrackingResult:
    """Closed loop in process: computed torque (sampled, zero-order hold) on the joint-space plant.

    At each controller instant ``t_k = k h`` the controller reads the plant's
    ``q, dq`` (exact measurements), gets ``X = dk_controller(q)``, computes
    ``tau`` with the reference at ``t_k``, and the plant
    (:func:`dynamics.integrate.joint_space_rhs` with ``plant`` parameters and
    ``dk_plant``) advances by one RK4 step of ``h`` with ``tau`` held.

    Parameters
    ----------
    controller : ComputedTorqueController
    plant : DynamicParameters
        The real robot's parameters (e.g. ``controller.params.with_scaled_masses(1.2)``).
    trajectory : CircleTrajectory
        Reference; ``trajectory.joint`` gives ``q_d, dq_d, ddq_d``.
    t_end : float
        Duration, s.
    h : float
        Controller period and integration step, s.
    dk_plant, dk_controller : callable ``q -> X``, optional
        Pose suppliers; default a separate :class:`NearestPoseDK` each, started at
        the reference pose at ``t = 0``.
    q0, dq0 : array_like (3,), optional
        Initial plant state; default the reference at ``t = 0``.

    Returns
    -------
    TrackingResult
    """
    _check_loop(controller, plant, trajectory, t_end, h)
    model = controller.model
    n = int(round(t_end / h))
    t = h * np.arange(n + 1)
    q_d, dq_d, ddq_d = trajectory.joint(model, t)
    X0 = trajectory.task(0.0)[0]
    dk_plant = dk_plant or NearestPoseDK(model, X0)
    dk_controller = dk_controller or NearestPoseDK(model, X0)
    x = np.concatenate([q_d[0] if q0 is None else as_array("q0", q0),
                        dq_d[0] if dq0 is None else as_array("dq0", dq0)])
    if x.shape != (6,):
        raise SolverInputError(f"q0, dq0: expected shapes (3,), got {x.shape}")
    held = [np.zeros(3)]
    f = joint_space_rhs(plant, model, dk_plant, tau=lambda t_, x_: held[0])
    qs, dqs, Xs, taus = (np.empty((n + 1, 3)) for _ in range(4))
    ctrl = controller
    for k in range(n + 1):
        q, dq = x[:3], x[3:]
        X = np.asarray(dk_controller(q), dtype=float)
        tau = evaluate_computed_torque(ctrl.params, model, ctrl.gains, {"q": q, "dq": dq, "X": X, "q_d": q_d[k],
                                                                        "dq_d": dq_d[k], "ddq_d": ddq_d[k]})
        qs[k], dqs[k], Xs[k], taus[k] = q, dq, X, tau
        if k < n:
            held[0] = tau
            x = rk4_step(f, t[k], x, h)
    return TrackingResult(t, qs, dqs, Xs, taus, q_d, dq_d, wrap(q_d - qs))
