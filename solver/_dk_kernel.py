"""Compiled kernel of :func:`solver.kinematics.dk_all` (one joint vector at a time).

The derivation is in :mod:`solver.kinematics`.  Every step there is done here
for one joint vector with scalar arithmetic; ``dk_batch`` runs the kernel over
a batch (in parallel threads for large batches), and a single call is a batch
of one, so both go through the same code.  numba compiles on first use and
caches the machine code next to this file.

Why compiled: a numpy version of the same algorithm spends ~400 array
operations per call; that is ~500 us for one joint vector and ~70,000 sets/s
in batches on this machine, while the tracker and the FMUs call the direct
kinematics once per step (and four times per Runge-Kutta step).
"""
from __future__ import annotations

import cmath
import math

import numpy as np
from numba import njit, prange

EPS = 2.220446049250313e-16
#: A polished real root may not move phi further than this from the sextic's root (rad).
PHI_DRIFT = 1e-5
#: Two real solutions closer than this (sum of |dx|, |dy|, |dphi|) are the same solution twice.
DUPLICATE = 1e-7
#: Below this Hadamard ratio of J a repeated solution is a genuine double root.
HADAMARD_SINGULAR = 1e-6
RULE_REAL_PHI = 0
RULE_LITERAL = 1
RULE_REAL_X = 2
RULE_REAL_Y = 3
RULE_ASPECT = 4


@njit(cache=True, inline="always")
def _elim(c, s, D, b, l2sq):
    """Elimination step 1 at cos/sin ``c, s`` (real or complex)."""
    ux0 = c * b[0, 0] - s * b[0, 1] - D[0, 0]
    uy0 = s * b[0, 0] + c * b[0, 1] - D[0, 1]
    ux1 = c * b[1, 0] - s * b[1, 1] - D[1, 0]
    uy1 = s * b[1, 0] + c * b[1, 1] - D[1, 1]
    ux2 = c * b[2, 0] - s * b[2, 1] - D[2, 0]
    uy2 = s * b[2, 0] + c * b[2, 1] - D[2, 1]
    k0 = ux0 * ux0 + uy0 * uy0 - l2sq[0]
    k1 = ux1 * ux1 + uy1 * uy1 - l2sq[1]
    k2 = ux2 * ux2 + uy2 * uy2 - l2sq[2]
    r2x, r2y, r3x, r3y = ux1 - ux0, uy1 - uy0, ux2 - ux0, uy2 - uy0
    h2, h3 = -0.5 * (k1 - k0), -0.5 * (k2 - k0)
    delta = r2x * r3y - r2y * r3x
    nx = h2 * r3y - h3 * r2y
    ny = r2x * h3 - r3x * h2
    return delta, nx, ny, ux0, uy0, k0, r2x, r2y, r3x, r3y, h2, h3


