"""What a tracker step reports: :class:`StepInfo`, and :class:`TrackResult` for a whole stream.

Both are read from a step's result pack (:mod:`solver._kernels.layout` ``OUT_*``, ``F_*``, ``I_*``);
the tracker's data is :mod:`solver.tracker_state`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._kernels import layout as _lay
from ._kernels.layout import (F_COND, F_D_BEST, F_D_SECOND, I_AMBIGUOUS, I_CERTAIN, I_CERTIFICATE, I_JUMP, I_LABEL,
                              I_N_CAND, I_N_REAL, I_NEAR_BORDER, I_STATUS, I_TRUST, INFO_F_SIZE, INFO_I_SIZE,
                              OUT_BOUND, OUT_INFO, OUT_X, TB_AMBIGUOUS, TB_CERTAIN, TB_JUMP, TB_NEAR_BORDER,
                              TB_OUT_OF_BUDGET, TF_BOUND, TF_COND, TF_D_BEST, TF_D_SECOND, TF_SECONDS, TF_X, TF_X_PRED,
                              TI_CERTIFICATE, TI_LABEL, TI_N_CAND, TI_N_REAL, TI_SINCE, TI_STATUS, TI_TRUST,
                              TRACK_BOOLS, TRACK_FLOATS, TRACK_INTS, TRUST, TRUST_LOST)

__all__ = ["StepInfo", "TrackResult", "result_views", "track_blocks", "STATUS", "CERTIFICATES", "TRUST", "NO_BOUND",
           "STEP_FIELDS"]

#: Status codes of a step by code (also the FMU's ``status`` output; 3, rejected, is the FMU's own).
STATUS = _lay.STATUS

#: Certificates by code (``StepInfo.certificate``), see :mod:`solver.tracker`.
CERTIFICATES = {0: "none", 1: "continuation", 2: "elimination", 3: "posture", 4: "reacquired", 5: "tube"}

#: The pose bound of a step that is not certain: no bound (inf, inf, inf), read-only.
NO_BOUND = np.full(3, np.inf)
NO_BOUND.flags.writeable = False


#: The pose, X_pred and bound in the copy of :meth:`StepInfo.from_views` (``head``: ``OUT_X`` to the bound)
_BOUND = slice(OUT_BOUND - OUT_X, OUT_BOUND - OUT_X + 3)
_new = tuple.__new__


def result_views(out_real: np.ndarray, out_int: np.ndarray) -> tuple:
    """The views of a result pack a step's :class:`StepInfo` is read from: ``out_real`` from the pose to the
    pose bound (33,), its info floats (INFO_F_SIZE,), and ``out_int``'s first INFO_I_SIZE int64."""
    return out_real[OUT_X:OUT_BOUND + 3], out_real[OUT_INFO:OUT_INFO + INFO_F_SIZE], out_int[:INFO_I_SIZE]


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
        The heuristic doubt of the choice (see :mod:`solver.tracker`); ``certain`` is the proof.
    status : int
        See :data:`STATUS`: 0 ok, 1 unreachable (pose held), 2 singular, 3 rejected
        (an outlier the gate refused, pose held, state kept), 4 diverged.
    jump : bool
        The joint step was far larger than recent ones.
    d_best, d_second : float
        Weighted distance (m) from the prediction to the chosen and to the
        nearest other real solution.
    certain : bool
        The tracker vouches that the pose lies on the branch continued from the
        initial pose (a chain of certificates back to it; see :mod:`solver.tracker`).
    certificate : int
        The certificate of this step (:data:`CERTIFICATES`): 0 none, 1
        continuation, 2 elimination, 3 posture, 4 reacquired (measured joints).
    n_candidates : int
        DK solutions the true branch can be after this step (1 when known).
    uncertain_since : int
        Step index since which the tracker cannot vouch; -1 when ``certain``.
    pose_bound : ndarray, shape (3,)
        When ``certain``: half-widths (m, m, rad) of a box about the returned pose that holds
        every pose consistent, on the tracked branch, with joints within ``joint_tolerance``
        of the sample (a proof, like ``certain``; about 1e-12 with exact joints).  inf when
        not certain (:data:`NO_BOUND`).
    trust : int
        What a controller can act on (:data:`TRUST`): 2 certain (the branch proved, the pose
        within ``pose_bound``); 1 possible (the branch along the measured joints is known but
        not proved over the joint tolerance: a fold may lie within it); 0 lost.
    out_of_budget : bool
        With a step budget (``Tracker(step_budget=...)``): the step is not certain because its
        budget ran out before its proof was complete (the tube chain goes on at the next steps).
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
    certain: bool = False
    certificate: int = 0
    n_candidates: int = 0
    uncertain_since: int = -1
    pose_bound: np.ndarray = NO_BOUND
    trust: int = TRUST_LOST
    out_of_budget: bool = False

    @classmethod
    def from_result(cls, out_real: np.ndarray, out_int: np.ndarray, uncertain_since: int) -> "StepInfo":
        """The step's information from its result pack (:mod:`solver._kernels.layout` ``OUT_*``, ``F_*``, ``I_*``)."""
        return cls.from_views(result_views(out_real, out_int), uncertain_since)[1]

    @classmethod
    def pose_and_info(cls, out_real: np.ndarray, out_int: np.ndarray, uncertain_since: int):
        """``(X, info)`` of a step from its result pack: the pose (3,) and :meth:`from_result`."""
        return cls.from_views(result_views(out_real, out_int), uncertain_since)

    @classmethod
    def from_views(cls, views: tuple, uncertain_since: int):
        """:meth:`pose_and_info` from the :func:`result_views` of the result pack (the step's hot path: a
        tracker makes the views once, a step pays one copy, two or three slices and two ``tolist``); the
        pose, ``X_pred`` and the bound are views of the one copy."""
        head, floats, ints = views
        # the packs' fields unpacked in their layout's order (asserted below): no lookups, no indexing
        label, near, n_real, ambiguous, status, jump, _, certain, certificate, n_cand, _, trust = ints.tolist()
        d_best, d_second, _, cond, _, _ = floats.tolist()
        xx = head.copy()                                    # one copy for the pose, X_pred and the bound
        certain = certain != 0
        return xx[:3], _new(cls, (label, near != 0, xx[3:6], n_real, cond, ambiguous != 0, status, jump != 0, d_best,
                                  d_second, certain, certificate, n_cand, uncertain_since,
                                  xx[_BOUND] if certain else NO_BOUND, trust, False))

    @property
    def status_name(self) -> str:
        return STATUS[self.status]

    @property
    def trust_name(self) -> str:
        """``trust`` by name: "certain", "possible" or "lost"."""
        return TRUST[self.trust]


