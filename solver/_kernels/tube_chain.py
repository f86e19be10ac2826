"""Chains and covers of tubes (:mod:`.tube`) over a tracker step, and the pose bound of a cover.

A *cover* of a joint box is one tube of the whole box or, where one tube cannot hold it, the tubes
of its 2**3 or 3**3 parts (:func:`cover_box`, :func:`cover`); every tube is checked against every
earlier tube whose joint box meets its own (:func:`.tube.tested_takeover`), so that all of them
hold one solution: a continuous function on the union of their boxes.  :func:`tube_chain` covers a
tracker step's joint segment, widened by the joint tolerance, piece by piece from the previous
step's cover, then the reading's own box; :func:`pose_bound` turns the reading's cover into a box
about the returned pose.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .krawczyk import PAD
from .linalg import wrap
from .tube import (MATCH_PAD, SLACK, TUBE_K, TUBE_Q, TUBE_R, TUBE_S, TUBE_SIZE, TUBE_T, predictor, tested_takeover)

#: Tubes of the reading's own box, each taking over from the last, that tighten its bound.
REFINE = 6
#: Most tubes one step's chain may hold (the pieces of the joint step and the reading's own box).
MAX_PIECES = 200
#: A joint box one tube cannot hold is split in 2**3, then 3**3 parts (a *cover*), each with its tube.
COVER_PARTS = 3
#: Most tubes of one joint box's cover (COVER_PARTS**3): what a tracker's state holds.
MAX_COVER = 27


@njit(cache=True)
def cover_box(pieces, n, guess, qc, t, parts, M, l1, l2sq, b):
    """Cover the joint box ``qc +- t`` (3,) with ``parts**3`` tubes appended to ``pieces`` (m, TUBE_SIZE)
    after its first ``n``, each taking over from every earlier tube whose joint box meets its own
    (:func:`tested_takeover`); ``guess`` (TUBE_SIZE,): a tube whose predictor starts Newton.
    Returns the new number of tubes, or -1 when a part fails or ``pieces`` is full."""
    q, h, xg = np.empty(3), np.empty(3), np.empty(3)
    new = np.empty(TUBE_SIZE)
    m = n
    for k in range(parts ** 3):
        if m >= pieces.shape[0]:
            return -1
        for i in range(3):
            idx = (k // parts ** i) % parts
            h[i] = t[i] / parts
            q[i] = qc[i] - t[i] + (2 * idx + 1) * h[i]
        predictor(guess, q, xg)
        if not tested_takeover(pieces, m, xg, q, h, M, l1, l2sq, b, new):
            return -1
        pieces[m, :] = new
        m += 1
    return m


@njit(cache=True)
def cover(pieces, n, guess, qc, t, M, l1, l2sq, b):
    """:func:`cover_box` with one tube, else 2**3, else 3**3 parts.  Returns (new count, -1 when none
    closed; tube tests used)."""
    tests = 0
    for parts in range(1, COVER_PARTS + 1):
        tests += parts ** 3
        m = cover_box(pieces, n, guess, qc, t, parts, M, l1, l2sq, b)
        if m > 0:
            return m, tests
    return -1, tests


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
    qc, t = np.empty(3), np.empty(3)
    s, step = 0.0, 1.0
    tests = 0
    last = 0                                           # where the last piece's cover starts
    while s < 1.0:
        if tests >= max_tests or step < 1.0 / 256.0:
            return -max(tests, 1), 0
        sb = min(1.0, s + step)
        for i in range(3):
            qc[i] = qp[i] + 0.5 * (s + sb) * dq[i]
            t[i] = 0.5 * abs(dq[i]) * (sb - s) + tol
        m, used = cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b)
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
    m, used = cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b)
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
def refine(out, pieces, n, qc, t, M, l1, l2sq, b):
    """Tighten the single tube ``out[0]`` of the reading's box ``qc +- t``: tubes of the same box, each
    taking over from the last (kappa shrinks with rho^2), while kappa shrinks.  Returns the tests."""
    tests = 0
    xg = np.empty(3)
    new = np.empty(TUBE_SIZE)
    if n >= pieces.shape[0]:
        return 0
    for _ in range(REFINE):
        if t[0] == 0.0 and t[1] == 0.0 and t[2] == 0.0 and out[0, TUBE_T] == 0.0 and out[0, TUBE_T + 1] == 0.0 \
                and out[0, TUBE_T + 2] == 0.0 and tests > 0:
            break
        predictor(out[0], qc, xg)
        tests += 1
        pieces[n, :] = out[0]
        if not tested_takeover(pieces[n:n + 1], 1, xg, qc, t, M, l1, l2sq, b, new):
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
    p, c, h = np.empty(3), np.empty(3), np.empty(3)
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
            holds = holds and abs(wrap(q[i] - tube[TUBE_Q + i])) <= tube[TUBE_T + i] + PAD
            c[i], h[i] = 0.5 * (lo + hi), max(0.5 * (hi - lo), 0.0)
        if not meet:
            continue
        predictor(tube, c, p)
        for r in range(3):
            d = X[r] - p[r]
            if r == 2:
                d = wrap(d)
            spread = 0.0
            for m in range(3):
                spread += abs(tube[TUBE_S + 3 * r + m]) * h[m]
            b = (spread + abs(d) + tube[TUBE_K + r]) * (1.0 + SLACK) + PAD * (1.0 + abs(X[r])) + 1e-15
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
