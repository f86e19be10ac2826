"""Procedures 2-3: choose, at every step of a joint stream, the DK solution that is the robot.

``Tracker(model, map_tensor, mode=...)`` is constant (geometry, map, options);
its mutable data is a :class:`TrackerState` (previous pose and joints, the
scale of recent joint steps), replaced as a whole at every accepted step, so a
rejected step leaves it untouched and a caller can save and restore it (an FMU
rolling back a step does exactly that).

Modes
-----
``mode="paper"``: procedures 2 and 3 exactly as written.  All six DK
solutions of the current joints, numbered by the map's rule; procedure 2 at the
previous pose (labels of the nodes within radius ``r``, eq. 18-19); far from
a border the region is the one label seen; near a border it is the label of the
node nearest the eq. 22 prediction ``X_prev - J^-1 K (q - q_prev)``; the
answer is the solution with that number.  Where that solution is not real
(procedure 3 has no answer) the nearest real solution to the prediction is
returned and the step is flagged ``ambiguous``.

``mode="default"``: what the measurements (README, ``bench/bench_tracker.py``)
show works best.  The eq. 22 predictor is a single Euler step of the velocity
model; near singularities and for coarse sampling its error is as large as the
distance between solutions.  The default mode integrates the same velocity
model ``J dX = -K dq`` along the straight joint segment from the previous to
the current joints with RK4 (one substep per 0.05 rad of joint motion, at most
16): a continuation predictor whose error is far below the gap between
solutions whenever the segment does not pass a branch point.  Candidates are
the real solutions whose label is seen by procedure 2 near the previous pose
or near the prediction (the map's part: a solution in a region not adjacent to
the motion is never taken); the one nearest the prediction wins.  The choice is
flagged ``ambiguous`` when it is not certain: the nearest other real solution
is less than ``1 / ambiguity_ratio`` times farther from the prediction, the map
and the prediction disagree, the predictor met a singularity (it then falls
back to eq. 22 or the previous pose), or the joint step is ``jump_factor``
times larger than recent steps.

Every step reports a :class:`StepInfo`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import _track_kernel as _tk
from ._checks import SolverInputError, as_array
from .kinematics import _RULE_CODES, NEWTON_STEPS, REAL_RESIDUAL, REAL_SNAP, _constants, wrap_angle
from .manipulator import Manipulator
from .maptensor import MapTensor

__all__ = ["Tracker", "TrackerState", "StepInfo", "TrackResult", "STATUS", "TrackerError"]

#: Status codes of a step (also the FMU's ``status`` output).
STATUS = {0: "ok", 1: "unreachable", 2: "singular", 3: "rejected", 4: "diverged"}


class TrackerError(ValueError):
    """A tracker used wrongly (no state yet, a map of another geometry...)."""


@dataclass(frozen=True)
class TrackerState:
    """The tracker's data: everything a step reads and writes.

    Attributes
    ----------
    X : ndarray, shape (3,)
        Previous pose (m, m, rad).
    q : ndarray, shape (3,)
        Previous joints (rad).
    X2 : ndarray, shape (3,) or None
        The pose before ``X`` (for the tool-space extrapolation), None right after a reset.
    dq_scale : float
        Running mean of recent joint step sizes max|dq_i| (rad), for jump detection.
    steps : int
        Accepted steps since reset.
    dt : float
        Duration of the last accepted step (s) when the caller gave one, else NaN.
    """

    X: np.ndarray
    q: np.ndarray
    X2: np.ndarray | None = None
    dq_scale: float = 0.0
    steps: int = 0
    dt: float = float("nan")

    @property
    def history(self) -> int:
        """Consecutive known poses (1, or 2 when ``X2`` is the pose before ``X``)."""
        return 1 if self.X2 is None else 2

    def as_array(self) -> np.ndarray:
        """The state as 12 floats (X, q, X2 or NaN, dq_scale, steps, dt or NaN): what an FMU serialises."""
        x2 = np.full(3, np.nan) if self.X2 is None else self.X2
        return np.concatenate([self.X, self.q, x2, [self.dq_scale, float(self.steps), self.dt]])

    @classmethod
    def from_array(cls, a) -> "TrackerState":
        a = np.asarray(a, dtype=float)
        if a.shape != (12,) or not np.all(np.isfinite(a[[0, 1, 2, 3, 4, 5, 9, 10]])):
            raise TrackerError(f"state: expected 12 floats (X, q, X2, dq_scale, steps, dt), got {a!r}")
        x2 = None if np.any(np.isnan(a[6:9])) else a[6:9].copy()
        return cls(a[:3].copy(), a[3:6].copy(), x2, float(a[9]), int(a[10]), float(a[11]))


class StepInfo(NamedTuple):
    """What a step knows about its choice.

    Attributes
    ----------
    label : int
        Solution number (region) used, 1..6; 0 when nothing was chosen.
    near_border : bool
        Procedure 2 saw more than one label near the previous pose.
    X_pred : ndarray, shape (3,)
        The prediction the choice was compared with (eq. 22 in paper mode, the
        continuation predictor in default mode, the start of Newton for baselines).
    n_real : int
        Number of real DK solutions (-1 where a baseline does not compute them).
    cond : float
        Hadamard ratio |det J| / prod |rows of J| at the returned pose (0 singular, 1 best).
    ambiguous : bool
        The choice is not certain (see the module docstring).
    status : int
        See :data:`STATUS`: 0 ok, 1 unreachable (pose held), 2 singular, 4 diverged.
    jump : bool
        The joint step was far larger than recent ones.
    d_best, d_second : float
        Weighted distance (m) from the prediction to the chosen and to the
        nearest other real solution.
    """

    label: int
    near_border: bool
    X_pred: np.ndarray
    n_real: int
    cond: float
    ambiguous: bool
    status: int
    jump: bool
    d_best: float
    d_second: float

    @property
    def status_name(self) -> str:
        return STATUS[self.status]


class TrackResult(NamedTuple):
    """Result of :meth:`Tracker.track`: poses and per-step information as arrays.

    Attributes
    ----------
    X : ndarray (n, 3)
    label, n_real, status : ndarray of int (n,)
    near_border, ambiguous, jump : ndarray of bool (n,)
    X_pred : ndarray (n, 3)
    cond, d_best, d_second : ndarray (n,)
    seconds : ndarray (n,)
        Wall time of each step (s); 0 for the initial pose.
    """

    X: np.ndarray
    label: np.ndarray
    near_border: np.ndarray
    X_pred: np.ndarray
    n_real: np.ndarray
    cond: np.ndarray
    ambiguous: np.ndarray
    status: np.ndarray
    jump: np.ndarray
    d_best: np.ndarray
    d_second: np.ndarray
    seconds: np.ndarray


def _check_q(q) -> np.ndarray:
    """q as a float array (3,), or SolverInputError naming ``q`` (fast path for the common case)."""
    if isinstance(q, np.ndarray) and q.shape == (3,) and q.dtype == np.float64 and np.isfinite(q).all():
        return q
    arr = as_array("q", q, (3,))
    if arr.shape != (3,):
        raise SolverInputError(f"q: expected shape (3,), got {arr.shape}")
    return arr


class _TrackerBase:
    """reset / step / track shared by the tracker and the baselines."""

    name = "base"

    def __init__(self, model: Manipulator):
        if not isinstance(model, Manipulator):
            raise TrackerError(f"model: expected a Manipulator, got {type(model).__name__}")
        self.model = model
        k = _constants(model)
        tol = REAL_RESIDUAL * float(np.min(model.l2) ** 2)
        self._geo = np.concatenate([k["M"].ravel(), k["l1"], k["l2sq"], k["b"].ravel(), k["cos8"], k["sin8"],
                                    k["psi"], [REAL_SNAP, tol, float(NEWTON_STEPS)]])
        self._T = np.ascontiguousarray(k["T"])
        self._w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])
        self.state: TrackerState | None = None
        self._st = np.empty(12)
        self._out_f = np.empty(11)
        self._ii = np.empty(7, dtype=np.int64)

    def reset(self, X0, q0) -> None:
        """Start tracking from a known configuration.

        Parameters
        ----------
        X0 : array_like, shape (3,)
            Pose at ``q0`` (m, m, rad).
        q0 : array_like, shape (3,)
            Joints (rad).
        """
        X0 = as_array("X0", X0, (3,))
        q0 = as_array("q0", q0, (3,))
        if X0.shape != (3,) or q0.shape != (3,):
            raise SolverInputError(f"X0, q0: expected shapes (3,) and (3,), got {X0.shape} and {q0.shape}")
        X0 = X0.copy()
        X0[2] = wrap_angle(X0[2])
        self.state = TrackerState(X0, q0.copy(), None, 0.0, 0, float("nan"))

    def _kernel(self, q, st):                                      # pragma: no cover - abstract
        raise NotImplementedError

    def step(self, q, dt: float | None = None):
        """Track one step: the pose of the manipulator at joints ``q``.

        Parameters
        ----------
        q : array_like, shape (3,)
            Current joints (rad).
        dt : float, optional
            Time since the previous sample (s).  Only the ratio of successive
            ``dt`` matters (it scales the tool-space extrapolation); without it
            the samples are taken as uniformly spaced.

        Returns
        -------
        X : ndarray, shape (3,)
            Pose (m, m, rad); the previous pose when ``q`` is unreachable.
        info : StepInfo

        Raises
        ------
        SolverInputError
            ``q`` of the wrong shape or not finite; the state is unchanged.
        TrackerError
            No state yet (call :meth:`reset`).
        """
        q = _check_q(q)
        st = self.state
        if st is None:
            raise TrackerError(f"{self.name}: no state; call reset(X0, q0) first")
        pk = self._st
        pk[0:3], pk[3:6] = st.X, st.q
        pk[6:9] = st.X if st.X2 is None else st.X2
        pk[9], pk[10] = st.history, st.dq_scale
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise SolverInputError(f"dt: expected a positive time step in s, got {dt!r}")
        pk[11] = dt / st.dt if dt is not None and np.isfinite(st.dt) else 1.0
        self._kernel(q, pk)
        ii, of = self._ii, self._out_f
        status = int(ii[_tk.I_STATUS])
        X = of[0:3].copy()
        fi = of[6:11]
        info = StepInfo(int(ii[_tk.I_LABEL]), bool(ii[_tk.I_NEAR_BORDER]), of[3:6].copy(),
                        int(ii[_tk.I_N_REAL]), float(fi[_tk.F_COND]), bool(ii[_tk.I_AMBIGUOUS]), status,
                        bool(ii[_tk.I_JUMP]), float(fi[_tk.F_D_BEST]), float(fi[_tk.F_D_SECOND]))
        if status != _tk.STATUS_UNREACHABLE:
            dqn = float(fi[_tk.F_DQ])
            scale = dqn if st.steps == 0 else 0.8 * st.dq_scale + 0.2 * dqn
            self.state = TrackerState(X, q.copy(), st.X, scale, st.steps + 1,
                                      float("nan") if dt is None else float(dt))
        return X, info

    def track(self, q_stream, X0) -> TrackResult:
        """Track a whole joint stream.

        Parameters
        ----------
        q_stream : array_like, shape (n, 3)
            Joints (rad); ``q_stream[0]`` is the configuration of ``X0``.
        X0 : array_like, shape (3,)
            Pose at ``q_stream[0]`` (m, m, rad).

        Returns
        -------
        TrackResult
        """
        import time

        q_stream = as_array("q_stream", q_stream, (3,))
        if q_stream.ndim != 2 or len(q_stream) < 1:
            raise SolverInputError(f"q_stream: expected shape (n, 3) with n >= 1, got {q_stream.shape}")
        n = len(q_stream)
        self.reset(X0, q_stream[0])
        out = {k: np.zeros(n, dtype=t) for k, t in (("label", int), ("near_border", bool), ("n_real", int),
                                                     ("cond", float), ("ambiguous", bool), ("status", int),
                                                     ("jump", bool), ("d_best", float),
                                                     ("d_second", float), ("seconds", float))}
        X = np.zeros((n, 3))
        Xp = np.zeros((n, 3))
        X[0] = Xp[0] = self.state.X
        for k in range(1, n):
            t0 = time.perf_counter()
            X[k], info = self.step(q_stream[k])
            out["seconds"][k] = time.perf_counter() - t0
            Xp[k] = info.X_pred
            for key in ("label", "near_border", "n_real", "cond", "ambiguous", "status", "jump", "d_best",
                        "d_second"):
                out[key][k] = getattr(info, key)
        return TrackResult(X=X, X_pred=Xp, **out)


class Tracker(_TrackerBase):
    """The basic-regions DK tracker (procedures 2-3) of one posture.

    Parameters
    ----------
    model : Manipulator
    map_tensor : MapTensor
        Map of the tracker's posture, built for ``model`` (same geometry digest).
    mode : {"default", "paper"}
        See the module docstring.
    r : float, optional
        Procedure-2 radius (eq. 18); default ``map_tensor.default_radius()``.
    weights : array_like (3,), optional
        Eq. 19 weights; default ``map_tensor.default_weights`` (1, 1, rho^2).
    ambiguity_ratio : float
        Default mode: flag ``ambiguous`` when ``d_best > ambiguity_ratio * d_second``.
    jump_factor : float
        Flag ``ambiguous`` when max|dq| exceeds this many times the recent mean step.
    singular_tol : float
        Hadamard ratio of J below which a configuration is reported singular.
    use_map : bool
        Default mode: restrict candidates by procedure 2 (True) or not (for measurements).
    """

    def __init__(self, model: Manipulator, map_tensor: MapTensor, mode: str = "default", r=None,
                 weights=None, ambiguity_ratio: float = 0.25, jump_factor: float = 20.0,
                 singular_tol: float = 1e-4, use_map: bool = True, strategy: int = 2,
                 segment_singular: float = 0.05):
        super().__init__(model)
        if not isinstance(map_tensor, MapTensor):
            raise TrackerError(f"map_tensor: expected a MapTensor, got {type(map_tensor).__name__}")
        if map_tensor.model.digest() != model.digest():
            raise TrackerError(f"map_tensor: built for geometry {map_tensor.model.name!r}, not for "
                               f"{model.name!r}")
        if mode not in ("default", "paper"):
            raise TrackerError(f"mode: expected 'default' or 'paper', got {mode!r}")
        for key, val in (("ambiguity_ratio", ambiguity_ratio), ("jump_factor", jump_factor),
                         ("singular_tol", singular_tol)):
            if not (np.isfinite(val) and val > 0):
                raise TrackerError(f"{key}: expected a positive number, got {val!r}")
        self.map = map_tensor
        self.mode = mode
        self.posture = map_tensor.posture
        self.name = f"tracker-{mode}" if use_map or mode == "paper" else "tracker-nomap"
        w = map_tensor.default_weights if weights is None else as_array("weights", weights, (3,))
        r = map_tensor.default_radius(w) if r is None else float(r)
        self._w = np.ascontiguousarray(w, dtype=float)
        self.r = r
        self._labels = np.ascontiguousarray(map_tensor.labels)
        self._mgeo = np.concatenate([map_tensor.origin, map_tensor.step, [1.0 if map_tensor.periodic else 0.0,
                                                                          r * r], self._w])
        self._stencil = map_tensor._stencil(r, w)
        self._params = np.array([ambiguity_ratio, jump_factor, 0.05, 16.0, singular_tol,
                                 1.0 if use_map else 0.0, float(strategy), segment_singular])
        self._mode = _tk.MODE_PAPER if mode == "paper" else _tk.MODE_DEFAULT
        self._rule = _RULE_CODES[map_tensor.rule]

    def _kernel(self, q, st):
        _tk.tracker_step_packed(self._mode, self._rule, q, st, self._geo, self._T, self._labels, self._mgeo,
                                self._stencil, self._params, self._out_f, self._ii)
