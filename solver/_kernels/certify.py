"""The tracker's certificates, compiled: Krawczyk-verified continuation of DK branches.

Path model.  Between two samples the joints are taken to move along
``q(s) = q0 + s d1 + s^2 d2``, ``s`` in [0, 1]: the straight segment
(``d1 = dq``, ``d2 = 0``) or, where the segment meets a singularity, the
parabola through the last three samples (time-scaled).

:func:`krawczyk` proves, for a box ``B = m +- rho`` of poses and an interval
``S`` of ``s``, that for every ``s`` in ``S`` the constraints
``F(X, q(s)) = 0`` have exactly one solution in ``B`` (J regular on B).  It is
Krawczyk's operator in centred form,
``K = m - Y F(m, s_c) - Y g(m, S) (S - s_c) + (I - Y J(B, S)) (B - m)``
with ``Y = J(m, s_c)^-1`` and ``g = dF/ds = K dq/ds``; ``K`` inside ``B`` is the proof.
:func:`follow_branch` chains boxes from ``s = 0`` to ``s = 1``; two consecutive
boxes share a tiny box (half-width :data:`TINY`) around the solution at their
common ``s``, itself proved to hold exactly one solution, so the chain proves
that the branch through the start pose ends in the last tiny box.

:func:`certify` turns chains into the tracker's candidate set: the DK solutions
that the true branch can be.  One candidate: a forward chain from it names its
continuation.  Otherwise each real solution of the new joints is followed
backwards; one that provably comes from a non-candidate is dropped.  Finally,
if several remain and the tracker knows its posture, those of another posture are
dropped.  The answer is vouched for when one candidate remains.

Floating point: the interval arithmetic here rounds to nearest, not outward.
Every interval end and every point evaluation is padded by :data:`PAD` (1e-14
for quantities of order 1, over 100 times the rounding error of the few
operations that produce them) and the final comparison by a relative 1e-12.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import geometry
from .linalg import wrap

#: Absolute pad of every interval end and point evaluation.
PAD = 1e-14
#: Half-width of the tiny verified boxes that link a chain (m, m, rad).
TINY = 1e-9
#: Epsilon-inflation rounds of one box before its interval of s is halved.
INFLATE = 3
#: Largest half-width a box is inflated to (m or rad).
RHO_CAP = 0.05
#: Two poses are the same solution when they differ by less than this (m, m, rad).
MATCH = 1e-7
TWO_PI = 2.0 * math.pi

#: Certificates (the tracker's ``certificate`` output).
CERT_NONE, CERT_CONTINUATION, CERT_ELIMINATION, CERT_POSTURE = 0, 1, 2, 3

# workspace of a chain (floats): point F, J, g; Y; interval J lo/hi; interval g lo/hi; K half-widths
W_F, W_J, W_G, W_Y, W_JLO, W_JHI, W_GLO, W_GHI, W_TOT, W_FQ = 0, 3, 12, 15, 24, 33, 42, 45, 48, 51
W_SIZE = 54


@njit(cache=True, inline="always")
def _mul(alo, ahi, blo, bhi):
    p1, p2, p3, p4 = alo * blo, alo * bhi, ahi * blo, ahi * bhi
    return min(min(p1, p2), min(p3, p4)), max(max(p1, p2), max(p3, p4))


@njit(cache=True, inline="always")
def _smul(k, lo, hi):
    if k >= 0.0:
        return k * lo, k * hi
    return k * hi, k * lo


@njit(cache=True)
def icos(lo, hi):
    """An enclosure of cos over [lo, hi]."""
    if hi - lo >= TWO_PI:
        return -1.0, 1.0
    a, b = math.cos(lo), math.cos(hi)
    clo, chi = min(a, b), max(a, b)
    if TWO_PI * math.ceil(lo / TWO_PI) <= hi:                       # a maximum 2 k pi inside
        chi = 1.0
    if TWO_PI * math.ceil((lo - math.pi) / TWO_PI) + math.pi <= hi:  # a minimum (2 k + 1) pi inside
        clo = -1.0
    return clo - PAD, chi + PAD


@njit(cache=True)
def isin(lo, hi):
    """An enclosure of sin over [lo, hi]."""
    return icos(lo - 0.5 * math.pi, hi - 0.5 * math.pi)


@njit(cache=True, inline="always")
def _path(q0, d1, d2, i, s):
    return q0[i] + s * (d1[i] + s * d2[i])


@njit(cache=True)
def point_terms(x, y, phi, q0, d1, d2, s, M, l1, b, l2sq, w):
    """F (w[W_F:]), J = dF/dX (w[W_J:], row-major) and g = dF/ds (w[W_G:]) at pose (x, y, phi), q(s)."""
    c, sn = math.cos(phi), math.sin(phi)
    for i in range(3):
        rbx = c * b[i, 0] - sn * b[i, 1]
        rby = sn * b[i, 0] + c * b[i, 1]
        qi = _path(q0, d1, d2, i, s)
        cq, sq = math.cos(qi), math.sin(qi)
        lx = x + rbx - M[i, 0] - l1[i] * cq
        ly = y + rby - M[i, 1] - l1[i] * sq
        w[W_F + i] = lx * lx + ly * ly - l2sq[i]
        w[W_J + 3 * i] = 2.0 * lx
        w[W_J + 3 * i + 1] = 2.0 * ly
        w[W_J + 3 * i + 2] = 2.0 * (ly * rbx - lx * rby)
        w[W_G + i] = 2.0 * l1[i] * (lx * sq - ly * cq) * (d1[i] + 2.0 * s * d2[i])


@njit(cache=True)
def inverse3(w, src, dst):
    """w[dst:dst+9] = inverse of the 3x3 matrix w[src:src+9] (row-major); False if singular."""
    a, b_, c = w[src], w[src + 1], w[src + 2]
    d, e, f = w[src + 3], w[src + 4], w[src + 5]
    g, h, k = w[src + 6], w[src + 7], w[src + 8]
    A, B, C = e * k - f * h, f * g - d * k, d * h - e * g
    det = a * A + b_ * B + c * C
    if det == 0.0 or not math.isfinite(det):
        return False
    r = 1.0 / det
    w[dst], w[dst + 1], w[dst + 2] = A * r, (c * h - b_ * k) * r, (b_ * f - c * e) * r
    w[dst + 3], w[dst + 4], w[dst + 5] = B * r, (a * k - c * g) * r, (c * d - a * f) * r
    w[dst + 6], w[dst + 7], w[dst + 8] = C * r, (b_ * g - a * h) * r, (a * e - b_ * d) * r
    return True


@njit(cache=True)
def krawczyk(m, rho, q0, d1, d2, s_lo, s_hi, eps, M, l1, b, l2sq, w):
    """Krawczyk's test of the box ``m +- rho`` (3,) for every ``s`` in [s_lo, s_hi].

    True when the box holds exactly one solution of ``F(., q) = 0`` for each
    joint vector ``q`` within ``eps`` (rad, max norm) of ``q(s)``, ``s`` in
    [s_lo, s_hi] (``eps = 0``: the path itself).  Leaves the half-widths of the Krawczyk image about ``m`` in
    ``w[W_TOT:W_TOT + 3]`` (what epsilon-inflation grows the box to).
    """
    s_c = 0.5 * (s_lo + s_hi)
    hs = 0.5 * (s_hi - s_lo)
    point_terms(m[0], m[1], m[2], q0, d1, d2, s_c, M, l1, b, l2sq, w)
    if not inverse3(w, W_J, W_Y):
        return False
    clo, chi = icos(m[2] - rho[2], m[2] + rho[2])
    slo, shi = isin(m[2] - rho[2], m[2] + rho[2])
    cm, sm = math.cos(m[2]), math.sin(m[2])
    for i in range(3):
        # q_i and dq_i/ds over [s_lo, s_hi]
        qa, qb = _path(q0, d1, d2, i, s_lo), _path(q0, d1, d2, i, s_hi)
        qlo, qhi = min(qa, qb), max(qa, qb)
        if d2[i] != 0.0:
            sv = -d1[i] / (2.0 * d2[i])
            if s_lo < sv < s_hi:
                qx = _path(q0, d1, d2, i, sv)
                qlo, qhi = min(qlo, qx), max(qhi, qx)
        va, vb = d1[i] + 2.0 * s_lo * d2[i], d1[i] + 2.0 * s_hi * d2[i]
        vlo, vhi = min(va, vb) - PAD, max(va, vb) + PAD
        cqlo, cqhi = icos(qlo - eps - PAD, qhi + eps + PAD)
        sqlo, sqhi = isin(qlo - eps - PAD, qhi + eps + PAD)
        bx, by = b[i, 0], b[i, 1]
        a1lo, a1hi = _smul(bx, clo, chi)
        a2lo, a2hi = _smul(-by, slo, shi)
        rxlo, rxhi = a1lo + a2lo - PAD, a1hi + a2hi + PAD               # R(phi) b, x
        a1lo, a1hi = _smul(bx, slo, shi)
        a2lo, a2hi = _smul(by, clo, chi)
        rylo, ryhi = a1lo + a2lo - PAD, a1hi + a2hi + PAD               # R(phi) b, y
        t1lo, t1hi = _smul(-l1[i], cqlo, cqhi)
        t2lo, t2hi = _smul(-l1[i], sqlo, sqhi)
        lxlo = m[0] - rho[0] + rxlo - M[i, 0] + t1lo - PAD
        lxhi = m[0] + rho[0] + rxhi - M[i, 0] + t1hi + PAD
        lylo = m[1] - rho[1] + rylo - M[i, 1] + t2lo - PAD
        lyhi = m[1] + rho[1] + ryhi - M[i, 1] + t2hi + PAD
        w[W_JLO + 3 * i], w[W_JHI + 3 * i] = 2.0 * lxlo, 2.0 * lxhi
        w[W_JLO + 3 * i + 1], w[W_JHI + 3 * i + 1] = 2.0 * lylo, 2.0 * lyhi
        p1lo, p1hi = _mul(lylo, lyhi, rxlo, rxhi)
        p2lo, p2hi = _mul(lxlo, lxhi, rylo, ryhi)
        w[W_JLO + 3 * i + 2], w[W_JHI + 3 * i + 2] = 2.0 * (p1lo - p2hi) - PAD, 2.0 * (p1hi - p2lo) + PAD
        # g_i over S at the point m: 2 l1 (lx sin q - ly cos q) dq_i/ds
        rbx, rby = cm * bx - sm * by, sm * bx + cm * by
        mxlo, mxhi = m[0] + rbx - M[i, 0] + t1lo - PAD, m[0] + rbx - M[i, 0] + t1hi + PAD
        mylo, myhi = m[1] + rby - M[i, 1] + t2lo - PAD, m[1] + rby - M[i, 1] + t2hi + PAD
        u1lo, u1hi = _mul(mxlo, mxhi, sqlo, sqhi)
        u2lo, u2hi = _mul(mylo, myhi, cqlo, cqhi)
        k2 = 2.0 * l1[i]
        fqlo, fqhi = k2 * (u1lo - u2hi) - PAD, k2 * (u1hi - u2lo) + PAD        # dF_i/dq_i at m
        w[W_GLO + i], w[W_GHI + i] = _mul(fqlo, fqhi, vlo, vhi)
        w[W_FQ + i] = max(abs(fqlo), abs(fqhi)) * eps
    ok = True
    for r in range(3):
        yf = 0.0
        ypad = 0.0
        glo = 0.0
        ghi = 0.0
        for j in range(3):
            y = w[W_Y + 3 * r + j]
            yf += y * w[W_F + j]
            ypad += abs(y)
            a, c2 = _smul(y, w[W_GLO + j], w[W_GHI + j])
            glo += a
            ghi += c2
        t = abs(yf) + ypad * PAD + hs * max(abs(glo), abs(ghi))
        for j in range(3):                            # the joints' own box: |Y| |dF/dq| eps
            t += abs(w[W_Y + 3 * r + j]) * w[W_FQ + j]
        for j in range(3):
            lo = 1.0 if r == j else 0.0
            hi = lo
            for k in range(3):
                a, c2 = _smul(w[W_Y + 3 * r + k], w[W_JLO + 3 * k + j], w[W_JHI + 3 * k + j])
                lo -= c2
                hi -= a
            t += max(abs(lo), abs(hi)) * rho[j]
        w[W_TOT + r] = t * (1.0 + 1e-12)
        ok = ok and w[W_TOT + r] < rho[r]
    return ok


@njit(cache=True)
def newton_on_path(X, q0, d1, d2, s, M, l1, b, l2sq, w, iters):
    """Newton on F(., q(s)) = 0 from X (in place); the last correction's max norm (inf if singular)."""
    last = np.inf
    for _ in range(iters):
        point_terms(X[0], X[1], X[2], q0, d1, d2, s, M, l1, b, l2sq, w)
        if not inverse3(w, W_J, W_Y):
            return np.inf
        last = 0.0
        for r in range(3):
            d = w[W_Y + 3 * r] * w[W_F] + w[W_Y + 3 * r + 1] * w[W_F + 1] + w[W_Y + 3 * r + 2] * w[W_F + 2]
            X[r] -= d
            last = max(last, abs(d))
        if last < 1e-14:
            break
    return last


