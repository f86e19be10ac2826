"""The tracker's gates for measured joints, compiled: what the platform can have reached.

A speed bound (m/s, rad/s) says how far the platform moves between two samples.  The speed
gate (:func:`speed_gate`) holds back a solution farther than that from the previous output
(plus the reach of two pose boxes, 2 ``RHO_CAP``): the measured joints crossed a fold that
the robot did not.  The tracker does not apply it to a solution that a chain of Krawczyk
boxes joins to a previous candidate along the measured joints (the straight segment between
the samples crossed no fold; the robot's joints, within the tolerance of it, may have: a
choice, not a proof, and the chain does not vouch) nor to a re-acquired one; before it
acts on a trusted sample with one previous candidate, the tracker tries that chain once more
with a larger budget of tests (default mode).  The re-acquisition
region (:func:`reacquire_region`) is anchored at a certain pose, whose proven pose bound
holds the platform.

The outlier gate (:func:`outlier_gate`) refuses a sample whose joint step is off the
expected one (constant joint velocity) by more than the tolerance and the recent
innovations allow, weighed by what the unexpected motion does to the pose: near a serial
(type-1) singularity a joint swings fast while the platform barely moves, and such a swing
is not an outlier.  A sample the gate lets through with a step off by more than the noise
allows is not vouched for: it may still be a glitch (the tracker ends the chain there).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .certify import RHO_CAP
from .layout import PARAM_ROOT, PARAM_SPEED, STATE_ANCHOR, STATE_ANCHOR_AGE, STATE_ANCHOR_BOUND
from .kinematics import jacobian
from .linalg import det3, wrap
from .scratch import floats, scratch2

#: Verdicts of :func:`outlier_gate`.
GATE_PASS, GATE_SUSPECT, GATE_REFUSE = 0, 1, 2


@njit(cache=True)
def reach(params, seconds):
    """How far the platform can have moved in ``seconds`` under the speed bound, plus the pose
    boxes' reach (2 RHO_CAP): (m, rad)."""
    return 2.0 * RHO_CAP + params[PARAM_SPEED] * seconds, 2.0 * RHO_CAP + params[PARAM_SPEED + 1] * seconds


@njit(cache=True)
def reacquire_region(params, state, region):
    """The pose box (6,) the robot is in: the tool space, cut to what the platform can have reached
    since its last certain pose when a speed bound is given (that pose's proven bound plus the
    speed bound times the time since)."""
    region[0:4] = params[PARAM_ROOT:PARAM_ROOT + 4]
    region[4], region[5] = -math.pi, math.pi
    age = state[STATE_ANCHOR_AGE]
    bound = state[STATE_ANCHOR_BOUND:STATE_ANCHOR_BOUND + 3]
    if params[PARAM_SPEED] > 0.0 and math.isfinite(age) and math.isfinite(bound[0] + bound[1] + bound[2]):
        a = state[STATE_ANCHOR:STATE_ANCHOR + 3]
        r, rp = params[PARAM_SPEED] * age, params[PARAM_SPEED + 1] * age
        rx, ry, rp = (r + bound[0]) * (1.0 + 1e-9), (r + bound[1]) * (1.0 + 1e-9), (rp + bound[2]) * (1.0 + 1e-9)
        region[0], region[1] = max(region[0], a[0] - rx), min(region[1], a[0] + rx)
        region[2], region[3] = max(region[2], a[1] - ry), min(region[3], a[1] + ry)
        if rp < math.pi:
            region[4], region[5] = a[2] - rp, a[2] + rp


@njit(cache=True)
def speed_gate(poses, real, chosen, Xp, params, seconds):
    """The speed gate: is the chosen solution one the platform can have reached?

    ``poses`` (6, 3) complex / ``real`` (6,): the DK solutions at the measured joints;
    ``Xp`` (3,) the previous output (m, m, rad), ``seconds`` (s) since it.  A solution is within
    reach when each coordinate differs from ``Xp`` by at most :func:`reach`.  Returns ``chosen``
    when it is within reach, else the one real solution within reach if exactly one is, else
    -1 (nothing to take: hold).
    """
    r, rp = reach(params, seconds)
    X = floats(3)
    other, n_in = -1, 0
    for k in range(6):
        if not real[k]:
            continue
        for i in range(3):
            X[i] = poses[k, i].real
        inside = abs(X[0] - Xp[0]) <= r and abs(X[1] - Xp[1]) <= r and abs(wrap(X[2] - Xp[2])) <= rp
        if inside and k == chosen:
            return chosen
        if inside:
            other, n_in = k, n_in + 1
    return other if n_in == 1 else -1