@njit(cache=True)
def _residual_step(x, y, phi, D, b, l2sq):
    """max|F_i|, the Newton step (dx, dy, dphi) on F(X) = 0 at a real pose, whether the
    step is finite, and the Hadamard ratio |det J| / prod |rows of J| (0 when singular)."""
    c, s = math.cos(phi), math.sin(phi)
    Lx = np.empty(3)
    Ly = np.empty(3)
    J3 = np.empty(3)
    g = np.empty(3)
    res = 0.0
    for i in range(3):
        rbx = c * b[i, 0] - s * b[i, 1]
        rby = s * b[i, 0] + c * b[i, 1]
        lx = x + rbx - D[i, 0]
        ly = y + rby - D[i, 1]
        F = lx * lx + ly * ly - l2sq[i]
        res = max(res, abs(F))
        Lx[i], Ly[i], J3[i], g[i] = lx, ly, ly * rbx - lx * rby, -0.5 * F
    # (J / 2) dX = -F / 2 by Cramer's rule
    det = (Lx[0] * (Ly[1] * J3[2] - J3[1] * Ly[2]) - Ly[0] * (Lx[1] * J3[2] - J3[1] * Lx[2])
           + J3[0] * (Lx[1] * Ly[2] - Ly[1] * Lx[2]))
    had = abs(det) / max(math.sqrt((Lx[0] ** 2 + Ly[0] ** 2 + J3[0] ** 2) * (Lx[1] ** 2 + Ly[1] ** 2 + J3[1] ** 2)
                                   * (Lx[2] ** 2 + Ly[2] ** 2 + J3[2] ** 2)), 1e-300)
    if det == 0.0 or not math.isfinite(det):
        return res, 0.0, 0.0, 0.0, False, 0.0
    dx = (g[0] * (Ly[1] * J3[2] - J3[1] * Ly[2]) - Ly[0] * (g[1] * J3[2] - J3[1] * g[2])
          + J3[0] * (g[1] * Ly[2] - Ly[1] * g[2])) / det
    dy = (Lx[0] * (g[1] * J3[2] - J3[1] * g[2]) - g[0] * (Lx[1] * J3[2] - J3[1] * Lx[2])
          + J3[0] * (Lx[1] * g[2] - g[1] * Lx[2])) / det
    dp = (Lx[0] * (Ly[1] * g[2] - g[1] * Ly[2]) - Ly[0] * (Lx[1] * g[2] - g[1] * Lx[2])
          + g[0] * (Lx[1] * Ly[2] - Ly[1] * Lx[2])) / det
    ok = math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dp)
    return res, dx, dy, dp, ok, had


@njit(cache=True)
def _polish(x, y, phi, D, b, l2sq, steps):
    """Newton steps; a step is kept only where it lowers max|F|.

    Returns x, y, phi, the residual max|F_i| and the Hadamard ratio of J there.
    """
    res, dx, dy, dp, ok, had = _residual_step(x, y, phi, D, b, l2sq)
    for _ in range(steps):
        if not ok or res == 0.0:
            break
        rt, dx2, dy2, dp2, ok2, had2 = _residual_step(x + dx, y + dy, phi + dp, D, b, l2sq)
        if not rt < res:
            break
        x, y, phi, res, had = x + dx, y + dy, phi + dp, rt, had2
        dx, dy, dp, ok = dx2, dy2, dp2, ok2
    return x, y, phi, res, had


@njit(cache=True)
def _roots6(coef):
    """All roots of the degree-6 polynomial ``coef`` (highest first, coef[0] != 0).

    Aberth-Ehrlich simultaneous iteration (Gauss-Seidel updates) from points on
    a circle of radius the geometric mean of the root moduli.  A root is frozen
    once its correction is at rounding level, or once ``|p(z)|`` is below its
    rounding-error bound ``4 eps sum |a_i| |z|^i`` and the corrections stop
    shrinking (a multiple root).  Stopping on ``|p|`` alone would leave the two
    roots of a close pair with a forward error far above their separation.
    """
    n = 6
    a = np.empty(n + 1, dtype=np.complex128)
    for i in range(n + 1):
        a[i] = coef[i] / coef[0]
    r = abs(a[n]) ** (1.0 / n) if a[n] != 0 else 1.0
    if r == 0.0 or not math.isfinite(r):
        r = 1.0
    z = np.empty(n, dtype=np.complex128)
    for k in range(n):
        z[k] = r * cmath.exp(1j * (2.0 * math.pi * k / n + 0.4))
    done = np.zeros(n, dtype=np.bool_)
    last = np.full(n, np.inf)
    for _ in range(200):
        alldone = True
        for k in range(n):
            if done[k]:
                continue
            zk = z[k]
            p = a[0]
            dp = 0j
            bound = abs(a[0])
            az = abs(zk)
            for i in range(1, n + 1):
                dp = dp * zk + p
                p = p * zk + a[i]
                bound = bound * az + abs(a[i])
            if p == 0:
                done[k] = True
                continue
            alldone = False
            if dp == 0:
                z[k] = zk + r * 1e-3 * (1 + 1j)
                continue
            ratio = p / dp
            sigma = 0j
            for j in range(n):
                if j != k:
                    diff = zk - z[j]
                    if diff != 0:
                        sigma += 1.0 / diff
            w = ratio / (1.0 - ratio * sigma)
            z[k] = zk - w
            # converged when the correction is at rounding level, or when |p| is at its rounding
            # level and the correction no longer shrinks (a multiple root, linear convergence)
            if abs(w) <= 2.0 * EPS * abs(z[k]) or (abs(p) <= 4.0 * EPS * bound and abs(w) >= 0.5 * last[k]):
                done[k] = True
            last[k] = abs(w)
        if alldone:
            break
    return z


