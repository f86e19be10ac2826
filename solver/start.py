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

__all__ = ["START_TOLERANCE", "StartInfo", "honest_start", "encoder_bits", "encoder_note"]

#: How far the initial pose given to :meth:`solver.Tracker.reset` may be from the robot's (m, m, rad).
START_TOLERANCE = (0.01, 0.01, 0.05)


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


#: Encoders of MIN_ENCODER_BITS to MAX_ENCODER_BITS bits per turn are recognised from their readings
#: (:func:`encoder_bits`).
MIN_ENCODER_BITS, MAX_ENCODER_BITS = 8, 24


def encoder_bits(q) -> int | None:
    """The bits per turn of the encoder grid the joints ``q`` (3,) (rad) lie on, or None.

    Readings of a ``B``-bit encoder are integer multiples of ``2 pi / 2**B``; joints that are all
    such multiples for some ``B <= MAX_ENCODER_BITS`` (the smallest is returned, at least
    ``MIN_ENCODER_BITS``: joints on a coarser grid, such as 0 or pi / 2, are set by hand) are taken
    as encoder readings.  Joints computed in floating point (inverse kinematics, a simulation) land
    on such a grid with a probability of about ``1e-8``.
    """
    q = np.asarray(q, dtype=float)
    for bits in range(1, MAX_ENCODER_BITS + 1):
        k = q * (2.0 ** bits / (2.0 * np.pi))
        if np.all(np.abs(k - np.round(k)) <= 1e-9 * np.maximum(1.0, np.abs(k))):
            # joints on a grid coarser than MIN_ENCODER_BITS (0, pi / 2, ...) are set by hand, not read
            return bits if bits >= MIN_ENCODER_BITS else None
    return None


def encoder_note(what: str, bits: int, tol: float, speed_bound) -> str:
    """What a tracker with ``joint_tolerance = 0`` says when ``what`` (joints) lies on a ``bits``-bit
    encoder grid and it takes ``tol`` (rad, half a step) as its tolerance: why, and what to set."""
    note = (f"{what} lies on a {bits}-bit encoder grid (2 pi / 2**{bits} rad): readings, not exact joints; "
            f"joint_tolerance = 0 would vouch for the branch along the readings, so the tracker takes half "
            f"a step, joint_tolerance = {tol:.3g} rad (pass joint_tolerance, e.g. Sensor.tolerance(), to choose)")
    if speed_bound is None:
        note += ("; with readings and no speed_bound, certainty lost near a singularity seldom comes back "
                 "(re-acquisition would have to rule out every other pose of the tool space): pass "
                 "speed_bound=(m/s, rad/s), a bound on the platform's speed")
    return note


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
