"""All six direct-kinematics solutions of one joint vector (:func:`solver.dk_all`), compiled.

The derivation is in :mod:`solver.direct_kinematics`.  Every step there is done here for
one joint vector with scalar arithmetic; :func:`dk_serial` and :func:`dk_parallel` run
:func:`dk_one` over a batch (in parallel threads for large batches), and a single call is
a batch of one, so both go through the same code.

Why compiled: a numpy version of the same algorithm spends ~400 array operations per
call; that is ~500 us for one joint vector and ~70,000 sets/s in batches on this
machine, while the tracker and the FMUs call the direct kinematics once per step (and
four times per Runge-Kutta step).
"""
from __future__ import annotations

import cmath
import math

import numpy as np
from numba import njit, prange

from .kinematics import elbows, geometry, loop_row, newton_step, radius_sq
from .layout import MODEL_COS8, MODEL_NEWTON_STEPS, MODEL_PSI, MODEL_REAL_TOL, MODEL_SIN8, MODEL_SNAP_TOL
from .linalg import solve3, wrap
from .ordering import number_solutions
from .scratch import floats, scratch, scratch2

EPS = 2.220446049250313e-16
#: A polished real root may not move phi further than this from the sextic's root (rad).
PHI_DRIFT = 1e-5
#: Two real solutions closer than this (sum of |dx|, |dy|, |dphi|) are the same solution twice.
DUPLICATE = 1e-7
#: Below this Hadamard ratio of J a repeated solution is a genuine double root.
HADAMARD_SINGULAR = 1e-6


@njit(cache=False)
def elim(c, s, D, b, l2sq):
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
def polish(x, y, phi, D, b, l2sq, steps):
    """Newton steps; a step is kept only where it lowers max|F|.

    Returns x, y, phi, the residual max|F_i| and the Hadamard ratio of J there.
    """
    res, dx, dy, dp, ok, had = newton_step(x, y, phi, D, b, l2sq)
    for _ in range(steps):
        if not ok or res == 0.0:
            break
        rt, dx2, dy2, dp2, ok2, had2 = newton_step(x + dx, y + dy, phi + dp, D, b, l2sq)
        if not rt < res:
            break
        x, y, phi, res, had = x + dx, y + dy, phi + dp, rt, had2
        dx, dy, dp, ok = dx2, dy2, dp2, ok2
    return x, y, phi, res, had


@njit(cache=True)
def roots6(coef):
    """All roots (6,) complex of the degree-6 polynomial ``coef`` (7,) (highest first, coef[0] != 0):
    :func:`roots6_into` into a new array."""
    z = np.empty(6, dtype=np.complex128)
    roots6_into(coef, z)
    return z