@njit(cache=True)
def _wrap(a):
    return math.pi - ((math.pi - a) % (2.0 * math.pi)) + 0.0


@njit(cache=True)
def _line_circle_candidates(phi, D, b, l2sq):
    """The two intersections of the better row's line r . P = h with the circle F_1 = 0."""
    c, s = math.cos(phi), math.sin(phi)
    delta, nx, ny, u0x, u0y, k0, r2x, r2y, r3x, r3y, h2, h3 = _elim(c, s, D, b, l2sq)
    if abs(r2x) + abs(r2y) >= abs(r3x) + abs(r3y):
        rx, ry, hh = r2x, r2y, h2
    else:
        rx, ry, hh = r3x, r3y, h3
    nrm = rx * rx + ry * ry
    if nrm == 0.0:
        return 0.0, 0.0, 0.0, 0.0, False
    p0x, p0y = rx * hh / nrm, ry * hh / nrm
    sq = math.sqrt(nrm)
    ex, ey = -ry / sq, rx / sq
    wx, wy = p0x + u0x, p0y + u0y
    bq = 2.0 * (ex * wx + ey * wy)
    cq = wx * wx + wy * wy - l2sq[0]
    root = math.sqrt(max(bq * bq - 4.0 * cq, 0.0))
    la, lb = 0.5 * (-bq + root), 0.5 * (-bq - root)
    return p0x + la * ex, p0y + la * ey, p0x + lb * ex, p0y + lb * ey, True


@njit(cache=True)
def _deflated_newton(x, y, p, ax, ay, ap, D, b, l2sq, iters):
    """Newton on the deflated system ``(1 / |X - X_a|^2 + 1) F(X) = 0`` (Farrell et al.).

    The factor makes the accepted solution ``X_a`` repel the iteration, so from a start near a
    (near-)double root it converges to the *other* solution.  Returns x, y, phi.
    """
    Lx = np.empty(3)
    Ly = np.empty(3)
    J3 = np.empty(3)
    F = np.empty(3)
    A = np.empty((3, 3))
    for _ in range(iters):
        c, s = math.cos(p), math.sin(p)
        for i in range(3):
            rbx = c * b[i, 0] - s * b[i, 1]
            rby = s * b[i, 0] + c * b[i, 1]
            Lx[i] = x + rbx - D[i, 0]
            Ly[i] = y + rby - D[i, 1]
            J3[i] = Ly[i] * rbx - Lx[i] * rby
            F[i] = 0.5 * (Lx[i] * Lx[i] + Ly[i] * Ly[i] - l2sq[i])
        dx, dy, dp = x - ax, y - ay, _wrap(p - ap)
        r2 = dx * dx + dy * dy + dp * dp
        if r2 == 0.0:
            dx, dy, dp, r2 = 1e-8, 1e-8, 1e-8, 3e-16
        m = 1.0 / r2 + 1.0
        g0, g1, g2 = -2.0 * dx / (r2 * r2), -2.0 * dy / (r2 * r2), -2.0 * dp / (r2 * r2)
        for i in range(3):                 # d(m F)/dX = m J + F grad(m)^T  (J halved like F)
            A[i, 0] = m * Lx[i] + F[i] * g0
            A[i, 1] = m * Ly[i] + F[i] * g1
            A[i, 2] = m * J3[i] + F[i] * g2
        det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
               + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
        if det == 0.0 or not math.isfinite(det):
            break
        r0, r1, rr2 = -m * F[0], -m * F[1], -m * F[2]
        sx = (r0 * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (r1 * A[2, 2] - A[1, 2] * rr2)
              + A[0, 2] * (r1 * A[2, 1] - A[1, 1] * rr2)) / det
        sy = (A[0, 0] * (r1 * A[2, 2] - A[1, 2] * rr2) - r0 * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
              + A[0, 2] * (A[1, 0] * rr2 - r1 * A[2, 0])) / det
        sp = (A[0, 0] * (A[1, 1] * rr2 - r1 * A[2, 1]) - A[0, 1] * (A[1, 0] * rr2 - r1 * A[2, 0])
              + r0 * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])) / det
        if not (math.isfinite(sx) and math.isfinite(sy) and math.isfinite(sp)):
            break
        x, y, p = x + sx, y + sy, p + sp
        if abs(sx) + abs(sy) + abs(sp) < 1e-15:
            break
    return x, y, p


