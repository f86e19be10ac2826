"""Chains and covers of tubes (:mod:`.tube`) over a tracker step, and the pose bound of a cover.

A *cover* of a joint box is one tube of the whole box or, where one tube cannot hold it, slabs
across the needle (:func:`slab_cover`: the box cut across ``v1``, the top right-singular vector of
``S``, into :data:`SLABS` parts, each a thin parallelepiped with its tube), else the tubes of its
2**3 or 3**3 axis-aligned parts (:func:`cover_box`, :func:`cover`).  Every tube is checked
against every earlier tube it may meet (:func:`.handoff.tested_takeover`), so that all of them hold
one solution: a continuous function on the union of their joint sets.  :func:`tube_chain` covers
a tracker step's joint segment, widened by the joint tolerance, piece by piece from the previous
step's cover, then the reading's own box; :func:`pose_bound` turns the reading's cover into a box
about the returned pose.

Why slabs: the poses of a joint box form a needle of length about ``|S| t`` along ``S v1``; a
tube's remainder grows with the square of that length, so cutting the box across ``v1`` into N
slabs divides it by N**2 at the cost of N tests, where axis-aligned parts cost N**3 and shorten
the needle only by N (measured on the 16-bit + 1e-4 rad streams: design note section 2.4).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .clock import expired
from .krawczyk import PAD
from .linalg import identity3, wrap
from .scratch import floats, scratch2
from .handoff import tested_takeover
from .tube import (MATCH_PAD, SLACK, TUBE_K, TUBE_Q, TUBE_R, TUBE_S, TUBE_SIZE, TUBE_T, TUBE_V, TUBE_W, TUBE_X,
                   lin_bound, predictor)

#: Tubes of the reading's own box, each taking over from the last, that tighten its bound.
REFINE = 6
#: A single joint vector's tube with kappa within this many rounding pads (:data:`.krawczyk.PAD`) of its
#: coordinates is not refined (:func:`at_rounding`).
ROUNDING_KAPPA = 64.0
#: Most tubes one step's chain may hold (the pieces of the joint step and the reading's own box).
MAX_PIECES = 200
#: A joint box one tube cannot hold is split in 2**3, then 3**3 parts (a *cover*), each with its tube.
COVER_PARTS = 3
#: Slab counts tried (in this order) across the needle when one tube cannot hold a joint box.
SLABS = (3, 8, 20, 50)
#: Most tubes of one joint box's cover (COVER_PARTS**3): what a tracker's state holds.
MAX_COVER = 27


@njit(cache=True)
def cover_box(pieces, n, guess, qc, t, parts, M, l1, l2sq, b, deadline=0.0, k0=0):
    """Cover the joint box ``qc +- t`` (3,) with ``parts**3`` tubes appended to ``pieces`` (m, TUBE_SIZE)
    after its first ``n``, each taking over from every earlier tube whose joint box meets its own
    (:func:`tested_takeover`); ``guess`` (TUBE_SIZE,): a tube whose predictor starts Newton.
    Returns the new number of tubes, or -1 when a part fails or ``pieces`` is full.  With a
    ``deadline`` (:mod:`.clock`): ``-2 - k`` when it passed before part ``k`` (the parts before it are
    ``pieces[n:n + k]``, also when its hand-offs were cut); a cover cut there goes on from part ``k0``
    (that part runs to its end, whatever the deadline: each call makes progress)."""
    q, h, xg = floats(3), floats(3), floats(3)
    new = floats(TUBE_SIZE)
    eye = scratch2(3, 3, np.float64)
    identity3(eye)
    m = n + k0
    for k in range(k0, parts ** 3):
        if m >= pieces.shape[0]:
            return -1
        if k > k0 and expired(deadline):
            return -2 - k
        for i in range(3):
            idx = (k // parts ** i) % parts
            h[i] = t[i] / parts
            q[i] = qc[i] - t[i] + (2 * idx + 1) * h[i]
        predictor(guess, q, xg)
        new[TUBE_S] = np.nan
        if not tested_takeover(pieces, m, xg, q, eye, h, h, M, l1, l2sq, b, new, deadline if k > k0 else 0.0):
            if k > k0 and expired(deadline):           # cut in its hand-offs: this part again next time
                return -2 - k
            pieces[m, :] = new                         # scratch past the count: S for a slab cover
            return -1
        pieces[m, :] = new
        m += 1
    return m


@njit(cache=True)
def needle_frame(S, V):
    """An orthonormal frame ``V`` (3, 3) whose first column is the needle's joint direction: the top
    right-singular vector of ``S`` (3, 3; power iteration on ``S^T S``); the others complete it."""
    A = S.T @ S
    v = np.ones(3) / np.sqrt(3.0)
    for _ in range(60):
        u = A @ v
        nu = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
        if not nu > 0.0:
            break
        u /= nu
        if abs(u @ v) > 1.0 - 1e-14:
            v = u
            break
        v = u
    k = int(np.argmin(np.abs(v)))
    e = np.zeros(3)
    e[k] = 1.0
    e -= (e @ v) * v
    e /= np.sqrt(e @ e)
    V[:, 0] = v
    V[:, 1] = e
    V[:, 2] = np.cross(v, e)


@njit(cache=True)
def slab_cover(pieces, n, guess, qc, t, slabs, V, M, l1, l2sq, b, deadline=0.0, k0=0):
    """Cover the joint box ``qc +- t`` (3,) with ``slabs`` slabs across ``V[:, 0]`` (the needle's joint
    direction, :func:`needle_frame`), each a parallelepiped ``q_m + V w`` with its tube
    (:func:`.tube.slab_test`), appended to ``pieces`` after its first ``n`` and each taking over
    from every earlier tube it may meet.  Returns the new number of tubes, or -1; with a ``deadline``,
    ``-2 - k`` as :func:`cover_box` (and from slab ``k0`` on)."""
    tw = floats(3)
    for j in range(3):                                  # the box in the frame: |w_j| <= sum_i |V_ij| t_i
        tw[j] = (abs(V[0, j]) * t[0] + abs(V[1, j]) * t[1] + abs(V[2, j]) * t[2]) * (1.0 + 1e-12)
    width = tw[0]
    tw[0] = width / slabs
    q, xg, tq = floats(3), floats(3), floats(3)
    new = floats(TUBE_SIZE)
    m = n + k0
    for k in range(k0, slabs):
        if m >= pieces.shape[0]:
            return -1
        if k > k0 and expired(deadline):
            return -2 - k
        off = -width + (2 * k + 1) * tw[0]
        for i in range(3):                              # the slab's centre, and the box about it holding box & slab
            q[i] = qc[i] + V[i, 0] * off
            hull = abs(V[i, 0]) * tw[0] + abs(V[i, 1]) * tw[1] + abs(V[i, 2]) * tw[2]
            lo = max(qc[i] - t[i], q[i] - hull)
            hi = min(qc[i] + t[i], q[i] + hull)
            tq[i] = max(q[i] - lo, hi - q[i]) * (1.0 + 1e-12) + PAD
        predictor(guess, q, xg)
        if not tested_takeover(pieces, m, xg, q, V, tw, tq, M, l1, l2sq, b, new, deadline if k > k0 else 0.0):
            return -2 - k if k > k0 and expired(deadline) else -1
        pieces[m, :] = new
        m += 1
    return m


#: What :func:`cover` tries: every stage; one tube only; no axis-aligned parts after the slabs.
COVER_ALL, COVER_ONE, COVER_SLABS = 0, 1, 2


@njit(cache=True)
def cover(pieces, n, guess, qc, t, M, l1, l2sq, b, deadline=0.0, stages=COVER_ALL):
    """:func:`cover_box` with one tube, else slabs across the needle (:data:`SLABS`), else 2**3 and
    3**3 parts, until the ``deadline``; ``stages`` (:func:`cover_stages`) may stop after the one tube
    or after the slabs.  Returns (new count, -1 when none closed; tube tests used)."""
    tests = 1
    m = cover_box(pieces, n, guess, qc, t, 1, M, l1, l2sq, b, deadline)
    if m > 0 or expired(deadline) or stages == COVER_ONE:
        return m, tests
    if n < pieces.shape[0] and pieces[n, TUBE_S] == pieces[n, TUBE_S]:   # the failed test left S
        V = scratch2(3, 3, np.float64)
        S = scratch2(3, 3, np.float64)
        for i in range(3):
            for j in range(3):
                S[i, j] = pieces[n, TUBE_S + 3 * i + j]
        needle_frame(S, V)
        for slabs in SLABS:
            tests += slabs
            m = slab_cover(pieces, n, guess, qc, t, slabs, V, M, l1, l2sq, b, deadline)
            if m > 0 or expired(deadline):
                return m, tests
        if stages == COVER_SLABS:
            return -1, tests
    for parts in range(2, COVER_PARTS + 1):
        tests += parts ** 3
        m = cover_box(pieces, n, guess, qc, t, parts, M, l1, l2sq, b, deadline)
        if m > 0 or expired(deadline):
            return m, tests
    return -1, tests


@njit(cache=False)
def cover_stages(half, tol):
    """The stages worth trying for a piece of a joint step with half-extent ``half`` (3,, rad) along the
    step, widened by ``tol``.  With measured joints (``tol > 0``): a piece longer than its tolerance box
    gets one tube, and when that fails is halved rather than cut in slabs (a shorter piece is cheaper
    than 20 or 50 slabs, measured on the suite's near-singular stretches); slabs that fail are not
    followed by axis-aligned parts (which never closed there).  Exact joints: every stage."""
    if tol <= 0.0:
        return COVER_ALL
    if max(half[0], max(half[1], half[2])) > tol:
        return COVER_ONE
    return COVER_SLABS


@njit(cache=True)
def tube_chain(old, n_old, qp, dq, tol, max_tests, M, l1, l2sq, b, out):
    """Chain tubes over the joint step from ``qp`` to ``qp + dq`` (3,, unwrapped), each covering the
    joints within ``tol`` (rad) of a piece of the segment, starting from the previous step's
    cover ``old[:n_old]`` (n, TUBE_SIZE; it covers ``qp +- tol``), then a cover of the reading's
    own box ``qp + dq +- tol``.

    Assumes the robot's joints stay within ``tol`` of the segment between the samples.  Then,
    when it returns a positive number of tests, the robot's pose at the new sample is the
    solution of the cover ``out[:n_out]`` (MAX_COVER, TUBE_SIZE) at its true joints (within
    ``tol`` of ``qp + dq``): every two tubes agree on the box where their joint boxes meet
    (:func:`takes_over`), so their solutions make one continuous function on the union of the
    boxes, and a pose that moves continuously along a tube's solution cannot leave it (its
    deviation is at most ``kappa < rho``).  A piece one tube cannot hold is covered in parts
    (:func:`cover`).  Returns (tests, n_out); tests is ``-tests`` when the chain did not close
    within ``max_tests`` tube tests.
    """
    pieces = np.empty((MAX_PIECES, TUBE_SIZE))
    for j in range(n_old):
        pieces[j, :] = old[j]
        for i in range(3):                             # the old tubes' joints next to qp
            pieces[j, TUBE_Q + i] = qp[i] + wrap(old[j, TUBE_Q + i] - qp[i])
    n = n_old
    qc, t, half = floats(3), floats(3), floats(3)
    s, step = 0.0, 1.0
    tests = 0
    last = 0                                           # where the last piece's cover starts
    while s < 1.0:
        if tests >= max_tests or step < 1.0 / 256.0:
            return -max(tests, 1), 0
        sb = min(1.0, s + step)
        for i in range(3):
            qc[i] = qp[i] + 0.5 * (s + sb) * dq[i]
            half[i] = 0.5 * abs(dq[i]) * (sb - s)
            t[i] = half[i] + tol
        m, used = cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b, 0.0, cover_stages(half, tol))
        tests += used
        if m > 0:
            last, n = n, m
            s = sb
            step = min(1.25 * step, 1.0)
        else:
            step *= 0.5
    # the reading's own box: a tighter cover about the new joints (else the last piece's)
    for i in range(3):
        qc[i] = qp[i] + dq[i]
        t[i] = tol
    m, used = cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b, 0.0, COVER_ALL if tol <= 0.0 else COVER_SLABS)
    tests += used
    if m > 0:
        last, n = n, m
    n_out = min(n - last, MAX_COVER)
    if n - last > MAX_COVER:                           # a piece in 27 parts past the reading: too wide to keep
        return -max(tests, 1), 0
    for j in range(n_out):
        out[j, :] = pieces[last + j]
    if n_out == 1:
        tests += refine(out, pieces, n, qc, t, M, l1, l2sq, b)
    return tests, n_out


@njit(cache=True)
def at_rounding(tube, t):
    """Whether the tube of a single joint vector (``t`` (3,) zero) is as tight as its rounding allows:
    every kappa within :data:`ROUNDING_KAPPA` pads of its coordinate.  Another tube of the same point
    would take over with ``rho`` about ``2 kappa`` and end at the same rounding level (measured on the
    paper circle: 2.22e-14 -> 2.22e-14 m), so :func:`refine` does not run it."""
    if not (t[0] == 0.0 and t[1] == 0.0 and t[2] == 0.0):
        return False
    for r in range(3):
        if not tube[TUBE_K + r] <= ROUNDING_KAPPA * PAD * (1.0 + abs(tube[TUBE_X + r])):
            return False
    return True


@njit(cache=True)
def refine(out, pieces, n, qc, t, M, l1, l2sq, b):
    """Tighten the single tube ``out[0]`` of the reading's box ``qc +- t``: tubes of the same box, each
    taking over from the last (kappa shrinks with rho^2), while kappa shrinks.  Returns the tests."""
    tests = 0
    xg = floats(3)
    new = floats(TUBE_SIZE)
    eye = scratch2(3, 3, np.float64)
    identity3(eye)
    if n >= pieces.shape[0] or at_rounding(out[0], t):
        return 0
    for _ in range(REFINE):
        if t[0] == 0.0 and t[1] == 0.0 and t[2] == 0.0 and out[0, TUBE_T] == 0.0 and out[0, TUBE_T + 1] == 0.0 \
                and out[0, TUBE_T + 2] == 0.0 and tests > 0:
            break
        predictor(out[0], qc, xg)
        tests += 1
        pieces[n, :] = out[0]
        if not tested_takeover(pieces[n:n + 1], 1, xg, qc, eye, t, t, M, l1, l2sq, b, new):
            break
        shrink = max(new[TUBE_K] / out[0, TUBE_K], max(new[TUBE_K + 1] / out[0, TUBE_K + 1],
                                                       new[TUBE_K + 2] / out[0, TUBE_K + 2]))
        out[0, :] = new
        if shrink > 0.7:
            break
    return tests


@njit(cache=True)
def pose_bound(tubes, n, q, tol, X, out):
    """Half-widths (3,) into ``out`` of a box about the pose ``X`` (3,) holding the solution of the cover
    ``tubes[:n]`` (n, TUBE_SIZE) for every joint vector within ``tol`` of ``q`` (3,): over each
    tube whose joint box meets ``q +- tol`` (centre ``c``, half-widths ``h`` of the meeting box),
    ``|S| h + |X - x~ - S (c - q~)| + kappa``.  Returns whether ``X`` lies, up to
    :data:`MATCH_PAD`, in the tube of a joint box holding ``q`` (a DK solution there is the
    cover's, up to its own rounding).  The bound holds for any ``X``."""
    p, c, h, tw = floats(3), floats(3), floats(3), floats(3)
    V = scratch2(3, 3, np.float64)
    inside = False
    for r in range(3):
        out[r] = 0.0
    for j in range(n):
        tube = tubes[j]
        meet, holds = True, True
        for i in range(3):
            lo = max(q[i] - tol, tube[TUBE_Q + i] - tube[TUBE_T + i])
            hi = min(q[i] + tol, tube[TUBE_Q + i] + tube[TUBE_T + i])
            meet = meet and lo <= hi + PAD
            c[i], h[i] = 0.5 * (lo + hi), max(0.5 * (hi - lo), 0.0)
        if not meet:
            continue
        for i in range(3):
            tw[i] = tube[TUBE_W + i]
            for m in range(3):
                V[i, m] = tube[TUBE_V + 3 * i + m]
        for m in range(3):                             # q in the tube's joint set: |V^T (q - q~)| <= tw
            wm, mag = 0.0, 0.0
            for i in range(3):
                d = wrap(q[i] - tube[TUBE_Q + i]) * V[i, m]
                wm += d
                mag += abs(d)
            holds = holds and abs(wm) <= tw[m] + PAD * (1.0 + mag)
        predictor(tube, c, p)
        for r in range(3):
            d = X[r] - p[r]
            if r == 2:
                d = wrap(d)
            spread = 0.0
            for m in range(3):
                spread += abs(tube[TUBE_S + 3 * r + m]) * h[m]
            d0 = X[r] - tube[TUBE_X + r]               # or over the tube's whole joint set (a slab's is narrower)
            if r == 2:
                d0 = wrap(d0)
            whole = lin_bound(tube[TUBE_S + 3 * r], tube[TUBE_S + 3 * r + 1], tube[TUBE_S + 3 * r + 2], V, tw) + abs(d0)
            b = (min(spread + abs(d), whole) + tube[TUBE_K + r]) * (1.0 + SLACK) + PAD * (1.0 + abs(X[r])) + 1e-15
            out[r] = max(out[r], b)
        if holds:
            predictor(tube, q, p)
            at_q = True
            for r in range(3):
                d = X[r] - p[r]
                if r == 2:
                    d = wrap(d)
                at_q = at_q and abs(d) < tube[TUBE_R + r] + MATCH_PAD
            inside = inside or at_q
    return inside