class TrackResult(NamedTuple):
    """Result of :meth:`Tracker.track`: poses and per-step information as arrays.

    Attributes
    ----------
    X : ndarray (n, 3)
    label, n_real, status, certificate, n_candidates, uncertain_since, trust : ndarray of int (n,)
    near_border, ambiguous, jump, certain, out_of_budget : ndarray of bool (n,)
    X_pred : ndarray (n, 3)
    cond, d_best, d_second : ndarray (n,)
    pose_bound : ndarray (n, 3)
        Half-widths of the proven pose box (m, m, rad) at certain steps, inf elsewhere; row 0 the start's.
    seconds : ndarray (n,)
        Wall time of each step (s); 0 for the initial pose (which is certain).

    The arrays are C-contiguous views of three blocks, one per dtype (:func:`track_blocks`), that the
    compiled loop writes step by step: an array kept alone keeps its block alive (``.copy()`` it to
    keep only its own memory).
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
    certain: np.ndarray
    certificate: np.ndarray
    n_candidates: np.ndarray
    uncertain_since: np.ndarray
    trust: np.ndarray
    pose_bound: np.ndarray
    seconds: np.ndarray
    out_of_budget: np.ndarray


#: Per-step fields of TrackResult (name, dtype) besides X, X_pred and seconds.
STEP_FIELDS = (("label", int), ("near_border", bool), ("n_real", int), ("cond", float), ("ambiguous", bool),
               ("status", int), ("jump", bool), ("d_best", float), ("d_second", float), ("certain", bool),
               ("certificate", int), ("n_candidates", int), ("uncertain_since", int), ("trust", int),
               ("out_of_budget", bool))


def track_blocks(n: int) -> tuple:
    """The arrays of a :class:`TrackResult` of ``n`` steps, as views of the three blocks a compiled stream
    loop writes step by step (:mod:`solver._kernels.layout` ``TF_*``, ``TI_*``, ``TB_*``; three
    allocations instead of nineteen, and no copy from the loop's rows into the fields).

    Returns
    -------
    blocks : tuple
        ``floats`` (TRACK_FLOATS * n,) float64, ``ints`` (TRACK_INTS, n) int64, ``bools`` (TRACK_BOOLS, n) bool.
    fields : dict
        Every TrackResult field by name, each a C-contiguous view of a block: zeros, ``pose_bound`` inf.
    """
    floats = np.zeros(TRACK_FLOATS * n)
    ints = np.zeros((TRACK_INTS, n), dtype=np.int64)
    bools = np.zeros((TRACK_BOOLS, n), dtype=np.bool_)
    fields = dict(zip(_TRIPLE_NAMES, floats[:TF_COND * n].reshape(3, n, 3)))
    fields.update(zip(_FLOAT_NAMES, floats[TF_COND * n:].reshape(TRACK_FLOATS - TF_COND, n)))
    fields.update(zip(_INT_NAMES, ints))
    fields.update(zip(_BOOL_NAMES, bools))
    fields["pose_bound"].fill(np.inf)
    return (floats, ints, bools), fields


#: TrackResult's arrays in the order of their blocks (:func:`track_blocks`): the (n, 3) floats from TF_X * n,
#: TF_X_PRED * n, TF_BOUND * n; the (n,) floats from TF_COND * n on; the rows of the int and the bool block
_TRIPLE_NAMES = ("X", "X_pred", "pose_bound")
_FLOAT_NAMES = ("cond", "d_best", "d_second", "seconds")
_INT_NAMES = ("label", "n_real", "status", "certificate", "n_candidates", "uncertain_since", "trust")
_BOOL_NAMES = ("near_border", "ambiguous", "jump", "certain", "out_of_budget")
# StepInfo.from_views unpacks the info packs whole, in this order
assert (I_LABEL, I_NEAR_BORDER, I_N_REAL, I_AMBIGUOUS, I_STATUS, I_JUMP, I_CERTAIN, I_CERTIFICATE, I_N_CAND,
        I_TRUST, INFO_I_SIZE) == (0, 1, 2, 3, 4, 5, 7, 8, 9, 11, 12)
assert (F_D_BEST, F_D_SECOND, F_COND, INFO_F_SIZE) == (0, 1, 3, 6)
assert (TF_X, TF_X_PRED, TF_BOUND, TF_COND, TF_D_BEST, TF_D_SECOND, TF_SECONDS) == (0, 3, 6, 9, 10, 11, 12)
assert (TI_LABEL, TI_N_REAL, TI_STATUS, TI_CERTIFICATE, TI_N_CAND, TI_SINCE, TI_TRUST) == tuple(range(7))
assert (TB_NEAR_BORDER, TB_AMBIGUOUS, TB_JUMP, TB_CERTAIN, TB_OUT_OF_BUDGET) == tuple(range(5))
assert (TRACK_FLOATS, TRACK_INTS, TRACK_BOOLS) == (13, len(_INT_NAMES), len(_BOOL_NAMES))
