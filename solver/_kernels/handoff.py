"""Hand-offs between tubes (:mod:`.tube`): where two tubes' joint sets meet, does one tube's solution lie
inside the other's tube?  Then the two solutions agree there, and a cover or chain of tubes that
pass these checks holds one continuous branch (:mod:`.tube_chain`).

Two tubes meet in the frame ``V`` of the newer one: the older one's joint set, seen in that frame, is
cut by the newer one's ``|w| <= tw`` (exact for two slabs of one cover, which share ``V``).  That
is a superset of the true intersection, so a hand-off checked over it holds there.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .clock import expired
from .krawczyk import PAD
from .linalg import wrap
from .scratch import floats, scratch2
from .tube import SLACK, TUBE_K, TUBE_Q, TUBE_R, TUBE_S, TUBE_T, TUBE_V, TUBE_W, TUBE_X, lin_bound, slab_test


@njit(cache=True)
def handoff(old, new, qm, U, h, need):
    """Does the solution of tube ``old`` lie inside tube ``new`` for every joint vector of the
    parallelepiped ``qm + U w``, ``|w| <= h`` (3,; ``U`` (3, 3), the identity for a box)?  Writes the
    half-widths ``new`` would need into ``need`` (3,) and returns whether its own are larger (then
    the two tubes' solutions agree there: it is the one solution of ``new``'s tube)."""
    ok = True
    for r in range(3):
        d = old[TUBE_X + r] - new[TUBE_X + r]
        if r == 2:
            d = wrap(d)
        for m in range(3):
            do = wrap(qm[m] - old[TUBE_Q + m])
            dn = wrap(qm[m] - new[TUBE_Q + m])
            d += old[TUBE_S + 3 * r + m] * do - new[TUBE_S + 3 * r + m] * dn
        spread = lin_bound(old[TUBE_S + 3 * r] - new[TUBE_S + 3 * r], old[TUBE_S + 3 * r + 1] - new[TUBE_S + 3 * r + 1],
                           old[TUBE_S + 3 * r + 2] - new[TUBE_S + 3 * r + 2], U, h)
        need[r] = ((abs(d) + spread + old[TUBE_K + r]) * (1.0 + SLACK) + PAD * (1.0 + abs(new[TUBE_X + r]))
                   + 1e-15)
        ok = ok and need[r] < new[TUBE_R + r]
    return ok


@njit(cache=True)
def meeting(a, b_, qm, U, h):
    """Where the joint sets of tubes ``a`` and ``b_`` (TUBE_SIZE,) may meet, as a parallelepiped
    ``qm + U w``, ``|w| <= h`` holding their intersection (written into ``qm`` (3,), ``U`` (3, 3),
    ``h`` (3,)), in the frame of ``b_`` (``U = V_b``): there ``a``'s set lies in the box about
    ``V_b^T (q_a - q_b)`` of half-widths ``|V_b^T V_a| tw_a``, cut by ``b_``'s own ``|w| <= tw_b``.
    (For two slabs of one cover, ``V_b^T V_a = I``: exact.)  Returns False when they cannot meet."""
    w = floats(3)
    for n in range(3):
        c, mag, half = 0.0, 0.0, 0.0
        for m in range(3):
            d = wrap(a[TUBE_Q + m] - b_[TUBE_Q + m]) * b_[TUBE_V + 3 * m + n]
            c += d
            mag += abs(d)
        for j in range(3):
            vv = 0.0
            for m in range(3):
                vv += b_[TUBE_V + 3 * m + n] * a[TUBE_V + 3 * m + j]
            half += abs(vv) * a[TUBE_W + j]
        pad = PAD * (1.0 + mag + half)
        lo = max(c - half, -b_[TUBE_W + n])
        hi = min(c + half, b_[TUBE_W + n])
        if lo > hi + pad:
            return False
        w[n] = 0.5 * (lo + hi)
        h[n] = max(0.5 * (hi - lo), 0.0) + pad
    for m in range(3):
        qm[m] = (b_[TUBE_Q + m] + b_[TUBE_V + 3 * m] * w[0] + b_[TUBE_V + 3 * m + 1] * w[1]
                 + b_[TUBE_V + 3 * m + 2] * w[2])
        for n in range(3):
            U[m, n] = b_[TUBE_V + 3 * m + n]
    return True


@njit(cache=True)
def takes_over(pieces, n, new, need, deadline=0.0):
    """Does tube ``new`` take over from every tube of ``pieces[:n]`` (n, TUBE_SIZE) where their joint
    sets may meet (:func:`meeting`, :func:`handoff`)?  ``need`` (3,) receives the largest
    half-widths ``new`` would need.  False also when the ``deadline`` (:mod:`.clock`) passes first."""
    ok = True
    qm, h, nd = floats(3), floats(3), floats(3)
    U = scratch2(3, 3, np.float64)
    for r in range(3):
        need[r] = 0.0
    for j in range(n):
        if (j & 15) == 15 and expired(deadline):
            return False
        if meeting(pieces[j], new, qm, U, h):
            ok = handoff(pieces[j], new, qm, U, h, nd) and ok
            for r in range(3):
                need[r] = max(need[r], nd[r])
    return ok


@njit(cache=True)
def point_prior(pieces, n, xg, qc, need):
    """The half-widths (3,) a tube of the single joint vector ``qc`` (3,) needs to take over from the
    tubes ``pieces[:n]`` whose joint boxes hold ``qc``, raised in ``need`` (3,) to 1.25 times that.

    Each such tube ``j`` holds one solution within ``kappa_j`` of its predictor at ``qc``, and the new
    tube's centre ``x~`` is that solution (Newton from ``xg``, the predictor), so :func:`handoff` asks
    for ``|x_j(qc) - x~| + kappa_j <= 2 kappa_j`` (with its rounding pads).  A tube test that starts
    this wide passes the hand-off on its first run; from its own ``2 a`` it would fail it whenever
    ``kappa_j`` is the wider (every step of the paper circle with exact joints: the reading's
    tube then ran twice).  Returns whether any tube holds ``qc`` (``need`` raised)."""
    found = False
    for j in range(n):
        holds = True
        for m in range(3):
            holds = holds and abs(wrap(qc[m] - pieces[j, TUBE_Q + m])) <= pieces[j, TUBE_T + m] + PAD
        if holds:
            found = True
            for r in range(3):
                want = (2.0 * pieces[j, TUBE_K + r] * (1.0 + SLACK) + PAD * (1.0 + abs(xg[r])) + 1e-15) * 1.25
                need[r] = max(need[r], want)
    return found


@njit(cache=True)
def tested_takeover(pieces, n, xg, qc, V, tw, tq, M, l1, l2sq, b, new, deadline=0.0):
    """A tube test of the joints ``qc + V w``, ``|w| <= tw``, within ``tq`` of ``qc`` (:func:`slab_test`, from the
    guess ``xg``) that also takes over from the tubes ``pieces[:n]`` (:func:`takes_over`): when the
    test passes but its tube is too narrow for a hand-off, it is tried once more with the
    half-widths the hand-offs need (until the ``deadline``).  A single joint vector (``tq`` zero: the
    exact reading of a tracker step) starts from :func:`point_prior`, so that its test runs once; when
    the test fails that wide, it starts again from its own width, as any other."""
    need = floats(3)
    need[:] = 0.0
    prior = tq[0] == 0.0 and tq[1] == 0.0 and tq[2] == 0.0 and point_prior(pieces, n, xg, qc, need)
    if not slab_test(xg, qc, V, tw, tq, need, M, l1, l2sq, b, new):
        if not prior:
            return False
        for r in range(3):
            need[r] = 0.0
        if not slab_test(xg, qc, V, tw, tq, need, M, l1, l2sq, b, new):
            return False
    if takes_over(pieces, n, new, need, deadline):
        return True
    if expired(deadline):
        return False
    for r in range(3):
        need[r] = max(1.25 * need[r], new[TUBE_R + r])
    return slab_test(xg, qc, V, tw, tq, need, M, l1, l2sq, b, new) and takes_over(pieces, n, new, need, deadline)