@njit(cache=True)
def _acceptable(x, y, ph, res, had, ph0, out, isreal, real_tol):
    """Whether a polished candidate is the real solution of the root at ``ph0``.

    The residual must be at rounding level, phi must not have drifted from the
    root (the sextic pins phi; only P can be off), and it must not repeat an
    accepted solution unless J is singular there (a true double root).
    """
    if not res <= real_tol or abs(ph - ph0) > PHI_DRIFT:
        return False
    if had > HADAMARD_SINGULAR:
        for j in range(6):
            if isreal[j] and (abs(out[j, 0].real - x) + abs(out[j, 1].real - y)
                              + abs(_wrap(out[j, 2].real - ph))) < DUPLICATE:
                return False
    return True


@njit(cache=True)
def dk_one(q, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps,
           poses, real):
    """All six DK solutions of one joint vector, written into ``poses`` (6, 3) and ``real`` (6,)."""
    D = np.empty((3, 2))
    for i in range(3):
        D[i, 0] = M[i, 0] + l1[i] * math.cos(q[i])
        D[i, 1] = M[i, 1] + l1[i] * math.sin(q[i])
    # 2-3: eliminant at the eight samples; psi + pi at the sample of largest |f|
    f = np.empty(8)
    jbest, fbest = 0, -1.0
    for m in range(8):
        delta, nx, ny, u0x, u0y, k0, _a, _b, _c, _d, _e, _f = _elim(cos8[m], sin8[m], D, b, l2sq)
        f[m] = nx * nx + ny * ny + 2.0 * delta * (nx * u0x + ny * u0y) + delta * delta * k0
        if abs(f[m]) > fbest:
            fbest, jbest = abs(f[m]), m
    coef = np.zeros(7)
    for m in range(8):
        for c in range(7):
            coef[c] += f[m] * T[jbest, m, c]
    psi = psis[jbest]
    out = np.empty((6, 3), dtype=np.complex128)
    isreal = np.zeros(6, dtype=np.bool_)
    if coef[0] == 0.0 or not math.isfinite(coef[0]):
        # f vanishes identically: a degenerate architecture, no isolated solutions
        for k in range(6):
            for c in range(3):
                out[k, c] = complex(np.nan, np.nan)
    else:
        t = _roots6(coef)
        phi_root = np.empty(6, dtype=np.complex128)
        for k in range(6):
            phi_root[k] = psi + 2.0 * cmath.atan(t[k])
        # complex roots first: P from step 1 at complex phi
        for k in range(6):
            phi = phi_root[k]
            if abs(phi.imag) > snap_tol:
                cc, ss = cmath.cos(phi), cmath.sin(phi)
                delta, nx, ny, _u, _v, _k, _a, _b, _c, _d, _e, _f = _elim(cc, ss, D, b, l2sq)
                out[k, 0], out[k, 1], out[k, 2] = nx / delta, ny / delta, phi
        # (near-)real roots: candidates polished by Newton, the first acceptable one is kept
        for k in range(6):
            ph0 = phi_root[k].real
            if abs(phi_root[k].imag) > snap_tol:
                continue
            out[k, 0], out[k, 1], out[k, 2] = complex(np.nan, np.nan), complex(np.nan, np.nan), ph0
            c0, s0 = math.cos(ph0), math.sin(ph0)
            delta, nx, ny, _u, _v, _k, _a, _b, _c, _d, _e, _f = _elim(c0, s0, D, b, l2sq)
            xa, ya, xb, yb, lc_ok = _line_circle_candidates(ph0, D, b, l2sq)
            for cand in range(4):
                p0 = ph0
                if cand == 0:
                    if delta == 0.0:
                        continue
                    x0, y0 = nx / delta, ny / delta
                elif cand == 1 or cand == 2:
                    if not lc_ok:
                        continue
                    x0, y0 = (xa, ya) if cand == 1 else (xb, yb)
                else:
                    # a twin of an accepted solution (a close pair the sextic cannot separate):
                    # deflated Newton from the Cramer point, away from the nearest accepted one
                    jn, dn = -1, np.inf
                    for j in range(6):
                        if isreal[j] and abs(_wrap(out[j, 2].real - ph0)) < 1e-4:
                            dd = abs(_wrap(out[j, 2].real - ph0))
                            if dd < dn:
                                jn, dn = j, dd
                    if jn < 0 or delta == 0.0:
                        continue
                    x0, y0, p0 = _deflated_newton(nx / delta, ny / delta, ph0, out[jn, 0].real,
                                                  out[jn, 1].real, out[jn, 2].real, D, b, l2sq, 40)
                x, y, ph, res, had = _polish(x0, y0, p0, D, b, l2sq, steps)
                if _acceptable(x, y, ph, res, had, ph0, out, isreal, real_tol):
                    out[k, 0], out[k, 1], out[k, 2] = x, y, ph
                    isreal[k] = True
                    break
            if not isreal[k]:
                # not a real solution after all: keep the root as a complex one
                cc, ss = cmath.cos(phi_root[k]), cmath.sin(phi_root[k])
                delta, nx, ny, _u, _v, _k, _a, _b, _c, _d, _e, _f = _elim(cc, ss, D, b, l2sq)
                out[k, 0], out[k, 1], out[k, 2] = nx / delta, ny / delta, phi_root[k]
        for k in range(6):
            if isreal[k]:
                out[k, 0] = out[k, 0].real
                out[k, 1] = out[k, 1].real
                out[k, 2] = _wrap(out[k, 2].real)
            else:
                finite = True
                for c in range(3):
                    if not (math.isfinite(out[k, c].real) and math.isfinite(out[k, c].imag)):
                        finite = False
                if finite:
                    out[k, 2] = complex(_wrap(out[k, 2].real), out[k, 2].imag)
                else:
                    for c in range(3):
                        out[k, c] = complex(np.nan, np.nan)
    # numbering: insertion sort by the rule's key
    order = np.arange(6)
    for i in range(1, 6):
        j = i
        while j > 0 and _before(out, isreal, order[j], order[j - 1], rule):
            order[j], order[j - 1] = order[j - 1], order[j]
            j -= 1
    if rule == RULE_ASPECT:
        order = _aspect_order(out, isreal, order, D, b)
    for i in range(6):
        for c in range(3):
            poses[i, c] = out[order[i], c]
        real[i] = isreal[order[i]]