@njit(cache=True)
def follow_branch(X0, verified, q0, d1, d2, eps, M, l1, b, l2sq, max_tests, out):
    """Follow the branch through ``X0`` at ``q(0)`` to ``s = 1`` with a chain of Krawczyk boxes.

    ``verified``: ``X0`` is already known to be within TINY of the only solution
    in its tiny box (the end of a previous chain), so the first test is skipped.
    Returns the number of tests used (> 0) and the end pose in ``out`` (3,) on
    success: the branch at ``q(1)`` is the one solution within TINY of ``out``.
    Returns ``-tests`` when the chain could not be closed within ``max_tests``.
    """
    w = np.empty(W_SIZE)
    tiny = np.full(3, TINY)
    x = X0.copy()
    tests = 0
    dq_max = 0.0
    for i in range(3):
        dq_max = max(dq_max, abs(d1[i]))
    if not verified:
        tests = 1
        if not krawczyk(x, tiny, q0, d1, d2, 0.0, 0.0, 0.0, M, l1, b, l2sq, w):
            return -1
    s, h = 0.0, 1.0
    xb, c, rho = np.empty(3), np.empty(3), np.empty(3)
    while s < 1.0:
        if tests >= max_tests:
            return -tests
        sb = min(1.0, s + h)
        if eps > 0.0 and s > 0.0 and sb < 1.0 and (sb - s) * dq_max <= 2.0 * eps * (1.0 + 1e-9):
            return -max(tests, 1)                     # an inner piece shorter than the tube's width
        # predictor: Euler along dX/ds = -J^-1 g, then Newton at q(sb)
        point_terms(x[0], x[1], x[2], q0, d1, d2, s, M, l1, b, l2sq, w)
        if not inverse3(w, W_J, W_Y):
            return -max(tests, 1)
        for r in range(3):
            xb[r] = x[r] - (sb - s) * (w[W_Y + 3 * r] * w[W_G] + w[W_Y + 3 * r + 1] * w[W_G + 1]
                                       + w[W_Y + 3 * r + 2] * w[W_G + 2])
        ok = newton_on_path(xb, q0, d1, d2, sb, M, l1, b, l2sq, w, 6) < 1e-12
        tests += 1
        if ok:
            dmax = 0.0
            for i in range(3):
                dmax = max(dmax, abs(xb[i] - x[i]))
            for i in range(3):
                c[i] = 0.5 * (x[i] + xb[i])
                rho[i] = 0.5 * abs(xb[i] - x[i]) + 0.25 * dmax + 2.0 * TINY
            ok = False
            for _ in range(INFLATE):                  # epsilon-inflation towards the Krawczyk image
                tests += 1
                if krawczyk(c, rho, q0, d1, d2, s, sb, eps, M, l1, b, l2sq, w):
                    ok = True
                    break
                grow = True
                for i in range(3):
                    r_new = 1.25 * w[W_TOT + i] + 2.0 * TINY
                    grow = grow and r_new < RHO_CAP
                    rho[i] = max(rho[i], r_new)
                if not grow:
                    break
            if ok:
                tests += 1
                ok = krawczyk(xb, tiny, q0, d1, d2, sb, sb, 0.0, M, l1, b, l2sq, w)
        if ok:
            s = sb
            x[:] = xb
            h = min(2.0 * h, 1.0)
        else:
            h *= 0.5
    out[:] = x
    return tests


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