@njit(cache=False)
def roots6_into(coef, z):
    """All roots of the degree-6 polynomial ``coef`` (7,) (highest first, coef[0] != 0) into ``z`` (6,) complex.

    Aberth-Ehrlich simultaneous iteration (Gauss-Seidel updates) from points on
    a circle of radius the geometric mean of the root moduli.  A root is frozen
    once its correction is at rounding level, or once ``|p(z)|`` is below its
    rounding-error bound ``4 eps sum |a_i| |z|^i`` and the corrections stop
    shrinking (a multiple root).  Stopping on ``|p|`` alone would leave the two
    roots of a close pair with a forward error far above their separation.

    In real arithmetic on the real and imaginary parts (the coefficients are real):
    a reciprocal is one real division, and the tests compare squared moduli, which
    halves the time of complex ``/`` and ``abs`` (measured: 3.9 -> 2.0 us a call on
    the paper circle; roots equal to within 1e-15).
    """
    n = 6
    ar = floats(7)
    aa = floats(7)                                   # |a_i|, for the rounding bound
    for i in range(n + 1):
        ar[i] = coef[i] / coef[0]
        aa[i] = abs(ar[i])
    r = aa[n] ** (1.0 / n) if ar[n] != 0.0 else 1.0
    if r == 0.0 or not math.isfinite(r):
        r = 1.0
    zr = floats(6)
    zi = floats(6)
    for k in range(n):
        ang = 2.0 * math.pi * k / n + 0.4
        zr[k] = r * math.cos(ang)
        zi[k] = r * math.sin(ang)
    done = scratch(6, np.bool_)
    last2 = floats(6)                                # |w|^2 of each root's last correction
    done[:] = False
    last2[:] = np.inf
    at_rounding = 4.0 * EPS * EPS                    # (2 eps)^2
    p_rounding = 16.0 * EPS * EPS                    # (4 eps)^2
    for _ in range(200):
        alldone = True
        for k in range(n):
            if done[k]:
                continue
            xr, xi = zr[k], zi[k]
            pr, pim = 1.0, 0.0                       # p(z) and p'(z) by Horner (a_0 = 1)
            dr, di = 0.0, 0.0
            bound = aa[0]
            az = math.sqrt(xr * xr + xi * xi)
            for i in range(1, n + 1):
                dr, di = dr * xr - di * xi + pr, dr * xi + di * xr + pim
                pr, pim = pr * xr - pim * xi + ar[i], pr * xi + pim * xr
                bound = bound * az + aa[i]
            if pr == 0.0 and pim == 0.0:
                done[k] = True
                continue
            alldone = False
            dd = dr * dr + di * di
            if dd == 0.0:
                zr[k] = xr + r * 1e-3
                zi[k] = xi + r * 1e-3
                continue
            rr, ri = (pr * dr + pim * di) / dd, (pim * dr - pr * di) / dd          # p / p'
            sr, si = 0.0, 0.0                                                     # sum 1 / (z_k - z_j)
            for j in range(n):
                if j != k:
                    fr, fi = xr - zr[j], xi - zi[j]
                    ff = fr * fr + fi * fi
                    if ff != 0.0:
                        sr += fr / ff
                        si -= fi / ff
            gr, gi = 1.0 - (rr * sr - ri * si), -(rr * si + ri * sr)              # 1 - ratio sigma
            gg = gr * gr + gi * gi
            wr, wi = (rr * gr + ri * gi) / gg, (ri * gr - rr * gi) / gg          # the correction w
            zr[k], zi[k] = xr - wr, xi - wi
            # converged when the correction is at rounding level, or when |p| is at its rounding
            # level and the correction no longer shrinks (a multiple root, linear convergence)
            w2 = wr * wr + wi * wi
            if w2 <= at_rounding * (zr[k] * zr[k] + zi[k] * zi[k]) or \
                    (pr * pr + pim * pim <= p_rounding * bound * bound and w2 >= 0.25 * last2[k]):
                done[k] = True
            last2[k] = w2
        if alldone:
            break
    for k in range(n):
        z[k] = complex(zr[k], zi[k])


@njit(cache=True)
def line_circle_candidates(phi, D, b, l2sq):
    """The two intersections of the better row's line r . P = h with the circle F_1 = 0."""
    c, s = math.cos(phi), math.sin(phi)
    delta, nx, ny, u0x, u0y, k0, r2x, r2y, r3x, r3y, h2, h3 = elim(c, s, D, b, l2sq)
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
def deflated_newton(x, y, p, ax, ay, ap, D, b, l2sq, iters):
    """Newton on the deflated system ``(1 / |X - X_a|^2 + 1) F(X) = 0`` (Farrell et al.).

    The factor makes the accepted solution ``X_a`` repel the iteration, so from a start near a
    (near-)double root it converges to the *other* solution.  Returns x, y, phi.
    """
    A = scratch2(3, 3, np.float64)
    r = floats(3)
    step = floats(3)
    for _ in range(iters):
        c, s = math.cos(p), math.sin(p)
        dx, dy, dp = x - ax, y - ay, wrap(p - ap)
        r2 = dx * dx + dy * dy + dp * dp
        if r2 == 0.0:
            dx, dy, dp, r2 = 1e-8, 1e-8, 1e-8, 3e-16
        m = 1.0 / r2 + 1.0
        g0, g1, g2 = -2.0 * dx / (r2 * r2), -2.0 * dy / (r2 * r2), -2.0 * dp / (r2 * r2)
        for i in range(3):                 # d(m F)/dX = m J + F grad(m)^T  (J and F halved)
            _rbx, _rby, lx, ly, lr = loop_row(x, y, c, s, b[i, 0], b[i, 1], D[i, 0], D[i, 1], 0.0, 0.0)
            F = 0.5 * (lx * lx + ly * ly - l2sq[i])
            A[i, 0] = m * lx + F * g0
            A[i, 1] = m * ly + F * g1
            A[i, 2] = m * lr + F * g2
            r[i] = -m * F
        if not solve3(A, r, step):
            break
        sx, sy, sp = step[0], step[1], step[2]
        x, y, p = x + sx, y + sy, p + sp
        if abs(sx) + abs(sy) + abs(sp) < 1e-15:
            break
    return x, y, p