@njit(cache=True)
def _key(out, k, comp):
    re, im = out[k, comp].real, out[k, comp].imag
    if not math.isfinite(re):
        re = np.inf
    if not math.isfinite(im):
        im = np.inf
    return re, im


@njit(cache=True)
def _before(out, isreal, a, b, rule):
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
    ra, ia = _key(out, a, comp)
    rb, ib = _key(out, b, comp)
    if ra != rb:
        return ra < rb
    return ia < ib


@njit(cache=True)
def _det_sign(x, y, phi, D, b):
    """Sign of det J at a real pose (+1 or -1; 0 exactly singular)."""
    c, s = math.cos(phi), math.sin(phi)
    J = np.empty((3, 3))
    for i in range(3):
        rbx = c * b[i, 0] - s * b[i, 1]
        rby = s * b[i, 0] + c * b[i, 1]
        lx, ly = x + rbx - D[i, 0], y + rby - D[i, 1]
        J[i, 0], J[i, 1], J[i, 2] = lx, ly, ly * rbx - lx * rby
    det = (J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1]) - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
           + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0]))
    return 1 if det > 0 else (-1 if det < 0 else 0)


@njit(cache=True)
def _aspect_order(out, isreal, order, D, b):
    """Rule 'aspect': slots 1-3 real solutions with det J >= 0, slots 4-6 those with det J < 0,
    each by phi; complex solutions (by Re phi, Im phi) fill the free slots, first class first.

    ``order`` arrives sorted by the real-phi key (real by phi, then complex).  Real solutions
    are born and die in pairs of opposite det J sign, so each class holds at most three;
    should a class overflow (only at an exactly singular input) the slots fill in sequence.
    """
    pos = np.empty(6, dtype=np.int64)
    neg = np.empty(6, dtype=np.int64)
    cpx = np.empty(6, dtype=np.int64)
    npos, nneg, ncpx = 0, 0, 0
    for i in range(6):
        k = order[i]
        if isreal[k]:
            if _det_sign(out[k, 0].real, out[k, 1].real, out[k, 2].real, D, b) >= 0:
                pos[npos] = k
                npos += 1
            else:
                neg[nneg] = k
                nneg += 1
        else:
            cpx[ncpx] = k
            ncpx += 1
    res = np.empty(6, dtype=np.int64)
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
        return res
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
    return res


