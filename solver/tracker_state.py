"""The tracker's data: :class:`TrackerState` (what a step reports, :class:`StepInfo` and :class:`TrackResult`,
is :mod:`solver.step_info`, re-exported here).

The tracker (:mod:`solver.tracker`) is constant; everything a step reads and
writes is a :class:`TrackerState`, replaced as a whole at every accepted step,
so a rejected step leaves it untouched and a caller (an FMU rolling back a
step) can keep a reference and restore it.  :meth:`TrackerState.as_array` is
its serialised form (a fixed number of floats, :data:`STATE_FLOATS`; the layout and the
checks of a saved array are :mod:`solver.state_array`).

A tracker keeps its data as that array and advances it in place, compiled
(:mod:`solver._kernels.stepper`); a :class:`TrackerState` is made from it when
read.  With the stuck-joint detector or the encoder-grid watch on, a step works on
the object: it packs itself for the compiled step (:meth:`TrackerState.pack`, the
state pack of :mod:`solver._kernels.layout`) and makes the next state from the
step's result pack (:meth:`TrackerState.after`), which the compiled stepper follows
float for float; :meth:`StepInfo.from_result` reads the same result pack.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ._kernels.certify import CERT_CONTINUATION, CERT_REACQUIRED
from ._kernels.layout import (F_DQ, F_INNOV, I_CERTAIN, I_CERTIFICATE, I_INTACT, I_N_CAND, I_STATUS, MAX_REFUSED,
                              OUT_BOUND, OUT_CANDS, OUT_INFO, OUT_N_PAVE, OUT_N_TUBES, OUT_PAVE, OUT_REGION, OUT_TUBE,
                              OUT_X, PAVE_BOXES, STATE_A_SCALE,
                              STATE_ANCHOR, STATE_ANCHOR_AGE, STATE_ANCHOR_BOUND, STATE_CANDS, STATE_DQ_SCALE,
                              STATE_EXT_SCALE, STATE_HAVE_Q2, STATE_HISTORY, STATE_INTACT, STATE_N_CAND,
                              STATE_N_PAVE, STATE_PAVE,
                              STATE_N_TUBES, STATE_Q, STATE_Q2, STATE_REFUSED, STATE_STEP_DT, STATE_TUBE,
                              STATE_VERIFIED, STATE_X, STATE_X2, STATUS_REJECTED, STATUS_UNREACHABLE)
from ._kernels.state_layout import MAX_HELD  # noqa: F401 (documented here)
from ._kernels.tube import TUBE_SIZE
from ._kernels.tube_chain import MAX_COVER
from .state_array import (STATE_FLOATS, TrackerError, _AGE, _ANCHOR, _ANCHOR_BOUND, _A_SCALE, _BASE, _CANDS,
                          _CLEAN_LAG, _CLEAN_TIME, _DQ_SCALE, _DT, _FINITE, _INTACT, _N_CAND, _N_PAVE, _N_TUBES,
                          _PAVE, _Q, _Q2, _READING, _REFUSED, _REPEATS, _SINCE, _SKIPPED, _SKIPPED_TIME, _STEPS,
                          _TUBE, _VERIFIED, _WALK, _X, _X2, _saved_cover, _saved_paving, _saved_seconds, _saved_walk)  # noqa: F401
# what a step reports lives in step_info; re-exported here, where callers have always found it
from .step_info import CERTIFICATES, NO_BOUND, STATUS, STEP_FIELDS, TRUST, StepInfo, TrackResult  # noqa: F401

__all__ = ["TrackerState", "StepInfo", "TrackResult", "TrackerError", "STATUS", "CERTIFICATES", "TRUST",
           "STATE_FLOATS", "NO_BOUND"]






def _cover(out_real: np.ndarray) -> np.ndarray | None:
    """The step's cover of tubes (n, TUBE_SIZE) from its result pack; None when it has none (a baseline's
    step, which vouches without tubes)."""
    n = out_real[OUT_N_TUBES]
    if not (np.isfinite(n) and 1 <= n <= MAX_COVER):
        return None
    n = int(n)
    return out_real[OUT_TUBE:OUT_TUBE + n * TUBE_SIZE].reshape(n, TUBE_SIZE).copy()


def _no_candidates() -> np.ndarray:
    return np.zeros((0, 3))


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
    q2 : ndarray, shape (3,) or None
        The joints before ``q`` (the parabola of the certificates), None right after a reset.
    candidates : ndarray, shape (n, 3), 1 <= n <= 6
        The DK solutions at ``q`` that the true branch can be (m, m, rad); one
        when the branch is known.  Empty means ``X`` alone (right after a reset).
    verified : bool
        The single candidate ends a verified chain (its tiny box is proved).
    uncertain_since : int
        Step index (steps since reset) since which the tracker cannot vouch; -1 while it can.
    intact : bool
        Every step since the reset was vouched for over the tube of joint paths
        within the tracker's ``joint_tolerance`` of the samples (always True with
        exact joints, ``joint_tolerance = 0``); once False, ``certain`` stays False
        until the next reset.
    a_scale : float
        Envelope of recent joint innovations (rad): the largest of the last innovation and
        a running mean decaying by a fifth per sample; the outlier gate's scale.
    refused : int
        Samples refused in a row since the last accepted one.
    anchor : ndarray, shape (3,) or None
        The centre of a pose box known to hold the robot (m, m, rad): the pose of the last certain
        step or, with a speed bound and joint tolerance, the box of the last uncertain step's
        set-membership update (:func:`solver._kernels.paving.region_step`); None before the first.
    anchor_age : float
        Seconds since that step (NaN when the caller gives no time steps).
    skipped : int
        Samples since the last accepted one (refused or held).
    skipped_time : float
        Seconds those samples spanned (the sum of their ``dt``; NaN when one came without): the next
        accepted sample is ``skipped_time + dt`` after the last accepted one, however uneven the steps.
    reading : ndarray, shape (3,) or None
        The last joints read (accepted or not), rad; for the stuck-joint detector.
    repeats : ndarray of int, shape (3,)
        Readings in a row each joint repeated its previous reading exactly.
    clean : TrackerState or None
        While a joint repeats: the state before its first repeated reading (the stuck-joint
        detector rolls back to it; :mod:`solver.stuck`).
    clean_lag : int
        Samples read since ``clean`` was taken.
    clean_time : float
        Seconds those samples spanned (NaN when one came without ``dt``).
    anchor_bound : ndarray, shape (3,)
        The half-widths of that box about ``anchor`` (m, m, rad; inf when none): with the speed
        bound, where the robot can be since.
    tube : ndarray, shape (n, 36) or None
        While certain: the last step's cover of tubes (:mod:`solver._kernels.tube`: each a centre
        pose, ``S``, centre joints, kappa, rho, its joint set; 1 <= n <= 27) that holds the
        robot's pose for every joint vector within the tolerance of ``q``; the next step's tube
        chain starts from it.  None when not certain.
    paving : ndarray, shape (n, 6) or None
        With a speed bound, while not certain: the set-membership step's pose boxes (x, y, phi
        lo/hi; 1 <= n <= PAVE_BOXES, :mod:`solver._kernels.paving`) whose hull is the box about
        ``anchor``; they hold the robot ``anchor_age`` ago.  None: the box about ``anchor`` alone.
    walk : ndarray, shape (k,) or None
        With a step budget, while the tube chain is unfinished: the walk the next step goes on
        with (the leading floats of :mod:`solver._kernels.anytime`'s pack: its tubes, where it
        stands, the readings still to reach).  None when there is none.
    """

    X: np.ndarray
    q: np.ndarray
    X2: np.ndarray | None = None
    dq_scale: float = 0.0
    steps: int = 0
    dt: float = float("nan")
    q2: np.ndarray | None = None
    candidates: np.ndarray = field(default_factory=_no_candidates)
    verified: bool = False
    uncertain_since: int = -1
    intact: bool = True
    a_scale: float = 0.0
    refused: int = 0
    anchor: np.ndarray | None = None
    anchor_age: float = float("nan")
    skipped: int = 0
    reading: np.ndarray | None = None
    repeats: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.int64))
    clean: "TrackerState | None" = None
    clean_lag: int = 0
    tube: np.ndarray | None = None
    anchor_bound: np.ndarray = field(default_factory=lambda: NO_BOUND)
    walk: np.ndarray | None = None
    paving: np.ndarray | None = None
    skipped_time: float = 0.0
    clean_time: float = 0.0

    @property
    def history(self) -> int:
        """Consecutive known poses (1, or 2 when ``X2`` is the pose before ``X``)."""
        return 1 if self.X2 is None else 2

    @property
    def certain(self) -> bool:
        """The tracker vouches for ``X`` (no step since the last certificate was uncertain)."""
        return self.uncertain_since < 0

    def pack(self, pk: np.ndarray, dt: float | None, stuck_after: int = 0) -> None:
        """Write the state pack (:mod:`solver._kernels.layout` ``STATE_*``) a step from this state reads.

        Parameters
        ----------
        pk : ndarray, shape (STATE_SIZE,)
            The pack, overwritten.
        dt : float or None
            Time since the previous sample (s), or None (uniformly spaced samples).
        stuck_after : int
            The tracker's stuck-joint detector (0: off): samples refused as a stuck joint's keep
            the speed gate on.
        """
        gap = self.skipped + 1                               # samples since the last accepted one
        gap_s = self._gap(dt)                                # and the seconds they span (NaN: unknown)
        pk[STATE_X:STATE_X + 3], pk[STATE_Q:STATE_Q + 3] = self.X, self.q
        pk[STATE_X2:STATE_X2 + 3] = self.X if self.X2 is None else self.X2
        pk[STATE_HISTORY], pk[STATE_DQ_SCALE] = self.history, self.dq_scale
        pk[STATE_EXT_SCALE] = gap_s / self.dt if np.isfinite(gap_s) and np.isfinite(self.dt) else float(gap)
        # the speed gate (measured joints): not after the sensor broke its tolerance (a forced sample)
        # nor after MAX_HELD samples held in a row (the robot moved on: follow the joints again)
        # (samples refused as a stuck joint's are known not to be the robot's: the gate stays on)
        stuck = stuck_after > 0 and self.clean is not None and int(self.repeats.max()) >= stuck_after - 1
        gate_on = dt is not None and self.refused < MAX_REFUSED and (self.skipped < MAX_HELD or stuck)
        pk[STATE_STEP_DT] = gap_s if gate_on else float("nan")
        if self.q2 is None:
            pk[STATE_HAVE_Q2] = 0.0
        else:
            pk[STATE_Q2:STATE_Q2 + 3], pk[STATE_HAVE_Q2] = self.q2, 1.0
        n = len(self.candidates)
        if n == 0:                                           # right after a reset: the initial pose
            pk[STATE_CANDS:STATE_CANDS + 3], pk[STATE_N_CAND] = self.X, 1.0
        else:
            pk[STATE_CANDS:STATE_CANDS + 3 * n], pk[STATE_N_CAND] = self.candidates.ravel(), n
        pk[STATE_VERIFIED] = 1.0 if self.verified else 0.0
        if self.tube is not None and self.certain:
            n = len(self.tube)
            pk[STATE_TUBE:STATE_TUBE + n * TUBE_SIZE], pk[STATE_N_TUBES] = self.tube.ravel(), n
        else:
            pk[STATE_N_TUBES] = 0.0
        pk[STATE_INTACT] = 1.0 if self.intact else 0.0
        pk[STATE_A_SCALE], pk[STATE_REFUSED] = self.a_scale, self.refused
        if self.anchor is None:
            pk[STATE_ANCHOR:STATE_ANCHOR + 3], pk[STATE_ANCHOR_AGE] = self.X, float("nan")
        else:
            pk[STATE_ANCHOR:STATE_ANCHOR + 3], pk[STATE_ANCHOR_AGE] = self.anchor, self._anchor_age(dt)
        pk[STATE_ANCHOR_BOUND:STATE_ANCHOR_BOUND + 3] = self.anchor_bound
        n = 0 if self.paving is None else len(self.paving)
        pk[STATE_N_PAVE] = n
        if n:
            pk[STATE_PAVE:STATE_PAVE + 6 * n] = self.paving.ravel()

    def _gap(self, dt: float | None) -> float:
        """Seconds from the last accepted sample to one ``dt`` after the last one read (NaN: unknown)."""
        return self.skipped_time + dt if dt is not None else float("nan")

    def _anchor_age(self, dt: float | None) -> float:
        """Seconds from the anchor's step to a sample ``dt`` after the last one read (NaN: unknown)."""
        return self.anchor_age + self._gap(dt)

    def skip(self, dt: float | None, **fields) -> "TrackerState":
        """This state after a sample ``dt`` seconds on that it refused or held: one more skipped sample
        (and ``fields`` replaced)."""
        return replace(self, skipped=self.skipped + 1, skipped_time=self._gap(dt), **fields)

    def since(self, certain: bool) -> int:
        """``uncertain_since`` of the next step, reported ``certain`` or not."""
        return -1 if certain else (self.uncertain_since if self.uncertain_since >= 0 else self.steps + 1)

    def after(self, q: np.ndarray, dt: float | None, out_real: np.ndarray, out_int: np.ndarray,
              extra: dict, walk: np.ndarray | None = None) -> "TrackerState":
        """The state after a step from this one to joints ``q`` (3,), read from its result pack.

        A rejected sample moves only the counts of refusals and skipped samples, a held one
        (unreachable) only the count of skipped samples; an accepted one makes a new state.

        Parameters
        ----------
        q : ndarray, shape (3,)
            The joints of the step (rad).
        dt : float or None
            Time since the previous sample (s), as given to :meth:`pack`.
        out_real, out_int : ndarray
            The step's result pack (:mod:`solver._kernels.layout` ``OUT_*``, ``F_*``, ``I_*``).
        extra : dict
            The stuck-joint detector's fields of the next state (:func:`solver.stuck.reading_fields`;
            empty when the detector is off).
        walk : ndarray or None
            The step's unfinished tube chain (see the attribute), kept when the step is accepted.
        """
        i = out_int.tolist()
        status = i[I_STATUS]
        if status == STATUS_REJECTED:                       # an outlier: only the counts of refusals move
            return self.skip(dt, refused=self.refused + 1, **extra)
        if status == STATUS_UNREACHABLE:                    # pose held: only the count of skipped samples
            return self.skip(dt, **extra)
        certain, n_cand = bool(i[I_CERTAIN]), i[I_N_CAND]
        f = out_real[OUT_INFO:OUT_INFO + F_INNOV + 1].tolist()
        dqn, innov = f[F_DQ], f[F_INNOV]
        scale = dqn if self.steps == 0 else 0.8 * self.dq_scale + 0.2 * dqn
        cands = out_real[OUT_CANDS:OUT_CANDS + 3 * n_cand].reshape(n_cand, 3).copy()
        X = out_real[OUT_X:OUT_X + 3].copy()
        # the last certain pose bounds where the robot is (its proven bound plus the speed bound times
        # the time since), whatever the sensor did since: also after refusals (the joints jumped and stayed)
        anchor, age, anchor_bound = self.anchor, self._anchor_age(dt), self.anchor_bound
        region, paving = out_real[OUT_REGION:OUT_REGION + 6], self.paving
        paved = bool(np.all(np.isfinite(region)))          # the set-membership step's paving holds the robot now
        if paved:                                          # (uncertain, or certain by the eliminant: no tubes)
            anchor, anchor_bound, age = 0.5 * (region[0::2] + region[1::2]), 0.5 * (region[1::2] - region[0::2]), 0.0
            n = out_real[OUT_N_PAVE]
            paving = out_real[OUT_PAVE:OUT_PAVE + 6 * int(n)].reshape(-1, 6).copy() if 1 <= n <= PAVE_BOXES else None
        boxed = certain and not paved                      # a certain step's bound starts the next region
        return TrackerState(X, q.copy(), self.X, scale, self.steps + 1,
                            float(self._gap(dt)), self.q, cands,
                            i[I_CERTIFICATE] in (CERT_CONTINUATION, CERT_REACQUIRED), self.since(certain),
                            bool(i[I_INTACT]),
                            innov if self.steps < 2 else max(innov, 0.8 * self.a_scale + 0.2 * innov), 0,
                            X if boxed else anchor, 0.0 if certain else age, **extra,
                            tube=_cover(out_real) if certain else None,
                            anchor_bound=out_real[OUT_BOUND:OUT_BOUND + 3].copy() if boxed else
                            (NO_BOUND if anchor is None else anchor_bound), walk=None if certain else walk,
                            paving=None if boxed else paving)

    def as_array(self) -> np.ndarray:
        """The state as :data:`STATE_FLOATS` floats (the fields are listed above ``_X`` at the end of this
        module): what an FMU serialises."""
        if self.paving is not None and not (self.paving.ndim == 2 and 1 <= len(self.paving) <= PAVE_BOXES
                                            and self.paving.shape[1] == 6):
            raise TrackerError(f"paving: expected (n, 6) pose boxes with 1 <= n <= {PAVE_BOXES}, got shape "
                               f"{self.paving.shape}")
        a = np.full(STATE_FLOATS, np.nan)
        a[_X:_X + 3], a[_Q:_Q + 3] = self.X, self.q
        if self.X2 is not None:
            a[_X2:_X2 + 3] = self.X2
        a[_DQ_SCALE], a[_STEPS], a[_DT] = self.dq_scale, float(self.steps), self.dt
        if self.q2 is not None:
            a[_Q2:_Q2 + 3] = self.q2
        n = len(self.candidates)
        a[_N_CAND], a[_VERIFIED], a[_SINCE] = float(n), float(self.verified), float(self.uncertain_since)
        a[_CANDS:_CANDS + 3 * n] = np.ravel(self.candidates)
        a[_INTACT], a[_A_SCALE], a[_REFUSED] = float(self.intact), self.a_scale, float(self.refused)
        if self.anchor is not None:
            a[_ANCHOR:_ANCHOR + 3] = self.anchor
        a[_AGE], a[_SKIPPED] = self.anchor_age, float(self.skipped)
        if self.reading is not None:
            a[_READING:_READING + 3] = self.reading
        a[_REPEATS:_REPEATS + 3], a[_CLEAN_LAG] = self.repeats, float(self.clean_lag)
        a[_N_TUBES] = 0.0 if self.tube is None else len(self.tube)
        if self.tube is not None:
            a[_TUBE:_TUBE + self.tube.size] = self.tube.ravel()
        a[_ANCHOR_BOUND:_ANCHOR_BOUND + 3] = self.anchor_bound
        a[_N_PAVE] = 0.0 if self.paving is None else len(self.paving)
        if self.paving is not None:
            a[_PAVE:_PAVE + self.paving.size] = self.paving.ravel()
        a[_SKIPPED_TIME], a[_CLEAN_TIME] = self.skipped_time, self.clean_time
        if self.clean is not None:
            a[_BASE:2 * _BASE] = self.clean.as_array()[:_BASE]
        if self.walk is not None:
            a[_WALK:_WALK + len(self.walk)] = self.walk
        return a

    @classmethod
    def from_array(cls, a) -> "TrackerState":
        """Inverse of :meth:`as_array`; :class:`TrackerError` if ``a`` is not such an array."""
        a = np.array(a, dtype=float)            # a writable copy: a read-only array is another kernel signature
        if a.shape != (STATE_FLOATS,):
            raise TrackerError(f"state: expected {STATE_FLOATS} floats (X, q, X2, dq_scale, steps, dt, q2, "
                               f"candidates, ..., the clean state), got {np.array2string(a, threshold=40)}")
        clean = None if np.all(np.isnan(a[_BASE:2 * _BASE])) else cls._from_base(a[_BASE:2 * _BASE])
        base = cls._from_base(a[:_BASE])
        return replace(base, clean=clean, walk=_saved_walk(a[_WALK:], base))

    @classmethod
    def _from_base(cls, a) -> "TrackerState":
        """A state without ``clean`` from the first ``_BASE`` floats of :meth:`as_array`."""
        if a.shape != (_BASE,) or not np.all(np.isfinite(a[_FINITE])) or not 0 <= a[_N_CAND] <= 6:
            raise TrackerError(f"state: expected {STATE_FLOATS} floats (X, q, X2, dq_scale, steps, dt, q2, "
                               f"candidates, ...), got {np.array2string(np.asarray(a), threshold=40)}")
        n = int(a[_N_CAND])
        cands = a[_CANDS:_CANDS + 3 * n].reshape(n, 3).copy()
        if not np.all(np.isfinite(cands)):
            raise TrackerError(f"state: {n} candidates expected, got non-finite values {cands.tolist()}")
        x2, q2 = a[_X2:_X2 + 3], a[_Q2:_Q2 + 3]
        return cls(a[_X:_X + 3].copy(), a[_Q:_Q + 3].copy(), None if np.any(np.isnan(x2)) else x2.copy(),
                   float(a[_DQ_SCALE]), int(a[_STEPS]), float(a[_DT]),
                   None if np.any(np.isnan(q2)) else q2.copy(), cands, bool(a[_VERIFIED]), int(a[_SINCE]),
                   bool(a[_INTACT]), float(a[_A_SCALE]), int(a[_REFUSED]),
                   None if np.any(np.isnan(a[_ANCHOR:_ANCHOR + 3])) else a[_ANCHOR:_ANCHOR + 3].copy(), float(a[_AGE]),
                   int(a[_SKIPPED]), None if np.any(np.isnan(a[_READING:_READING + 3])) else a[_READING:_READING + 3].copy(),
                   a[_REPEATS:_REPEATS + 3].astype(np.int64), None, int(a[_CLEAN_LAG]),
                   _saved_cover(a),
                   a[_ANCHOR_BOUND:_ANCHOR_BOUND + 3].copy(), paving=_saved_paving(a),
                   skipped_time=_saved_seconds(a, _SKIPPED_TIME, "skipped_time"),
                   clean_time=_saved_seconds(a, _CLEAN_TIME, "clean_time"))