@njit(cache=True)
def acceptable(x, y, ph, res, had, ph0, out, isreal, real_tol):
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
                              + abs(wrap(out[j, 2].real - ph))) < DUPLICATE:
                return False
    return True


@njit(cache=False)
def sextic(D, b, l2sq, cos8, sin8, sample_to_sextic, coef):
    """Steps 2-3: the eliminant at the eight sample angles, mapped to the sextic's coefficients
    ``coef`` (7,) for the half-angle shift of the sample of largest ``|f|``; returns that sample's index."""
    f = floats(8)
    jbest, fbest = 0, -1.0
    for m in range(8):
        delta, nx, ny, u0x, u0y, k0, _a, _b, _c, _d, _e, _f = elim(cos8[m], sin8[m], D, b, l2sq)
        f[m] = nx * nx + ny * ny + 2.0 * delta * (nx * u0x + ny * u0y) + delta * delta * k0
        if abs(f[m]) > fbest:
            fbest, jbest = abs(f[m]), m
    for c in range(7):
        coef[c] = 0.0
    for m in range(8):
        for c in range(7):
            coef[c] += f[m] * sample_to_sextic[jbest, m, c]
    return jbest


@njit(cache=False)
def complex_solution(phi, D, b, l2sq, out, k):
    """Step 5: ``P`` from step 1 at a complex ``phi``, with ``phi``, into row ``k`` of ``out`` (6, 3) complex
    (the row's index, not a view of it: making a view costs more than this step)."""
    cc, ss = cmath.cos(phi), cmath.sin(phi)
    delta, nx, ny, _u, _v, _k, _a, _b, _c, _d, _e, _f = elim(cc, ss, D, b, l2sq)
    out[k, 0], out[k, 1], out[k, 2] = nx / delta, ny / delta, phi


@njit(cache=False)
def twin_start(nx, ny, delta, ph0, D, b, l2sq, out, isreal):
    """Candidate 3 of a real root at ``ph0``: a twin of an accepted solution (a close pair the sextic
    cannot separate), deflated Newton from the Cramer point away from the nearest accepted one.
    Returns x0, y0, phi0 and whether there is such a candidate."""
    jn, dn = -1, np.inf
    for j in range(6):
        if isreal[j] and abs(wrap(out[j, 2].real - ph0)) < 1e-4:
            dd = abs(wrap(out[j, 2].real - ph0))
            if dd < dn:
                jn, dn = j, dd
    if jn < 0 or delta == 0.0:
        return 0.0, 0.0, 0.0, False
    x0, y0, p0 = deflated_newton(nx / delta, ny / delta, ph0, out[jn, 0].real, out[jn, 1].real, out[jn, 2].real,
                                 D, b, l2sq, 40)
    return x0, y0, p0, True


@njit(cache=False)
def real_solution(k, ph0, D, b, l2sq, steps, real_tol, out, isreal):
    """Steps 6-7 for the (near-)real root ``k`` at ``ph0``: candidates polished by Newton, the first
    acceptable one is written into ``out[k]`` and marked in ``isreal``; True if there is one."""
    out[k, 0], out[k, 1], out[k, 2] = complex(np.nan, np.nan), complex(np.nan, np.nan), ph0
    c0, s0 = math.cos(ph0), math.sin(ph0)
    delta, nx, ny, _u, _v, _k, _a, _b, _c, _d, _e, _f = elim(c0, s0, D, b, l2sq)
    xa, ya, xb, yb, lc_ok = line_circle_candidates(ph0, D, b, l2sq)
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
            x0, y0, p0, ok = twin_start(nx, ny, delta, ph0, D, b, l2sq, out, isreal)
            if not ok:
                continue
        x, y, ph, res, had = polish(x0, y0, p0, D, b, l2sq, steps)
        if acceptable(x, y, ph, res, had, ph0, out, isreal, real_tol):
            out[k, 0], out[k, 1], out[k, 2] = x, y, ph
            isreal[k] = True
            return True
    return False


