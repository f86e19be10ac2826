"""The numbering rules of the six DK solutions (paper eq. 15), compiled.

The rules are described in :data:`solver.ordering.ORDERING_RULES`; their codes are the
``RULE_*`` of :mod:`.layout`.  :func:`number_solutions` numbers the solutions of one
joint vector (called by the DK kernel and, in batches, by :func:`solver.order_solutions`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import det_sign, elbows
from .layout import RULE_ASPECT, RULE_LITERAL, RULE_REAL_X, RULE_REAL_Y
from .scratch import scratch, scratch2


@njit(cache=True)
def sort_key(out, k, comp):
    """(Re, Im) of component ``comp`` of solution ``k``, non-finite parts as +inf."""
    re, im = out[k, comp].real, out[k, comp].imag
    if not math.isfinite(re):
        re = np.inf
    if not math.isfinite(im):
        im = np.inf
    return re, im


@njit(cache=True)
def before(out, isreal, a, b, rule):
    """Whether solution ``a`` sorts strictly before ``b`` under ``rule``.

    literal: all six by (Re phi, Im phi); real-phi / real-x / real-y: real
    solutions first, by phi / x / y, then the complex ones by (Re phi, Im phi).
    """
    if rule != RULE_LITERAL and isreal[a] != isreal[b]:
        return isreal[a]
    comp = 2
    if isreal[a] and isreal[b]:
        if rule == RULE_REAL_X:
            comp = 0
        elif rule == RULE_REAL_Y:
            comp = 1
    ra, ia = sort_key(out, a, comp)
    rb, ib = sort_key(out, b, comp)
    if ra != rb:
        return ra < rb
    return ia < ib


@njit(cache=False)
def aspect_order(out, isreal, order, D, b, res):
    """Rule 'aspect': slots 1-3 real solutions with det J >= 0, slots 4-6 those with det J < 0,
    each by phi; complex solutions (by Re phi, Im phi) fill the free slots, first class first.

    ``order`` arrives sorted by the real-phi key (real by phi, then complex).  Real solutions
    are born and die in pairs of opposite det J sign, so each class holds at most three;
    should a class overflow (only at an exactly singular input) the slots fill in sequence.
    The order is written into ``res`` (6,) int64.
    """
    pos = scratch(6, np.int64)
    neg = scratch(6, np.int64)
    cpx = scratch(6, np.int64)
    npos, nneg, ncpx = 0, 0, 0
    for i in range(6):
        k = order[i]
        if isreal[k]:
            if det_sign(out[k, 0].real, out[k, 1].real, out[k, 2].real, D, b) >= 0:
                pos[npos] = k
                npos += 1
            else:
                neg[nneg] = k
                nneg += 1
        else:
            cpx[ncpx] = k
            ncpx += 1
    if npos > 3 or nneg > 3:
        n = 0
        for i in range(npos):
            res[n] = pos[i]
            n += 1
        for i in range(nneg):
            res[n] = neg[i]
            n += 1
        for i in range(ncpx):
            res[n] = cpx[i]
            n += 1
        return
    c = 0
    for i in range(3):
        if i < npos:
            res[i] = pos[i]
        else:
            res[i] = cpx[c]
            c += 1
    for i in range(3):
        if i < nneg:
            res[3 + i] = neg[i]
        else:
            res[3 + i] = cpx[c]
            c += 1


@njit(cache=True)
def number_solutions(out, isreal, rule, D, b, poses, real):
    """Number the solutions ``out`` (6, 3), ``isreal`` (6,) of the joints with elbows ``D`` by
    ``rule``: solution ``k + 1`` goes to ``poses[k]``, ``real[k]``."""
    order = scratch(6, np.int64)
    for i in range(6):
        order[i] = i
    for i in range(1, 6):                      # insertion sort by the rule's key (stable)
        j = i
        while j > 0 and before(out, isreal, order[j], order[j - 1], rule):
            order[j], order[j - 1] = order[j - 1], order[j]
            j -= 1
    if rule == RULE_ASPECT:
        by_aspect = scratch(6, np.int64)
        aspect_order(out, isreal, order, D, b, by_aspect)
        order[:] = by_aspect
    for i in range(6):
        for c in range(3):
            poses[i, c] = out[order[i], c]
        real[i] = isreal[order[i]]


@njit(cache=True)
def number_batch(poses, real, rule, q, M, l1, b, out_poses, out_real):
    """:func:`number_solutions` of solution sets ``poses`` (N, 6, 3), ``real`` (N, 6) of joints ``q`` (N, 3)."""
    D = scratch2(3, 2, np.float64)
    for n in range(poses.shape[0]):
        elbows(q[n], M, l1, D)
        number_solutions(poses[n], real[n], rule, D, b, out_poses[n], out_real[n])
