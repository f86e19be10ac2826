"""The tracking loop shared by the tracker and the baselines: reset, step, track.

A tracker is constant; :meth:`_TrackerBase.step` packs its :class:`TrackerState`
for the compiled step (``_kernel``), reads the outputs back and makes the next
state (a rejected or held sample moves only its counts), with the stuck-joint
detector's bookkeeping (:mod:`solver.stuck`).  The tracker's options and the
meaning of ``certain``: :mod:`solver.tracker`.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ._kernels.certify import CERT_CONTINUATION, CERT_REACQUIRED
from ._kernels.layout import (F_COND, F_D_BEST, F_D_SECOND, F_DQ, F_INNOV, I_AMBIGUOUS, I_CERTAIN, I_CERTIFICATE,
                              I_INTACT, I_JUMP, I_LABEL, I_N_CAND, I_N_REAL, I_NEAR_BORDER, I_STATUS, INFO_I_SIZE,
                              MAX_REFUSED, OUT_CANDS, OUT_INFO, OUT_SIZE, OUT_X, OUT_X_PRED, STATE_A_SCALE,
                              STATE_ANCHOR, STATE_ANCHOR_AGE, STATE_CANDS, STATE_DQ_SCALE, STATE_EXT_SCALE,
                              STATE_HAVE_Q2, STATE_HISTORY, STATE_INTACT, STATE_N_CAND, STATE_Q, STATE_Q2,
                              STATE_REFUSED, STATE_SIZE, STATE_STEP_DT, STATE_VERIFIED, STATE_X, STATE_X2,
                              STATUS_REJECTED, STATUS_UNREACHABLE)
from .checks import SolverInputError, as_array
from .direct_kinematics import kernel_constants
from .kinematics import wrap_angle
from .manipulators import MANIPULATOR_TYPES
from .stuck import reading_fields, repeat_counts, stuck_refusal
from .tracker_state import STEP_FIELDS, StepInfo, TrackerError, TrackerState, TrackResult

#: With measured joints and a speed bound: samples held in a row (a pose the platform cannot have
#: reached) after which the next pose is taken whatever its distance (see "Sensors").
MAX_HELD = 10


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
    #: Identical readings in a row that mark a joint stuck (0: off); see :mod:`solver.stuck`.
    stuck_after = 0

    def __init__(self, model):
        if not isinstance(model, tuple(MANIPULATOR_TYPES.values())):
            raise TrackerError(f"model: expected a Manipulator or an RPRManipulator, got {type(model).__name__}")
        self.model = model
        # a 3-RPR's legs have limits: the tool space its re-acquisition searches ends there
        self._limits = (model.rho_min, model.rho_max) if model.kind == "3-RPR" else None
        k = kernel_constants(model)
        self._model_pack, self._sample_to_sextic = k["pack"], k["sample_to_sextic"]
        self._w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])
        self.state: TrackerState | None = None
        self._state_pack = np.empty(STATE_SIZE)
        self._out_real = np.empty(OUT_SIZE)
        self._out_int = np.empty(INFO_I_SIZE, dtype=np.int64)

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
        self.state = TrackerState(X0, q0.copy(), None, 0.0, 0, float("nan"), anchor=X0, anchor_age=0.0,
                                  reading=q0.copy())

    def _kernel(self, q, state_pack):                              # pragma: no cover - abstract
        """Run the compiled step on joints ``q`` and the state pack into the output packs."""
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
        if self._limits is not None and (np.any(q < self._limits[0]) or np.any(q > self._limits[1])):
            raise SolverInputError(f"q: expected leg lengths within the joint limits [{self._limits[0]}, "
                                   f"{self._limits[1]}] m, got {q.tolist()}")
        st = self.state
        if st is None:
            raise TrackerError(f"{self.name}: no state; call reset(X0, q0) first")
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise SolverInputError(f"dt: expected a positive time step in s, got {dt!r}")
        if self.stuck_after:
            repeats = repeat_counts(st, q)
            held = stuck_refusal(st, q, repeats, self.stuck_after)
            if held is not None:                             # a stuck joint: back to the clean state, refused
                self.state = held
                since = held.uncertain_since if held.uncertain_since >= 0 else held.steps + 1
                return held.X.copy(), StepInfo(0, False, held.X.copy(), 0, 0.0, False, STATUS_REJECTED, False,
                                               0.0, 0.0, False, 0, max(len(held.candidates), 1), since)
            extra = reading_fields(st, q, repeats)
        else:
            extra = {}
        pk = self._state_pack
        pk[STATE_X:STATE_X + 3], pk[STATE_Q:STATE_Q + 3] = st.X, st.q
        pk[STATE_X2:STATE_X2 + 3] = st.X if st.X2 is None else st.X2
        pk[STATE_HISTORY], pk[STATE_DQ_SCALE] = st.history, st.dq_scale
        pk[STATE_EXT_SCALE] = (dt / st.dt if dt is not None and np.isfinite(st.dt) else 1.0) * (st.skipped + 1)
        # the speed gate (measured joints): not after the sensor broke its tolerance (a forced sample)
        # nor after MAX_HELD samples held in a row (the robot moved on: follow the joints again)
        # (samples refused as a stuck joint's are known not to be the robot's: the gate stays on)
        stuck = self.stuck_after > 0 and st.clean is not None and int(st.repeats.max()) >= self.stuck_after - 1
        gate_on = dt is not None and st.refused < MAX_REFUSED and (st.skipped < MAX_HELD or stuck)
        pk[STATE_STEP_DT] = dt * (st.skipped + 1) if gate_on else float("nan")
        if st.q2 is None:
            pk[STATE_HAVE_Q2] = 0.0
        else:
            pk[STATE_Q2:STATE_Q2 + 3], pk[STATE_HAVE_Q2] = st.q2, 1.0
        n = len(st.candidates)
        if n == 0:                                           # right after a reset: the initial pose
            pk[STATE_CANDS:STATE_CANDS + 3], pk[STATE_N_CAND] = st.X, 1.0
        else:
            pk[STATE_CANDS:STATE_CANDS + 3 * n], pk[STATE_N_CAND] = st.candidates.ravel(), n
        pk[STATE_VERIFIED] = 1.0 if st.verified else 0.0
        pk[STATE_INTACT] = 1.0 if st.intact else 0.0
        pk[STATE_A_SCALE], pk[STATE_REFUSED] = st.a_scale, st.refused
        age = st.anchor_age + dt * (st.skipped + 1) if dt is not None else float("nan")
        if st.anchor is None:
            pk[STATE_ANCHOR:STATE_ANCHOR + 3], pk[STATE_ANCHOR_AGE] = st.X, float("nan")
        else:
            pk[STATE_ANCHOR:STATE_ANCHOR + 3], pk[STATE_ANCHOR_AGE] = st.anchor, age
        self._kernel(q, pk)
        ii, of = self._out_int, self._out_real
        status = int(ii[I_STATUS])
        X = of[OUT_X:OUT_X + 3].copy()
        fi = of[OUT_INFO:]
        certain, n_cand = bool(ii[I_CERTAIN]), int(ii[I_N_CAND])
        since = -1 if certain else (st.uncertain_since if st.uncertain_since >= 0 else st.steps + 1)
        info = StepInfo(int(ii[I_LABEL]), bool(ii[I_NEAR_BORDER]), of[OUT_X_PRED:OUT_X_PRED + 3].copy(),
                        int(ii[I_N_REAL]), float(fi[F_COND]), bool(ii[I_AMBIGUOUS]), status,
                        bool(ii[I_JUMP]), float(fi[F_D_BEST]), float(fi[F_D_SECOND]), certain,
                        int(ii[I_CERTIFICATE]), n_cand, since)
        if status == STATUS_REJECTED:                       # an outlier: only the counts of refusals move
            self.state = replace(st, refused=st.refused + 1, skipped=st.skipped + 1, **extra)
        elif status == STATUS_UNREACHABLE:                  # pose held: only the count of skipped samples
            self.state = replace(st, skipped=st.skipped + 1, **extra)
        else:
            dqn, innov = float(fi[F_DQ]), float(fi[F_INNOV])
            scale = dqn if st.steps == 0 else 0.8 * st.dq_scale + 0.2 * dqn
            cands = of[OUT_CANDS:OUT_CANDS + 3 * n_cand].reshape(n_cand, 3).copy()
            cert = int(ii[I_CERTIFICATE])
            # a sample taken after refusals (the joints jumped and stayed): the sensor broke its
            # tolerance, so the last certain pose no longer bounds where the robot is
            anchor = None if st.refused >= MAX_REFUSED else st.anchor
            self.state = TrackerState(X, q.copy(), st.X, scale, st.steps + 1,
                                      float("nan") if dt is None else float(dt) * (st.skipped + 1), st.q, cands,
                                      cert in (CERT_CONTINUATION, CERT_REACQUIRED), since, bool(ii[I_INTACT]),
                                      innov if st.steps < 2 else max(innov, 0.8 * st.a_scale + 0.2 * innov), 0,
                                      X if certain else anchor, 0.0 if certain else age, **extra)
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
        q_stream = as_array("q_stream", q_stream, (3,))
        if q_stream.ndim != 2 or len(q_stream) < 1:
            raise SolverInputError(f"q_stream: expected shape (n, 3) with n >= 1, got {q_stream.shape}")
        n = len(q_stream)
        self.reset(X0, q_stream[0])
        out = {k: np.zeros(n, dtype=t) for k, t in STEP_FIELDS + (("seconds", float),)}
        out["certain"][0], out["uncertain_since"][0] = True, -1
        X = np.zeros((n, 3))
        Xp = np.zeros((n, 3))
        X[0] = Xp[0] = self.state.X
        for k in range(1, n):
            t0 = time.perf_counter()
            X[k], info = self.step(q_stream[k])
            out["seconds"][k] = time.perf_counter() - t0
            Xp[k] = info.X_pred
            for key, _ in STEP_FIELDS:
                out[key][k] = getattr(info, key)
        return TrackResult(X=X, X_pred=Xp, **out)