@njit(cache=True)
def pose_gains(X, q, M, l1, l2sq, b, S):
    """``S = |J^-1 K|`` (3, 3), elementwise, at ``(X, q)``: how far each joint moves each pose
    coordinate (m/rad, m/rad, rad/rad); False (``S`` unwritten) at a singularity of ``J``."""
    J = scratch2(3, 3, np.float64)
    kd = floats(3)
    jacobian(X, q, M, l1, l2sq, b, J, kd)
    det = det3(J)
    if det == 0.0 or not math.isfinite(det):
        return False
    for j in range(3):                        # column j of J^-1 by cofactors, times kd_j
        a, c = (j + 1) % 3, (j + 2) % 3
        for r in range(3):
            r1, r2 = (r + 1) % 3, (r + 2) % 3
            S[r, j] = abs((J[a, r1] * J[c, r2] - J[a, r2] * J[c, r1]) / det * kd[j])
    return math.isfinite(S[0, 0] + S[0, 1] + S[0, 2] + S[1, 0] + S[1, 1] + S[1, 2] + S[2, 0] + S[2, 1] + S[2, 2])


@njit(cache=True)
def outlier_gate(innov, threshold, noise, Xp, qp, M, l1, l2sq, b):
    """The outlier gate's verdict on a sample: GATE_PASS, GATE_SUSPECT or GATE_REFUSE.

    ``innov`` (3,): each joint's step minus the expected one (rad); ``threshold`` (rad): what
    the tolerance and the recent innovations allow; ``noise`` (rad): what the tolerance alone
    allows.  A sample passes when no innovation exceeds the threshold.  Otherwise it is
    refused when, for some pose coordinate, the innovations move it more than a step of
    ``noise`` on the joint that moves it most (first order at the previous pose ``Xp``, ``qp``;
    without a regular Jacobian there, always), and suspect when they do not: the platform
    did not move more than the noise could move it (a joint at a serial singularity swings
    while its leg barely moves the platform).  A suspect sample is taken, vouched for by nothing.
    """
    worst = max(abs(innov[0]), max(abs(innov[1]), abs(innov[2])))
    if not worst > threshold:
        return GATE_PASS
    S = scratch2(3, 3, np.float64)
    if not pose_gains(Xp, qp, M, l1, l2sq, b, S):
        return GATE_REFUSE
    for r in range(3):
        moved = S[r, 0] * abs(innov[0]) + S[r, 1] * abs(innov[1]) + S[r, 2] * abs(innov[2])
        if moved > noise * max(S[r, 0], max(S[r, 1], S[r, 2])):
            return GATE_REFUSE
    return GATE_SUSPECT


@njit(cache=True)
def swing(poses, real, Xp, qp, noise, params, seconds, M, l1, l2sq, b):
    """Is a sample the outlier gate refused a joint's swing after all?  A joint next to a serial
    singularity swings by up to radians in a sample while the platform moves as usual, beyond what
    the gate's first-order test sees.  It is one when a real DK solution (``poses`` (6, 3) complex,
    ``real`` (6,)) lies where the platform can be: within the speed bound's reach in ``seconds``
    of the previous pose ``Xp`` (3,) (at joints ``qp``), plus what ``noise`` (rad) on the joints
    of both samples moves each pose coordinate (first order at ``Xp``, at most the speed gate's
    margin 2 RHO_CAP).  A glitch of the sensor moves the DK solutions by its size times those
    gains, in general beyond.  Never without a speed bound.  A swing is taken, vouched for by
    nothing (it may still be a glitch), and leaves the gate's envelopes as they were."""
    if not (params[PARAM_SPEED] > 0.0 and math.isfinite(seconds)):
        return False
    S = scratch2(3, 3, np.float64)
    if not pose_gains(Xp, qp, M, l1, l2sq, b, S):
        return False
    r = floats(3)
    for i in range(3):
        r[i] = params[PARAM_SPEED + (1 if i == 2 else 0)] * seconds + min(noise * (S[i, 0] + S[i, 1] + S[i, 2]),
                                                                          2.0 * RHO_CAP)
    for k in range(6):
        if real[k] and abs(poses[k, 0].real - Xp[0]) <= r[0] and abs(poses[k, 1].real - Xp[1]) <= r[1] \
                and abs(wrap(poses[k, 2].real - Xp[2])) <= r[2]:
            return True
    return False
