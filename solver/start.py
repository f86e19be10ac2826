"""The honest start of a tracker: which DK solution of the initial joints the robot is in, and the proof.

:meth:`solver.Tracker.reset` takes an approximate initial pose ``X0`` (the robot within
``start_tolerance`` of it) and the initial joints ``q0`` (within ``joint_tolerance``).  It starts
from the DK solution of ``q0`` in that start region, certain when the compiled proof
(:func:`solver._kernels.start.certify_start`) shows it is the only pose the robot can be in;
otherwise uncertain, with the reason in :class:`StartInfo`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._kernels.start import START_NO_TUBE, START_PROVED, certify_start
from ._kernels.tube import TUBE_SIZE
from ._kernels.tube_chain import MAX_COVER, pose_bound
from .direct_kinematics import dk_all
from .kinematics import wrap_angle

__all__ = ["START_TOLERANCE", "StartInfo", "UncertainStartWarning", "honest_start", "start_tolerance_for"]

#: How far the initial pose given to :meth:`solver.Tracker.reset` may be from the robot's (m, m, rad), for
#: the paper's robot (a 1.2 m leg reach); :func:`start_tolerance_for` scales it to another 3-RRR.
START_TOLERANCE = (0.01, 0.01, 0.05)
#: The leg reach (m) :data:`START_TOLERANCE` is for: the paper's robot, l1 + l2 = 1.2 m
_PAPER_REACH = 1.2


def start_tolerance_for(model) -> tuple:
    """The default start tolerance (m, m, rad) of ``model``: :data:`START_TOLERANCE` with its lengths
    scaled by the 3-RRR's longest leg reach over the paper robot's 1.2 m (the paper's robot: exactly
    :data:`START_TOLERANCE`; a robot ten times smaller: a tenth); other kinds: :data:`START_TOLERANCE`."""
    if getattr(model, "kind", None) != "3-RRR":
        return START_TOLERANCE
    scale = float(np.max(model.l1 + model.l2)) / _PAPER_REACH
    return (START_TOLERANCE[0] * scale, START_TOLERANCE[1] * scale, START_TOLERANCE[2])


class UncertainStartWarning(UserWarning):
    """A tracker's start is not proved (:attr:`StartInfo.certain` False): it cannot vouch for its poses
    until it re-acquires; the message says why and what to change."""


class StartInfo(NamedTuple):
    """How a tracker started (:meth:`solver.Tracker.reset`).

    Attributes
    ----------
    certain : bool
        The start pose is proved the robot's (see :mod:`solver.start`).
    X : ndarray, shape (3,)
        The start pose (m, m, rad): the DK solution of ``q0`` in the start region, else the
        nearest one to ``X0``, else ``X0``.
    pose_bound : ndarray, shape (3,)
        When certain, half-widths (m, m, rad) of a box about ``X`` holding the robot's pose; inf otherwise.
    reason : str
        Why the start is not certain ("" when it is), with what to change.
    tube : ndarray, shape (n, 36) or None
        The first cover of tubes of the tracker's chain (:mod:`solver._kernels.tube`; None when not
        certain).
    note : str
        What the start changed, e.g. the joint tolerance it took for encoder readings ("" when nothing).
    """

    certain: bool
    X: np.ndarray
    pose_bound: np.ndarray
    reason: str
    tube: np.ndarray | None = None
    note: str = ""


def honest_start(model_pack, model, X0, q0, start_tolerance, joint_tolerance: float, weights,
                 max_boxes: int) -> StartInfo:
    """The start of a tracker of ``model`` from ``X0`` (3,) (within ``start_tolerance`` (3,)) at the
    joints ``q0`` (3,) (within ``joint_tolerance``); ``weights`` (3,) rank the DK solutions by
    distance to ``X0`` when none is in the start region."""
    r0 = np.asarray(start_tolerance, dtype=float)
    sols = dk_all(model, q0).real_poses()
    if len(sols) == 0:
        return StartInfo(False, X0.copy(), np.full(3, np.inf), "the initial joints q0 have no real DK solution "
                         "(unreachable): started from X0, uncertain")
    d = np.abs(sols - X0)
    d[:, 2] = np.abs(wrap_angle(sols[:, 2] - X0[2]))
    inside = np.all(d <= r0, axis=1)
    nearest = sols[int(np.argmin(d ** 2 @ weights))]
    if not inside.any():
        off = d[int(np.argmin(d ** 2 @ weights))]
        return StartInfo(False, nearest.copy(), np.full(3, np.inf),
                         f"no DK solution of q0 within start_tolerance {r0.tolist()} of X0 (the nearest is off by "
                         f"{off.tolist()} m, m, rad): give X0 closer to the robot's pose or a larger start_tolerance")
    if inside.sum() > 1:
        return StartInfo(False, nearest.copy(), np.full(3, np.inf),
                         f"{int(inside.sum())} DK solutions of q0 lie within start_tolerance {r0.tolist()} of X0: give "
                         "a smaller start_tolerance")
    Xs = sols[int(np.argmax(inside))].copy()
    tubes = np.empty((MAX_COVER, TUBE_SIZE))
    code, n = certify_start(np.asarray(X0, dtype=float), r0, Xs, np.asarray(q0, dtype=float),
                            float(joint_tolerance), int(max_boxes), model_pack, tubes)
    if code != START_PROVED:
        why = ("a singularity lies within joint_tolerance of q0" if code == START_NO_TUBE else
               "another pose within start_tolerance of X0 may reach joints within joint_tolerance of q0")
        return StartInfo(False, Xs, np.full(3, np.inf), f"the start is not proved: {why}; give a smaller "
                         "start_tolerance or start away from singularities")
    bound = np.empty(3)
    pose_bound(tubes, n, np.asarray(q0, dtype=float), float(joint_tolerance), Xs, bound)
    return StartInfo(True, Xs, bound, "", tubes[:n].copy())
