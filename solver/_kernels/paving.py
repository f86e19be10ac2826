"""The set-membership step of an uncertain step, compiled: a paving of the poses the robot can be in.

With a speed bound and a joint tolerance, the poses the robot can have now are those within the
speed bound's reach of the poses it could have at the last step whose inverse kinematics (in the
tracker's posture) lies within the tolerance of this reading.  On an ill-conditioned stretch the
poses consistent with one reading form a thin curved needle.  One box for the set (its hull)
cannot shrink along it: the hull of a curved needle holds the next reading's needle over its whole
length, so the box only grows, by the speed bound's reach at every step, and after a fold it holds
both branches.  The intersection of successive needles is much shorter: a paving of at most
:data:`.layout.PAVE_BOXES` boxes along the needle's long axis follows it.  Its hull is the region
re-acquisition proves uniqueness in (:func:`.gates.reacquire_region`, through the anchor and its
bound that the state keeps).

Every box the branch and bound drops holds no pose that reaches the tolerance box (a leg misses,
:func:`.exclusion.posture_misses`) or none the speed bound lets the robot reach, so the paving holds
the robot whenever the sensor kept its tolerance and the robot its speed bound.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .clock import expired
from .exclusion import bisect, posture_misses
from .gates import reacquire_region
from .kinematics import geometry
from .layout import (PARAM_JOINT_TOL, PARAM_POSTURE_BITS, PARAM_REACQUIRE, PARAM_ROOT, PARAM_SPEED, PAVE_BOXES,
                     STATE_ANCHOR_AGE, STATE_N_PAVE, STATE_PAVE)
from .scratch import floats

#: The branch and bound keeps pose boxes this fraction of the speed bound's reach per step.
REGION_RESOLUTION = 0.25
#: Depth of the branch and bound's stack (a box at the bottom is kept as it is).
PAVE_STACK = 64


@njit(cache=True)
def grown_paving(state, params, roots):
    """The boxes (n, 6) that held the robot at the anchor's time, grown by the speed bound's reach
    since (the state's paving, or the box about its anchor when it has none) and cut to the tool
    space, into ``roots`` (PAVE_BOXES, 6); returns their number n."""
    n = int(state[STATE_N_PAVE])
    if n <= 0:
        reacquire_region(params, state, roots[0])
        return 1 if roots[0, 0] <= roots[0, 1] and roots[0, 2] <= roots[0, 3] else 0
    age = state[STATE_ANCHOR_AGE]
    r, rp = params[PARAM_SPEED] * age * (1.0 + 1e-9), params[PARAM_SPEED + 1] * age * (1.0 + 1e-9)
    m = 0
    for k in range(n):
        box = state[STATE_PAVE + 6 * k:STATE_PAVE + 6 * k + 6]
        roots[m, 0], roots[m, 1] = max(box[0] - r, params[PARAM_ROOT]), min(box[1] + r, params[PARAM_ROOT + 1])
        roots[m, 2], roots[m, 3] = max(box[2] - r, params[PARAM_ROOT + 2]), min(box[3] + r, params[PARAM_ROOT + 3])
        roots[m, 4], roots[m, 5] = box[4] - rp, box[5] + rp
        if roots[m, 0] <= roots[m, 1] and roots[m, 2] <= roots[m, 3]:
            m += 1
    return m


@njit(cache=False)
def touches(box, roots, n):
    """The box (6,) meets one of the first ``n`` boxes of ``roots``."""
    for r in range(n):
        g = roots[r]
        if box[0] <= g[1] and box[1] >= g[0] and box[2] <= g[3] and box[3] >= g[2] and box[4] <= g[5] \
                and box[5] >= g[4]:
            return True
    return False


@njit(cache=True)
def preimage_paving(q, eps, posture_bits, roots, n_roots, res, max_boxes, M, l1, l2sq, b, pave, deadline=0.0):
    """A paving ``pave`` (PAVE_BOXES, 6) of every pose of the union of ``roots[:n_roots]`` with inverse
    kinematics (posture ``posture_bits + 1``) in ``q +- eps`` (3,).

    A branch and bound over the roots' hull drops the boxes that meet no root or reach no joint
    vector of ``q +- eps`` and keeps those narrower than ``res`` (2,: m, rad); a kept box goes to
    one of PAVE_BOXES slices of the hull along its longest axis (counted in ``res``), and each
    slice keeps the hull of its boxes.  Returns the number of boxes of the paving (its first
    rows), 0 when none is kept (a sensor off by more than ``eps``), -1 when ``max_boxes`` or the
    time to the ``deadline`` ran out.
    """
    root = floats(6)
    root[:] = roots[0]
    for r in range(1, n_roots):
        for k in range(0, 6, 2):
            root[k], root[k + 1] = min(root[k], roots[r, k]), max(root[k + 1], roots[r, k + 1])
    nx, ny, nphi = (root[1] - root[0]) / res[0], (root[3] - root[2]) / res[0], (root[5] - root[4]) / res[1]
    axis = 0 if nx >= ny and nx >= nphi else (2 if ny >= nphi else 4)
    lo, width = root[axis], max(root[axis + 1] - root[axis], 1e-300)
    for s in range(PAVE_BOXES):
        for k in range(0, 6, 2):
            pave[s, k], pave[s, k + 1] = np.inf, -np.inf
    stack = np.empty((PAVE_STACK, 6))
    stack[0, :] = root
    top, seen = 1, 0
    box = floats(6)
    while top > 0:
        top -= 1
        box[:] = stack[top]
        seen += 1
        if seen > max_boxes or expired(deadline):
            return -1
        if not touches(box, roots, n_roots) or posture_misses(box, q, eps, posture_bits, M, l1, l2sq, b):
            continue
        wx, wy, wp = box[1] - box[0], box[3] - box[2], box[5] - box[4]
        if (wx <= res[0] and wy <= res[0] and wp <= res[1]) or top + 2 > PAVE_STACK:
            s = min(max(int((0.5 * (box[axis] + box[axis + 1]) - lo) / width * PAVE_BOXES), 0), PAVE_BOXES - 1)
            for k in range(0, 6, 2):
                pave[s, k], pave[s, k + 1] = min(pave[s, k], box[k]), max(pave[s, k + 1], box[k + 1])
            continue
        nx, ny, nphi = wx / res[0], wy / res[0], wp / res[1]
        top = bisect(stack, top, box, 0 if nx >= ny and nx >= nphi else (2 if ny >= nphi else 4))
    n = 0
    for s in range(PAVE_BOXES):
        if pave[s, 0] <= pave[s, 1]:
            pave[n, :] = pave[s, :]
            n += 1
    return n


@njit(cache=True)
def region_step(state, qu, params, model_pack, out, out_pave, deadline=0.0):
    """An uncertain step with a speed bound: the paving of the poses that can hold the robot now
    (:func:`preimage_paving` of the last paving grown by the speed bound, :func:`grown_paving`, at the
    reading ``qu`` (3,)), into ``out_pave`` (1 + 6 PAVE_BOXES,: the number of boxes, then the boxes),
    and its hull into ``out`` (6,).  Both are left as they are (``out`` NaN, no boxes) without a speed
    bound, or when the branch and bound ran out or kept nothing (a reading off by more than its
    tolerance): the set then keeps growing from the last paving."""
    age = state[STATE_ANCHOR_AGE]
    if not (params[PARAM_SPEED] > 0.0 and age > 0.0 and int(params[PARAM_POSTURE_BITS]) >= 0):
        return
    roots = np.empty((PAVE_BOXES, 6))
    n_roots = grown_paving(state, params, roots)
    if n_roots == 0:
        return
    res = floats(2)
    res[0] = max(REGION_RESOLUTION * params[PARAM_SPEED] * age, 1e-7)
    res[1] = max(REGION_RESOLUTION * params[PARAM_SPEED + 1] * age, 1e-7)
    M, l1, l2sq, b = geometry(model_pack)
    pave = np.empty((PAVE_BOXES, 6))
    n = preimage_paving(qu, params[PARAM_JOINT_TOL], int(params[PARAM_POSTURE_BITS]), roots, n_roots, res,
                        int(params[PARAM_REACQUIRE]), M, l1, l2sq, b, pave, deadline)
    if n <= 0:
        return
    for k in range(0, 6, 2):
        out[k], out[k + 1] = np.inf, -np.inf
    for s in range(n):
        for k in range(0, 6, 2):
            out[k], out[k + 1] = min(out[k], pave[s, k]), max(out[k + 1], pave[s, k + 1])
    out_pave[0] = n
    out_pave[1:1 + 6 * n] = pave[:n].ravel()