@njit(cache=True)
def certify(cands, n_cand, verified, intact, qp, dq, d2_par, have_par, eps, poses, real, posture_bits, max_tests,
            model_pack, new_cands, keep):
    """The candidate set after one step (see the module docstring).

    cands (6, 3): the candidates at ``qp`` (``n_cand`` of them; ``verified``: the
    single one is the end of a chain).  dq (3,): the wrapped joint step;
    d2_par (3,): the parabola's quadratic term (used when ``have_par``).
    poses (6, 3) complex / real (6,): the DK solutions at ``qp + dq``.
    posture_bits: the tracker's posture - 1, or -1 for no posture certificate.
    Writes the new candidates to ``new_cands`` (6, 3) (verified chain ends when
    one remains by continuation) and, in ``keep`` (6,), which solutions they are.
    Returns (number of candidates, certificate code).
    """
    M, l1, l2sq, b = geometry(model_pack)
    zero = np.zeros(3)
    d1_par = np.empty(3)
    qu = np.empty(3)
    for i in range(3):
        d1_par[i] = dq[i] - d2_par[i]
        qu[i] = qp[i] + dq[i]
    end = np.empty(3)
    Xr = np.empty(3)
    n_paths = 2 if have_par else 1
    for k in range(6):
        keep[k] = False
    if n_cand == 1:
        # with measured joints (eps > 0), first the tube: the proof that keeps the chain intact
        first = 0 if eps > 0.0 and intact else 1
        for p in range(first, n_paths + 1):
            d1 = dq if p <= 1 else d1_par
            d2 = zero if p <= 1 else d2_par
            if follow_branch(cands[0], verified, qp, d1, d2, eps if p == 0 else 0.0, M, l1, b, l2sq, max_tests,
                             end) > 0:
                hit = -1
                for k in range(6):
                    if real[k]:
                        for i in range(3):
                            Xr[i] = poses[k, i].real
                        if same_pose(Xr, end):
                            hit = k if hit < 0 else 6          # 6: two solutions match (cannot tell)
                if 0 <= hit < 6:
                    keep[hit] = True
                    new_cands[0, :] = end
                    return 1, CERT_CONTINUATION, eps == 0.0 or p == 0
    # elimination: follow every real solution back; drop those that come from a non-candidate
    rd1 = np.empty(3)
    rd2 = np.empty(3)
    n_new = 0
    for k in range(6):
        if not real[k]:
            continue
        for i in range(3):
            Xr[i] = poses[k, i].real
        kept = True
        for p in range(n_paths):
            # the same path backwards: q(1 - u) = q(1) + u rd1 + u^2 rd2
            for i in range(3):
                d1i = dq[i] if p == 0 else d1_par[i]
                d2i = 0.0 if p == 0 else d2_par[i]
                rd1[i] = -(d1i + 2.0 * d2i)
                rd2[i] = d2i
            if follow_branch(Xr, False, qu, rd1, rd2, 0.0, M, l1, b, l2sq, max_tests, end) > 0:
                kept = False
                for j in range(n_cand):
                    kept = kept or same_pose(end, cands[j])
                break
        if kept:
            keep[k] = True
            new_cands[n_new, :] = Xr
            n_new += 1
    code = CERT_ELIMINATION
    if n_new > 1 and posture_bits >= 0:
        in_posture = np.zeros(6, dtype=np.bool_)      # kept candidates in the tracker's posture
        n_post = 0
        for k in range(6):
            if keep[k]:
                for i in range(3):
                    Xr[i] = poses[k, i].real
                in_posture[k] = elbow_bits(Xr, qu, M, l1, b) == posture_bits
                n_post += in_posture[k]
        if n_post >= 1:
            n_new = 0
            for k in range(6):
                keep[k] = in_posture[k]
                if keep[k]:
                    for i in range(3):
                        new_cands[n_new, i] = poses[k, i].real
                    n_new += 1
            code = CERT_POSTURE
    if n_new == 0:                                  # nothing consistent (cannot happen in exact arithmetic)
        for k in range(6):
            if real[k]:
                keep[k] = True
                for i in range(3):
                    new_cands[n_new, i] = poses[k, i].real
                n_new += 1
    return n_new, code if n_new == 1 else CERT_NONE, eps == 0.0
