"""Krawczyk's test for the loop constraints (circle legs: 3-RRR and 3-RPR) over a box of poses and a piece
of joint path.

Path model.  Between two samples the joints are taken to move along
``q(s) = q0 + s d1 + s^2 d2``, ``s`` in [0, 1]: the straight segment
(``d1 = dq``, ``d2 = 0``) or the parabola through the last three samples;
with measured joints, every joint vector within ``eps_i`` of it (a tube).

:func:`krawczyk` proves, for a box ``B = m +- rho`` of poses and an interval
``S`` of ``s``, that for every joint vector of the tube over ``S`` the
constraints ``F(X, q) = 0`` have exactly one solution in ``B`` (J regular on
B).  It is Krawczyk's operator in centred form,
``K = m - Y F(m, s_c) - Y g(m, S) (S - s_c) - Y F_q(m, Q) e + (I - Y J(B, Q)) (B - m)``
with ``Y = J(m, s_c)^-1``, ``g = dF/ds = F_q dq/ds`` and ``e`` the tube's offset;
``K`` inside ``B`` is the proof.  For the robot as built the constraints are ``F(X, q) = s`` for some
``|s_i| <= sigma_i`` (:func:`.kinematics.leg_slack`): one more term, ``|Y| sigma``, and the proof holds
for every such ``s``.

Floating point: the interval arithmetic here rounds to nearest, not outward.
Every interval end and every point evaluation is padded by :data:`PAD` (1e-14
for quantities of order 1, over 100 times the rounding error of the few
operations that produce them) and the final comparison by a relative 1e-12.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import leg_slack, radius_sq, radius_sq_dq
from .linalg import inverse3_flat as inverse3

#: Absolute pad of every interval end and point evaluation.
PAD = 1e-14
TWO_PI = 2.0 * math.pi

# workspace of a test (floats): point F, J, g; Y; interval J lo/hi; interval g lo/hi; K half-widths; |dF/dq| eps
W_F, W_J, W_G, W_Y, W_JLO, W_JHI, W_GLO, W_GHI, W_TOT, W_FQ = 0, 3, 12, 15, 24, 33, 42, 45, 48, 51
W_SIZE = 54


@njit(cache=False)
def _mul(alo, ahi, blo, bhi):
    p1, p2, p3, p4 = alo * blo, alo * bhi, ahi * blo, ahi * bhi
    return min(min(p1, p2), min(p3, p4)), max(max(p1, p2), max(p3, p4))


@njit(cache=False)
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


@njit(cache=False)
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
        w[W_F + i] = lx * lx + ly * ly - radius_sq(l2sq[i], qi)
        w[W_J + 3 * i] = 2.0 * lx
        w[W_J + 3 * i + 1] = 2.0 * ly
        w[W_J + 3 * i + 2] = 2.0 * (ly * rbx - lx * rby)
        w[W_G + i] = (2.0 * l1[i] * (lx * sq - ly * cq) - radius_sq_dq(l2sq[i], qi)) * (d1[i] + 2.0 * s * d2[i])


@njit(cache=True)
def krawczyk(m, rho, q0, d1, d2, s_lo, s_hi, eps, M, l1, b, l2sq, w):
    """Krawczyk's test of the box ``m +- rho`` (3,) for every ``s`` in [s_lo, s_hi].

    True when the box holds exactly one solution of ``F(., q) = 0`` for each
    joint vector ``q`` with ``|q_i - q_i(s)| <= eps_i`` (``eps`` (3,), rad),
    ``s`` in [s_lo, s_hi] (``eps = 0``: the path itself).  Leaves the half-widths of the Krawczyk image about ``m`` in
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
        qlo, qhi, vlo, vhi = _joint_range(q0, d1, d2, i, s_lo, s_hi)
        cqlo, cqhi = icos(qlo - eps[i] - PAD, qhi + eps[i] + PAD)
        sqlo, sqhi = isin(qlo - eps[i] - PAD, qhi + eps[i] + PAD)
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
        if l2sq[i] < 0.0:                            # a prismatic leg: dF_i/dq_i = -2 q_i over the tube
            fqlo, fqhi = fqlo - 2.0 * (qhi + eps[i]) - PAD, fqhi - 2.0 * (qlo - eps[i]) + PAD
        w[W_GLO + i], w[W_GHI + i] = _mul(fqlo, fqhi, vlo, vhi)
        w[W_FQ + i] = max(abs(fqlo), abs(fqhi)) * eps[i] + leg_slack(l2sq, i)   # (+ the as-built slack)
    return _image_inside(w, rho, hs)


@njit(cache=False)
def _joint_range(q0, d1, d2, i, s_lo, s_hi):
    """Joint ``i``'s range (qlo, qhi) over s in [s_lo, s_hi] and that of its speed dq_i/ds (vlo, vhi,
    padded)."""
    qa, qb = _path(q0, d1, d2, i, s_lo), _path(q0, d1, d2, i, s_hi)
    qlo, qhi = min(qa, qb), max(qa, qb)
    if d2[i] != 0.0:
        sv = -d1[i] / (2.0 * d2[i])
        if s_lo < sv < s_hi:
            qx = _path(q0, d1, d2, i, sv)
            qlo, qhi = min(qlo, qx), max(qhi, qx)
    va, vb = d1[i] + 2.0 * s_lo * d2[i], d1[i] + 2.0 * s_hi * d2[i]
    return qlo, qhi, min(va, vb) - PAD, max(va, vb) + PAD


@njit(cache=False)
def _image_inside(w, rho, hs):
    """The half-widths of the Krawczyk image about the centre into ``w[W_TOT:W_TOT + 3]`` from the
    terms :func:`krawczyk` left in ``w`` (the interval of s has half-width ``hs``); True when
    they are inside ``rho`` (3,)."""
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
        for j in range(3):                            # the joints' own box |Y| |dF/dq| eps, and |Y| sigma
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


