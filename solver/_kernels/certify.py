"""The tracker's certificates, compiled: chains of Krawczyk boxes along DK branches.

:func:`follow_branch` chains boxes (:func:`.krawczyk.krawczyk`) from ``s = 0``
to ``s = 1``; two consecutive boxes share a tiny box (half-width :data:`TINY`)
around the solution at their common ``s``, itself proved to hold exactly one
solution, so the chain proves that the branch through the start pose ends in the
last tiny box.  With measured joints the boxes cover the tube of joint paths
within ``eps`` of the segment (an inner piece at least ``2 eps`` long, so that
only neighbouring pieces meet), and a piece one box cannot cover is split in
parts (:func:`split_tube`).

:func:`.candidates.certify` turns chains into the tracker's candidate set (the
DK solutions that the true branch can be); the certificate codes are here.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from .clock import expired
from .kinematics import geometry
from .krawczyk import PAD, W_G, W_J, W_SIZE, W_TOT, W_Y, krawczyk, newton_on_path, point_terms
from .linalg import inverse3_flat as inverse3
from .linalg import wrap
from .scratch import floats, scratch2

#: Half-width of the tiny verified boxes that link a chain (m, m, rad).
TINY = 1e-9
#: Epsilon-inflation rounds of one box before its interval of s is halved.
INFLATE = 3
#: Largest half-width a box is inflated to (m or rad).
RHO_CAP = 0.05
#: Two poses are the same solution when they differ by less than this (m, m, rad).
MATCH = 1e-7

#: The boxes of one chain's links (:func:`follow_branch`): the tiny half-widths ``tiny`` (3,), a zero
#: tube ``none`` (3,), the joint tube ``tube`` (3,) rad, and a box's centre ``c`` and half-widths ``rho``
#: (3,) (m, m, rad), allocated once per chain.
LinkBoxes = namedtuple("LinkBoxes", ("tiny", "none", "tube", "c", "rho"))

#: Certificates (the tracker's ``certificate`` output).
CERT_NONE, CERT_CONTINUATION, CERT_ELIMINATION, CERT_POSTURE, CERT_REACQUIRED, CERT_TUBE = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def inflate(rho, w):
    """Epsilon-inflation: grow the half-widths ``rho`` (3,) to 1.25 times the last Krawczyk image
    (``w[W_TOT:]``) plus 2 TINY; False when a half-width would reach :data:`RHO_CAP`."""
    grow = True
    for i in range(3):
        r_new = 1.25 * w[W_TOT + i] + 2.0 * TINY
        grow = grow and r_new < RHO_CAP
        rho[i] = max(rho[i], r_new)
    return grow


@njit(cache=True)
def prove_part(qc, e, pq, px, n, guess, M, l1, b, l2sq, w, xc, rho):
    """Krawczyk's proof for the joint box ``qc +- e`` (3,), its pose box about the solution at ``qc``.

    ``xc`` (3,) receives that solution (Newton from ``guess``) and ``rho`` (3,) the pose
    box's half-widths (at most :data:`RHO_CAP`).  The pose box is grown
    (epsilon-inflation) from the smallest one that holds the tiny verified boxes of the
    points ``pq[:n]`` (joints) / ``px[:n]`` (their solutions) that lie in the joint box.
    Returns 1 when proved, 0 when not, -1 when there is no regular solution at ``qc``.
    """
    none = floats(3)
    none[:] = 0.0
    xc[:] = guess
    if newton_on_path(xc, qc, none, none, 0.0, M, l1, b, l2sq, w, 8) > 1e-12:
        return -1
    for i in range(3):
        rho[i] = 2.0 * TINY
    for j in range(n):
        inside = True
        for i in range(3):
            inside = inside and abs(pq[j, i] - qc[i]) <= e[i] + PAD
        if inside:
            for i in range(3):
                rho[i] = max(rho[i], abs(px[j, i] - xc[i]) + 2.0 * TINY)
    if max(rho[0], max(rho[1], rho[2])) > RHO_CAP:
        return 0
    for _ in range(INFLATE + 3):
        if krawczyk(xc, rho, qc, none, none, 0.0, 0.0, e, M, l1, b, l2sq, w):
            return 1
        if not inflate(rho, w):
            return 0
    return 0


@njit(cache=True)
def split_tube(x, xb, q0, d1, s, sb, eps, M, l1, b, l2sq, w):
    """The tube of one piece of a straight joint segment, proved in parts (two levels of halving).

    The piece's joint box (the hull of ``q(s) +- eps`` and ``q(sb) +- eps``) is split in
    eight about its centre ``q_m``, and a part that fails in eight again about its own
    centre.  Each part gets its own Krawczyk box about the solution at its centre; parts
    that share a centre hold the tiny verified box there, and a part holds the tiny boxes
    of the piece's ends (``x``, ``xb``) and of ``q_m`` when it contains their joints.  The
    parts' branches so agree where they meet (two regular branches that agree at one
    point of a convex set agree on all of it): one branch over the whole piece.
    Returns the number of Krawczyk tests (> 0) when proved, minus it when not.
    """
    none, tiny = floats(3), floats(3)
    none[:] = 0.0
    tiny[:] = TINY
    pq, px = scratch2(4, 3, np.float64), scratch2(4, 3, np.float64)
    e, ea, qa, xa, qc, xc = floats(3), floats(3), floats(3), floats(3), floats(3), floats(3)
    rho = floats(3)
    sm = 0.5 * (s + sb)
    for i in range(3):
        pq[0, i], px[0, i] = q0[i] + sm * d1[i], 0.5 * (x[i] + xb[i])
        pq[1, i], px[1, i] = q0[i] + s * d1[i], x[i]
        pq[2, i], px[2, i] = q0[i] + sb * d1[i], xb[i]
        e[i] = 0.25 * abs(d1[i]) * (sb - s) + 0.5 * eps
        ea[i] = 0.5 * e[i]
    tests = 1
    if newton_on_path(px[0], pq[0], none, none, 0.0, M, l1, b, l2sq, w, 8) > 1e-12 or \
            not krawczyk(px[0], tiny, pq[0], none, none, 0.0, 0.0, none, M, l1, b, l2sq, w):
        return -tests
    for corner in range(8):
        for i in range(3):
            qa[i] = pq[0, i] + (e[i] if (corner >> i) & 1 else -e[i])
        tests += 4
        got = prove_part(qa, e, pq, px, 3, px[0], M, l1, b, l2sq, w, xa, rho)
        if got == 1:
            continue
        tests += 1
        if got < 0 or not krawczyk(xa, tiny, qa, none, none, 0.0, 0.0, none, M, l1, b, l2sq, w):
            return -tests
        pq[3, :], px[3, :] = qa, xa
        for child in range(8):
            for i in range(3):
                qc[i] = qa[i] + (ea[i] if (child >> i) & 1 else -ea[i])
            tests += 4
            if prove_part(qc, ea, pq, px, 4, xa, M, l1, b, l2sq, w, xc, rho) != 1:
                return -tests
    return tests


@njit(cache=True)
def follow_branch(X0, verified, q0, d1, d2, eps, M, l1, b, l2sq, max_tests, out, deadline=0.0):
    """Follow the branch through ``X0`` at ``q(0)`` to ``s = 1`` with a chain of Krawczyk boxes.

    ``verified``: ``X0`` is already known to be within TINY of the only solution
    in its tiny box (the end of a previous chain), so the first test is skipped.
    Returns the number of tests used (> 0) and the end pose in ``out`` (3,) on
    success: the branch at ``q(1)`` is the one solution within TINY of ``out``.
    Returns ``-tests`` when the chain could not be closed within ``max_tests`` or before the
    ``deadline`` (:mod:`.clock`).
    """
    x = floats(3)
    x[:] = X0
    if not verified and not tiny_box(x, q0, d1, d2, M, l1, b, l2sq):
        return -1
    prog = floats(3)
    prog[0], prog[1], prog[2] = 0.0, 1.0, 0.0 if verified else 1.0
    if follow_on(x, q0, d1, d2, eps, M, l1, b, l2sq, max_tests, deadline, prog) <= 0:
        return -max(int(prog[2]), 1)
    out[:] = x
    return int(prog[2])


@njit(cache=False)
def tiny_box(x, q0, d1, d2, M, l1, b, l2sq):
    """The tiny box about ``x`` (3,) at ``q(0)`` holds exactly one solution (the first test of a chain)."""
    w = floats(W_SIZE)
    tiny, none = floats(3), floats(3)
    tiny[:] = TINY
    none[:] = 0.0
    return krawczyk(x, tiny, q0, d1, d2, 0.0, 0.0, none, M, l1, b, l2sq, w)


#: What :func:`follow_on` ends with.
FOLLOW_FAILED, FOLLOW_CUT, FOLLOW_DONE = -1, 0, 1


@njit(cache=True)
def follow_on(x, q0, d1, d2, eps, M, l1, b, l2sq, max_tests, deadline, prog):
    """The chain of :func:`follow_branch` from ``x`` (3,, a proved solution at ``q(s)``) on to ``s = 1``,
    resumable: ``prog`` (3,) holds ``s``, the next piece's length and the tests used, and ``x`` the
    branch at ``s``; both are updated in place.  Returns FOLLOW_DONE (``x`` is the branch at
    ``q(1)``), FOLLOW_CUT (the ``deadline`` passed: call again with the same ``prog``) or
    FOLLOW_FAILED (``max_tests`` used, a singular Jacobian, or a piece shorter than the tube)."""
    w = floats(W_SIZE)
    tiny, none, tube = floats(3), floats(3), floats(3)
    tiny[:] = TINY
    none[:] = 0.0
    tube[:] = eps
    bx = LinkBoxes(tiny, none, tube, floats(3), floats(3))
    dq_max = 0.0
    for i in range(3):
        dq_max = max(dq_max, abs(d1[i]))
    s, h, tests = prog[0], prog[1], int(prog[2])
    xb = floats(3)
    status = FOLLOW_DONE
    while s < 1.0:
        if tests >= max_tests:
            status = FOLLOW_FAILED
            break
        if expired(deadline):
            status = FOLLOW_CUT
            break
        sb = min(1.0, s + h)
        if eps > 0.0 and s > 0.0 and sb < 1.0 and (sb - s) * dq_max <= 2.0 * eps * (1.0 + 1e-9):
            status = FOLLOW_FAILED                    # an inner piece shorter than the tube's width
            break
        got = predict_piece(x, q0, d1, d2, s, sb, M, l1, b, l2sq, w, xb)
        if got < 0:
            status = FOLLOW_FAILED
            break
        tests += 1
        ok = got == 1
        if ok:
            ok, used = prove_piece(x, xb, q0, d1, d2, s, sb, eps, M, l1, b, l2sq, w, bx)
            tests += used
        if ok:
            s = sb
            x[:] = xb
            h = min(2.0 * h, 1.0)
        else:
            h *= 0.5
    prog[0], prog[1], prog[2] = s, h, tests
    return status


@njit(cache=False)
def predict_piece(x, q0, d1, d2, s, sb, M, l1, b, l2sq, w, xb):
    """The solution at ``q(sb)`` continued from ``x`` (3,) at ``q(s)``, into ``xb`` (3,): an Euler
    step along ``dX/ds = -J^-1 g``, then Newton at ``q(sb)``.  Returns 1 when Newton converged,
    0 when not, -1 when J is singular at ``x``."""
    point_terms(x[0], x[1], x[2], q0, d1, d2, s, M, l1, b, l2sq, w)
    if not inverse3(w, W_J, W_Y):
        return -1
    for r in range(3):
        xb[r] = x[r] - (sb - s) * (w[W_Y + 3 * r] * w[W_G] + w[W_Y + 3 * r + 1] * w[W_G + 1]
                                   + w[W_Y + 3 * r + 2] * w[W_G + 2])
    return 1 if newton_on_path(xb, q0, d1, d2, sb, M, l1, b, l2sq, w, 6) < 1e-12 else 0


@njit(cache=False)
def prove_piece(x, xb, q0, d1, d2, s, sb, eps, M, l1, b, l2sq, w, bx):
    """The chain's link over ``s`` in [s, sb]: one Krawczyk box (grown by epsilon-inflation)
    holding the branch from ``x`` to ``xb`` (3,) over the path (the tube within ``eps`` of it),
    then the tiny box at ``xb``; with measured joints, where one box fails, the tube in parts
    (:func:`split_tube`).  ``bx``: the chain's :data:`LinkBoxes`.  Returns (proved, Krawczyk
    tests used)."""
    tiny, none, tube, c, rho = bx.tiny, bx.none, bx.tube, bx.c, bx.rho
    tests = 0
    dmax = 0.0
    for i in range(3):
        dmax = max(dmax, abs(xb[i] - x[i]))
    for i in range(3):
        c[i] = 0.5 * (x[i] + xb[i])
        rho[i] = 0.5 * abs(xb[i] - x[i]) + 0.25 * dmax + 2.0 * TINY
    ok = False
    for _ in range(INFLATE):                  # epsilon-inflation towards the Krawczyk image
        tests += 1
        if (eps == 0.0 or max(rho[0], max(rho[1], rho[2])) <= RHO_CAP) and \
                krawczyk(c, rho, q0, d1, d2, s, sb, tube, M, l1, b, l2sq, w):
            ok = True
            break
        if not inflate(rho, w):
            break
    if ok:
        tests += 1
        ok = krawczyk(xb, tiny, q0, d1, d2, sb, sb, none, M, l1, b, l2sq, w)
    if not ok and eps > 0.0 and krawczyk(xb, tiny, q0, d1, d2, sb, sb, none, M, l1, b, l2sq, w):
        used = split_tube(x, xb, q0, d1, s, sb, eps, M, l1, b, l2sq, w)
        tests += abs(used)
        ok = used > 0
    return ok, tests


@njit(cache=True)
def follow_back(X, q, d1, d2, cands, n_cand, max_tests, M, l1, b, l2sq, deadline=0.0):
    """Where the solution ``X`` (3,) at the joints ``q`` (3,) came from: a chain of Krawczyk boxes
    back along the joint path ``q0 + s d1 + s^2 d2`` (``s`` from 1 to 0, ``q = q0 + d1 + d2``),
    walked as ``q(1 - u) = q + u rd1 + u^2 rd2`` with ``rd1 = -(d1 + 2 d2)``, ``rd2 = d2``.

    Returns 1 when it ends on one of ``cands[:n_cand]`` (6, 3), 0 when it ends elsewhere, -1 when
    the chain could not be closed within ``max_tests`` tests.
    """
    rd1, rd2, end = floats(3), floats(3), floats(3)
    for i in range(3):
        rd1[i] = -(d1[i] + 2.0 * d2[i])
        rd2[i] = d2[i]
    if follow_branch(X, False, q, rd1, rd2, 0.0, M, l1, b, l2sq, max_tests, end, deadline) <= 0:
        return -1
    for j in range(n_cand):
        if same_pose(end, cands[j]):
            return 1
    return 0


@njit(cache=True)
def comes_from(X, q, dq, cands, n_cand, max_tests, model_pack, deadline=0.0):
    """The solution ``X`` (3,) at the joints ``q`` (3,) is joined by a chain of Krawczyk boxes,
    back along the straight joint segment to ``q - dq``, to one of ``cands[:n_cand]`` (6, 3)
    (at most ``max_tests`` tests)."""
    M, l1, l2sq, b = geometry(model_pack)
    d2 = floats(3)
    d2[:] = 0.0
    return follow_back(X, q, dq, d2, cands, n_cand, max_tests, M, l1, b, l2sq, deadline) == 1


@njit(cache=True)
def same_pose(a, b):
    """The poses are the same solution (within MATCH, phi wrapped)."""
    return abs(a[0] - b[0]) < MATCH and abs(a[1] - b[1]) < MATCH and abs(wrap(a[2] - b[2])) < MATCH


@njit(cache=True)
def elbow_bits(X, q, M, l1, b):
    """Posture - 1 of the configuration (X, q): bit i set where leg i's elbow sign is negative."""
    c, s = math.cos(X[2]), math.sin(X[2])
    bits = 0
    for i in range(3):
        ex, ey = l1[i] * math.cos(q[i]), l1[i] * math.sin(q[i])          # D - M
        ax = X[0] + c * b[i, 0] - s * b[i, 1] - M[i, 0] - ex              # A - D
        ay = X[1] + s * b[i, 0] + c * b[i, 1] - M[i, 1] - ey
        if ex * ay - ey * ax < 0.0:
            bits |= 1 << i
    return bits