@njit(cache=True)
def dk_serial(q, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps, poses, real):
    for n in range(q.shape[0]):
        dk_one(q[n], M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps,
               poses[n], real[n])


@njit(cache=True, parallel=True)
def dk_parallel(q, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps, poses, real):
    for n in prange(q.shape[0]):
        dk_one(q[n], M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps,
               poses[n], real[n])


@njit(cache=True)
def ik_batch(X, bits, M, l1, l2, b, out):
    """Inverse kinematics of poses X (N, 3) with elbow bits (N, 3) (1 = negative elbow) into out (N, 3)."""
    for n in range(X.shape[0]):
        c, s = math.cos(X[n, 2]), math.sin(X[n, 2])
        ok = True
        for i in range(3):
            dx = X[n, 0] + c * b[i, 0] - s * b[i, 1] - M[i, 0]
            dy = X[n, 1] + s * b[i, 0] + c * b[i, 1] - M[i, 1]
            rho2 = dx * dx + dy * dy
            rho = math.sqrt(rho2)
            if rho == 0.0:
                ok = False
                break
            ca = (l1[i] * l1[i] + rho2 - l2[i] * l2[i]) / (2.0 * l1[i] * rho)
            if not abs(ca) <= 1.0 + 1e-12:
                ok = False
                break
            alpha = math.acos(min(1.0, max(-1.0, ca)))
            sign = 1.0 - 2.0 * bits[n, i]
            out[n, i] = _wrap(math.atan2(dy, dx) - sign * alpha)
        if not ok:
            for i in range(3):
                out[n, i] = np.nan
