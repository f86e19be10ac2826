"""Tube certificates: a parametric (affine-in-q) Krawczyk test for a whole box of joints.

For a box of joints ``Q = q~ +- t`` the poses consistent with it form a thin curved needle
along ``S = -J^-1 K``.  An axis-aligned Krawczyk box must hold J regular over the needle's
whole hull; the test here follows the needle instead.  With ``x~`` the solution at ``q~``,
``C ~ J~^-1`` and ``S = -C K~`` it takes the unknown as the deviation ``y`` from the linear
predictor, ``x = x~ + S (q - q~) + y``, and runs Krawczyk's test on
``G(y, q) = F(x~ + S (q - q~) + y, q)`` over ``y`` in ``Y = [-rho, rho]`` for every ``q`` in
``Q`` at once.  The first-order term in the joint error cancels (``J~ S + K~ ~ 0``), and the
Jacobian's spread is evaluated as an affine form in ``(q - q~, y)`` (point matrices
``C A_k``, ``C B_j``) plus a closed-form second-order remainder, so that cancellations are
kept.  (The robot as built: ``F(x, q) = s`` with ``|s_i| <= sigma_i``, :func:`.kinematics.leg_slack`, one
more parameter whose term ``|C| sigma`` joins the constant part; every claim below then holds for each
``(q, s)``.)  When the Krawczyk radius ``kappa < rho``, then for every ``q`` in ``Q`` exactly one
pose lies in the *tube* ``T = {x~ + S (q - q~) + y : |y| <= rho}``, and it satisfies
``|y| <= kappa``: the tube's solution is a continuous function of ``q`` on ``Q``.  ``kappa`` is then
tightened: the solution's ``y`` satisfies ``|y| <= a + M |y|`` (``a`` the Krawczyk image's
constant part, ``M`` its contraction matrix over ``Y``, by the mean value theorem along the
segment from 0 to ``y``), so iterating ``u <- min(u, a + M u)`` from ``kappa`` keeps a bound and
approaches ``(I - M)^-1 a``.

(Kolev's p-solutions ``x(p) in L p + a``; Rump, "Verification methods", Acta Numerica 2010,
sec. 13; Duff and Lee, "Certified homotopy tracking using the Krawczyk method", ISSAC 2024.
The derivation and its bounds: ``docs/noisy-joints-design.md``, section 4.)

A *tube* is a flat pack (``TUBE_*``): the centre pose ``x~``, ``S`` (row-major), the centre
joints ``q~``, ``kappa``, ``rho``, and its joint set: the joints ``q~ + V w``, ``|w| <= tw``, within
``t`` of ``q~`` (:func:`tube_test`: a box, ``V = I``; :func:`slab_test`: a slab across the needle,
``V[:, 0]`` its joint direction, the top right-singular vector of ``S``; design note section 2.4).
Hand-offs between tubes: :mod:`.handoff`.  Chains and covers of tubes over a tracker step, and the
pose bound: :mod:`.tube_chain`.

Floating point: round-to-nearest with a priori slack, as in :mod:`.krawczyk`: residuals
and products of signed terms get an absolute pad (:data:`.krawczyk.PAD` times their scale),
the sums of nonnegative terms a relative ``1e-12``, the final radius ``1e-9`` relative and
``1e-15`` absolute.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import leg_slack
from .krawczyk import PAD, W_SIZE, newton_on_path
from .linalg import identity3, inverse3, wrap
from .scratch import floats, scratch2, scratch3

# tube pack fields
TUBE_X = 0            # (3,) centre pose x~ (m, m, rad)
TUBE_S = 3            # (9,) S = -J~^-1 K~, row-major (m/rad, m/rad, rad/rad)
TUBE_Q = 12           # (3,) centre joints q~ (rad)
TUBE_K = 15           # (3,) kappa: |x - x~ - S (q - q~)| <= kappa for the tube's solution
TUBE_R = 18           # (3,) rho: the tube's half-widths about the linear predictor
TUBE_T = 21           # (3,) half-widths t of the joint box that holds the tube's joint set (rad)
TUBE_W = 24           # (3,) the joint set's half-widths along V's columns (rad)
TUBE_V = 27           # (9,) V (row-major, orthonormal): the joint set is q~ + V w, |w| <= TUBE_W
TUBE_SIZE = 36

#: Epsilon-inflation rounds of one tube test.
ROUNDS = 6
#: Largest rho a tube test grows to (m or rad): beyond it the tube is useless as a bound.
RHO_MAX = 0.05
#: How far (m, m, rad) a computed DK solution may lie outside a tube and still be taken as its solution
#: (its rounding: polished roots are within about 1e-15 of the exact ones, distinct ones farther apart).
MATCH_PAD = 1e-9
#: Relative slack of the final radius and of the hand-off check.
SLACK = 1e-9


@njit(cache=False)
def norm_up(x, y):
    """An upper bound of ``sqrt(x^2 + y^2)``: the rounded formula (within 4.5e-16 relative of it) raised
    by 1e-15 relative.  ``math.hypot`` is 3.5x as slow here (35 against 9.5 ns a call, measured), and a
    tube test makes about 18 of them."""
    return math.sqrt(x * x + y * y) * (1.0 + 1e-15)


@njit(cache=False)
def lin_bound(l0, l1_, l2, V, tw):
    """``max |l . V w|`` over ``|w| <= tw`` (3,): ``sum_n |l . V[:, n]| tw_n``, padded for rounding."""
    out = 0.0
    for n in range(3):
        acc = l0 * V[0, n] + l1_ * V[1, n] + l2 * V[2, n]
        mag = abs(l0 * V[0, n]) + abs(l1_ * V[1, n]) + abs(l2 * V[2, n])
        out += (abs(acc) + PAD * mag) * tw[n]
    return out * (1.0 + 1e-12)


@njit(cache=False)
def lin_bound2(l0, l1_, l2, V, tw, t):
    """``max |l . dq|`` over ``dq = V w``, ``|w| <= tw``, with ``|dq| <= t`` (3,): the smaller bound."""
    box = (abs(l0) * t[0] + abs(l1_) * t[1] + abs(l2) * t[2]) * (1.0 + 1e-12)
    return min(lin_bound(l0, l1_, l2, V, tw), box)


@njit(cache=True)
def tube_test(xg, qc, t, rho_min, M, l1, l2sq, b, tube):
    """The parametric Krawczyk test of the joint box ``qc +- t`` (3,) about the solution near ``xg``.

    ``xg`` (3,): a guess of the solution at ``qc`` (Newton polishes it); ``rho_min`` (3,): the
    smallest tube half-widths wanted (0 for the tightest).  Writes the tube pack ``tube``
    (TUBE_SIZE,) and returns True when proved: for every ``q`` with ``|q - qc| <= t`` exactly
    one solution lies in the tube, within ``kappa`` of ``x~ + S (q - q~)``.  (:func:`slab_test`
    with ``V = I``.)
    """
    eye = scratch2(3, 3, np.float64)
    identity3(eye)
    return slab_test(xg, qc, eye, t, t, rho_min, M, l1, l2sq, b, tube)


@njit(cache=True)
def slab_test(xg, qc, V, tw, tq, rho_min, M, l1, l2sq, b, tube):
    """The parametric Krawczyk test of the joints ``q = qc + V w``, ``|w| <= tw`` (3,), that also lie
    within ``tq`` (3,) of ``qc``: a parallelepiped cut by a box.

    ``V`` (3, 3) orthonormal: a slab across the needle has a small ``tw[0]`` along ``V[:, 0]``, the
    needle's joint direction.  Every linear term in the joint error is bounded over both
    (``min(|L V| tw, |L| t)``), the quadratic remainders over the joint box ``qc +- t``,
    ``t = min(|V| tw, tq)``.  As :func:`tube_test` otherwise; the pack keeps ``V``, ``tw`` and
    ``t`` (TUBE_V, TUBE_W, TUBE_T).  Writes ``x~``, ``S`` and ``q~`` into the pack even when the test
    fails (once Newton converged): a linear predictor.
    """
    t = floats(3)
    for i in range(3):
        t[i] = min((abs(V[i, 0]) * tw[0] + abs(V[i, 1]) * tw[1] + abs(V[i, 2]) * tw[2]) * (1.0 + 1e-15), tq[i])
    w = floats(W_SIZE)
    none = floats(3)
    none[:] = 0.0
    x = floats(3)
    x[:] = xg
    if not newton_on_path(x, qc, none, none, 0.0, M, l1, b, l2sq, w, 8) < 1e-11:
        return False
    c, s = math.cos(x[2]), math.sin(x[2])
    e = scratch2(3, 2, np.float64)
    wv = scratch2(3, 2, np.float64)
    J = scratch2(3, 3, np.float64)
    k = floats(3)
    F = floats(3)
    eu = scratch2(3, 2, np.float64)
    cn = floats(3)
    en = floats(3)
    fscale = floats(3)
    for i in range(3):
        rcx, rcy = c * b[i, 0] - s * b[i, 1], s * b[i, 0] + c * b[i, 1]
        wv[i, 0], wv[i, 1] = -rcy, rcx
        cq, sq = math.cos(qc[i]), math.sin(qc[i])
        eu[i, 0], eu[i, 1] = -sq, cq
        e[i, 0] = x[0] + rcx - M[i, 0] - l1[i] * cq
        e[i, 1] = x[1] + rcy - M[i, 1] - l1[i] * sq
        r2 = qc[i] * qc[i] if l2sq[i] < 0.0 else l2sq[i]
        F[i] = e[i, 0] * e[i, 0] + e[i, 1] * e[i, 1] - r2
        fscale[i] = e[i, 0] * e[i, 0] + e[i, 1] * e[i, 1] + r2 + 1.0
        J[i, 0], J[i, 1] = 2.0 * e[i, 0], 2.0 * e[i, 1]
        J[i, 2] = 2.0 * (e[i, 0] * wv[i, 0] + e[i, 1] * wv[i, 1])
        k[i] = -2.0 * l1[i] * (e[i, 0] * eu[i, 0] + e[i, 1] * eu[i, 1])
        if l2sq[i] < 0.0:
            k[i] -= 2.0 * qc[i]
        cn[i] = norm_up(b[i, 0], b[i, 1])
        en[i] = norm_up(e[i, 0], e[i, 1])
    C = scratch2(3, 3, np.float64)
    if not inverse3(J, C):
        return False
    S = scratch2(3, 3, np.float64)
    for r in range(3):
        for j in range(3):
            S[r, j] = -C[r, j] * k[j]
    tube[TUBE_X:TUBE_X + 3] = x
    tube[TUBE_S:TUBE_S + 9] = S.ravel()
    tube[TUBE_Q:TUBE_Q + 3] = qc
    aC = scratch2(3, 3, np.float64)
    for r in range(3):
        for j in range(3):
            aC[r, j] = abs(C[r, j])
    # |I - C J~| and N = J~ S + K~ with their rounding pads
    M0 = scratch2(3, 3, np.float64)
    sN = scratch2(3, 3, np.float64)
    pN = scratch2(3, 3, np.float64)
    for r in range(3):
        for j in range(3):
            acc, mag = 0.0, 0.0
            for m in range(3):
                acc += C[r, m] * J[m, j]
                mag += abs(C[r, m] * J[m, j])
            M0[r, j] = abs((1.0 if r == j else 0.0) - acc) + PAD * (mag + 1.0)
            acc, mag = 0.0, 0.0
            for m in range(3):
                acc += J[r, m] * S[m, j]
                mag += abs(J[r, m] * S[m, j])
            acc += k[r] if r == j else 0.0
            sN[r, j] = acc
            pN[r, j] = PAD * (mag + abs(k[r]) + 1.0)
    # |N dq| over the joints (the parameter term |C| |N dq| below): over w or over the box
    nd = floats(3)
    for r in range(3):
        byw, byq = 0.0, 0.0
        for j in range(3):
            acc, pad = 0.0, 0.0
            for m in range(3):
                acc += sN[r, m] * V[m, j]
                pad += pN[r, m] * abs(V[m, j])
            byw += (abs(acc) + pad * (1.0 + 1e-12) + PAD * abs(acc)) * tw[j]
            byq += (abs(sN[r, j]) + pN[r, j]) * t[j]
        nd[r] = min(byw, byq) * (1.0 + 1e-12)
    # G_i = H_i S - l1 E u e_i^T (2 x 3 per leg) and gamma_i = e . E w = -(e . R c)
    G = scratch3(3, 2, 3, np.float64)
    gam = floats(3)
    for i in range(3):
        for m in range(3):
            G[i, 0, m] = S[0, m] + wv[i, 0] * S[2, m] - (l1[i] * eu[i, 0] if m == i else 0.0)
            G[i, 1, m] = S[1, m] + wv[i, 1] * S[2, m] - (l1[i] * eu[i, 1] if m == i else 0.0)
        gam[i] = -(e[i, 0] * wv[i, 1] - e[i, 1] * wv[i, 0])
    # the affine parts of C (J - J~): C A_k t_k summed, and C B_j (per j)
    MA = scratch2(3, 3, np.float64)
    MA[:] = 0.0
    A = scratch2(3, 3, np.float64)
    CA = scratch3(3, 3, 3, np.float64)
    for m in range(3):
        for i in range(3):
            A[i, 0] = 2.0 * G[i, 0, m]
            A[i, 1] = 2.0 * G[i, 1, m]
            A[i, 2] = 2.0 * (G[i, 0, m] * wv[i, 0] + G[i, 1, m] * wv[i, 1] + gam[i] * S[2, m])
        for r in range(3):
            for j in range(3):
                CA[m, r, j] = C[r, 0] * A[0, j] + C[r, 1] * A[1, j] + C[r, 2] * A[2, j]
    for r in range(3):                       # over w (sum_m C A_m V_mn w_n) or over the box
        for j in range(3):
            byw, byq = 0.0, 0.0
            for n in range(3):
                acc = CA[0, r, j] * V[0, n] + CA[1, r, j] * V[1, n] + CA[2, r, j] * V[2, n]
                mag = abs(CA[0, r, j] * V[0, n]) + abs(CA[1, r, j] * V[1, n]) + abs(CA[2, r, j] * V[2, n])
                byw += (abs(acc) + PAD * mag) * tw[n]
                byq += abs(CA[n, r, j]) * (1.0 + PAD) * t[n]
            MA[r, j] = min(byw, byq)
    CB = scratch3(3, 3, 3, np.float64)
    for m in range(3):
        for i in range(3):
            hx = 1.0 if m == 0 else (0.0 if m == 1 else wv[i, 0])
            hy = 1.0 if m == 1 else (0.0 if m == 0 else wv[i, 1])
            A[i, 0] = 2.0 * hx
            A[i, 1] = 2.0 * hy
            A[i, 2] = 2.0 * (hx * wv[i, 0] + hy * wv[i, 1] + (gam[i] if m == 2 else 0.0))
        for r in range(3):
            for j in range(3):
                CB[m, r, j] = abs(C[r, 0] * A[0, j] + C[r, 1] * A[1, j] + C[r, 2] * A[2, j])
    # the parameter term: |C F~| + |C| beta + |C N| t
    phi0 = lin_bound2(S[2, 0], S[2, 1], S[2, 2], V, tw, t)
    gt = scratch2(3, 2, np.float64)
    beta = floats(3)
    for i in range(3):
        for r in range(2):
            gt[i, r] = lin_bound2(G[i, r, 0], G[i, r, 1], G[i, r, 2], V, tw, t)
        r0 = cn[i] * phi0 * phi0 / 2.0 + l1[i] * t[i] * t[i] / 2.0 + PAD * phi0
        beta[i] = 2.0 * en[i] * r0 + (norm_up(gt[i, 0], gt[i, 1]) + r0) ** 2 + PAD * fscale[i]
        if l2sq[i] < 0.0:
            beta[i] += t[i] * t[i]
        beta[i] += leg_slack(l2sq, i)          # the robot as built: F_i within sigma_i of 0 at its pose
    a = floats(3)
    for r in range(3):
        acc = abs(C[r, 0] * F[0] + C[r, 1] * F[1] + C[r, 2] * F[2])
        for j in range(3):
            acc += aC[r, j] * (beta[j] + nd[j])
        a[r] = acc * (1.0 + 1e-12)
    rho = floats(3)
    for r in range(3):
        rho[r] = max(rho_min[r], 2.0 * a[r] + 1e-15)
    kap = floats(3)
    Mt = scratch2(3, 3, np.float64)
    rem = scratch2(3, 3, np.float64)
    last = np.inf
    for _ in range(ROUNDS):
        phi = phi0 + rho[2]
        for i in range(3):
            ri = cn[i] * phi * phi / 2.0 + l1[i] * t[i] * t[i] / 2.0 + PAD * phi
            hx = rho[0] + abs(wv[i, 0]) * rho[2]
            hy = rho[1] + abs(wv[i, 1]) * rho[2]
            d = norm_up(gt[i, 0] + hx, gt[i, 1] + hy) + ri
            rem[i, 0] = 2.0 * ri
            rem[i, 1] = 2.0 * ri
            rem[i, 2] = 2.0 * (ri * cn[i] + d * cn[i] * phi + en[i] * cn[i] * phi * phi / 2.0)
        grow = False
        worst = 0.0
        for r in range(3):
            row = 0.0
            for j in range(3):
                v = M0[r, j] + MA[r, j] + CB[0, r, j] * rho[0] + CB[1, r, j] * rho[1] + CB[2, r, j] * rho[2]
                v += aC[r, 0] * rem[0, j] + aC[r, 1] * rem[1, j] + aC[r, 2] * rem[2, j]
                Mt[r, j] = v * (1.0 + 1e-12)
                row += Mt[r, j]
            worst = max(worst, row)
            kap[r] = (a[r] + Mt[r, 0] * rho[0] + Mt[r, 1] * rho[1] + Mt[r, 2] * rho[2]) * (1.0 + SLACK) + 1e-15
            grow = grow or not kap[r] < rho[r]
        if not grow:
            # the solution's deviation u = |y| obeys u <= a + M u (mean value along 0..y inside Y):
            # iterate from kappa down towards (I - M)^-1 a
            for _ in range(40):
                change = 0.0
                for r in range(3):
                    v = (a[r] + Mt[r, 0] * kap[0] + Mt[r, 1] * kap[1] + Mt[r, 2] * kap[2]) * (1.0 + SLACK) + 1e-15
                    if v < kap[r]:
                        change = max(change, 1.0 - v / kap[r])
                        kap[r] = v
                if change < 1e-3:
                    break
            tube[TUBE_X:TUBE_X + 3] = x
            tube[TUBE_S:TUBE_S + 9] = S.ravel()
            tube[TUBE_Q:TUBE_Q + 3] = qc
            tube[TUBE_K:TUBE_K + 3] = kap
            tube[TUBE_R:TUBE_R + 3] = rho
            tube[TUBE_T:TUBE_T + 3] = t
            tube[TUBE_W:TUBE_W + 3] = tw
            tube[TUBE_V:TUBE_V + 9] = V.ravel()
            return True
        if worst >= 1.0:
            return False
        size = max(kap[0] / max(rho[0], 1e-300), max(kap[1] / max(rho[1], 1e-300), kap[2] / max(rho[2], 1e-300)))
        if size > last * 1.5:
            return False
        last = size
        for r in range(3):
            rho[r] = max(rho[r], 1.2 * kap[r] + 1e-15)
            if rho[r] > RHO_MAX:
                return False
    return False


@njit(cache=False)
def spread(tube, r, t):
    """How far coordinate ``r`` of the tube's linear predictor moves over joints within ``t`` (rad) of its
    centre: ``sum_m |S_rm| t`` (m, or rad for r = 2).  The needle's hull is ``spread + kappa``."""
    return (abs(tube[TUBE_S + 3 * r]) + abs(tube[TUBE_S + 3 * r + 1]) + abs(tube[TUBE_S + 3 * r + 2])) * t


@njit(cache=False)
def set_spread(tube, r):
    """How far coordinate ``r`` of the tube's linear predictor moves over the tube's own joint set (m, or
    rad for r = 2): :func:`lin_bound2` of row ``r`` of ``S`` over ``V``, ``tw`` and ``t``."""
    V = tube[TUBE_V:TUBE_V + 9].reshape((3, 3))
    return lin_bound2(tube[TUBE_S + 3 * r], tube[TUBE_S + 3 * r + 1], tube[TUBE_S + 3 * r + 2], V,
                      tube[TUBE_W:TUBE_W + 3], tube[TUBE_T:TUBE_T + 3])


@njit(cache=True)
def predictor(tube, q, out):
    """The tube's linear predictor ``x~ + S (q - q~)`` at joints ``q`` (3,) into ``out`` (3,)."""
    for r in range(3):
        acc = tube[TUBE_X + r]
        for m in range(3):
            acc += tube[TUBE_S + 3 * r + m] * wrap(q[m] - tube[TUBE_Q + m])
        out[r] = acc