@njit(cache=False)
def normalise(out, isreal):
    """Real solutions as real numbers with phi wrapped; complex ones with Re phi wrapped, or NaN
    throughout if any part is not finite."""
    for k in range(6):
        if isreal[k]:
            out[k, 0] = out[k, 0].real
            out[k, 1] = out[k, 1].real
            out[k, 2] = wrap(out[k, 2].real)
        else:
            finite = True
            for c in range(3):
                if not (math.isfinite(out[k, c].real) and math.isfinite(out[k, c].imag)):
                    finite = False
            if finite:
                out[k, 2] = complex(wrap(out[k, 2].real), out[k, 2].imag)
            else:
                for c in range(3):
                    out[k, c] = complex(np.nan, np.nan)


@njit(cache=True)
def dk_one(q, model_pack, sample_to_sextic, rule, poses, real):
    """All six DK solutions of joints ``q`` (3,), numbered by ``rule``, into ``poses`` (6, 3) and ``real`` (6,).

    ``model_pack``: the model pack (:mod:`.layout`); ``sample_to_sextic`` (8, 8, 7): row ``j``
    maps the eliminant at the eight sample angles to the sextic's coefficients for the
    half-angle shift ``psi_j``.
    """
    M, l1, l2sq, b = geometry(model_pack)
    snap_tol, real_tol = model_pack[MODEL_SNAP_TOL], model_pack[MODEL_REAL_TOL]
    D = scratch2(3, 2, np.float64)
    elbows(q, M, l1, D)                              # the 3-RPR has l1 = 0: D = M, its base joints
    r2 = floats(3)
    for i in range(3):
        r2[i] = radius_sq(l2sq[i], q[i])             # ... and its joints are the legs' lengths
    l2sq = r2
    coef = floats(7)
    jbest = sextic(D, b, l2sq, model_pack[MODEL_COS8:MODEL_COS8 + 8], model_pack[MODEL_SIN8:MODEL_SIN8 + 8],
                   sample_to_sextic, coef)
    psi = model_pack[MODEL_PSI + jbest]
    out = scratch2(6, 3, np.complex128)
    isreal = scratch(6, np.bool_)
    isreal[:] = False
    if coef[0] == 0.0 or not math.isfinite(coef[0]):
        # f vanishes identically: a degenerate architecture, no isolated solutions
        for k in range(6):
            for c in range(3):
                out[k, c] = complex(np.nan, np.nan)
    else:
        t = scratch(6, np.complex128)
        roots6_into(coef, t)
        phi_root = scratch(6, np.complex128)
        for k in range(6):
            phi_root[k] = psi + 2.0 * cmath.atan(t[k])
        for k in range(6):                           # complex roots first: P from step 1 at complex phi
            if abs(phi_root[k].imag) > snap_tol:
                complex_solution(phi_root[k], D, b, l2sq, out, k)
        for k in range(6):                           # (near-)real roots, or complex after all
            if not abs(phi_root[k].imag) > snap_tol and not real_solution(
                    k, phi_root[k].real, D, b, l2sq, int(model_pack[MODEL_NEWTON_STEPS]), real_tol, out, isreal):
                complex_solution(phi_root[k], D, b, l2sq, out, k)
        normalise(out, isreal)
    number_solutions(out, isreal, rule, D, b, poses, real)


@njit(cache=True)
def dk_serial(q, model_pack, sample_to_sextic, rule, poses, real):
    """:func:`dk_one` of every row of ``q`` (N, 3) into ``poses`` (N, 6, 3) and ``real`` (N, 6)."""
    for n in range(q.shape[0]):
        dk_one(q[n], model_pack, sample_to_sextic, rule, poses[n], real[n])


@njit(cache=True, parallel=True)
def dk_parallel(q, model_pack, sample_to_sextic, rule, poses, real):
    """:func:`dk_serial` in parallel threads."""
    for n in prange(q.shape[0]):
        dk_one(q[n], model_pack, sample_to_sextic, rule, poses[n], real[n])
