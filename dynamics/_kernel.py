r"""Compiled kernels of the rigid-body dynamics of :mod:`dynamics.model` (one configuration at a time).

The derivation is in :mod:`dynamics.model`.  Every formula there -- the loop
geometry and ``J_q``, the 21 body velocity rows ``V``, the velocity-product
accelerations ``beta``, the nine friction rows, ``M_X = V^T W V``,
``C_X dX = V^T W beta``, ``G_X = -V^T W gamma``, ``F_X = V_f^T B V_f dX`` and the
joint-space forms ``M = (V J_x)^T W (V J_x)``, ``C dq = J_x^T V^T W (beta + V ddX_0)``,
``G = J_x^T G_X``, ``F = J_x^T F_X`` -- is evaluated here for one configuration
with scalar loops over small fixed-size work arrays, in the same order of
operations as the numpy code.  Each entry point runs one row function over a
batch of rows (arrays ``(n, 3)`` or ``(n, 6)``); a single call is a batch of
one, so both go through the same code.  numba compiles on first use and caches
the machine code next to this file.

Why compiled: the numpy version spends ~150 array operations on arrays of 3
to 63 numbers per call, ~200 us per configuration, almost all of it call
overhead, while the plant and the controller evaluate the dynamics at every
RK4 stage and every controller period (1 ms).

Packed constants (built by :func:`pack_model` / :func:`pack_params`, cached by
:mod:`dynamics.model`):

* ``G`` (18,): motors ``M_i`` (x, y) at 0..5, ``l1`` at 6..8, ``l2`` at 9..11,
  platform joints ``b_i`` (x, y, platform frame) at 12..17;
* ``P`` (40,): ``com_proximal`` at 0..2, ``com_distal`` at 3..5, the 21 row
  weights ``w`` at 6..26 (order of :func:`dynamics.model._constants`), the 9
  viscous coefficients ``b`` at 27..35, gravity (x, y) at 36..37,
  ``com_platform`` at 38..39.

Every entry point returns a status: :data:`OK`, or the first refusal
(:data:`BAD_INPUT` a non-finite input, :data:`OUTSIDE` no inverse-kinematics
solution, :data:`NOT_ASSEMBLED` loop residual above the tolerance,
:data:`SINGULAR` an exactly singular matrix or a non-finite result).  The
callers in :mod:`dynamics.model` then hand the call to the numpy reference,
which raises the documented error (or returns what it returns), so errors and
edge cases are exactly those of the reference.

Also here, for the closed loop of the co-simulation (one compiled call per
communication step and FMU, instead of ~100 numpy calls):

* the circle reference of :class:`dynamics.trajectory.CircleTrajectory`
  (:func:`circle_task_row`, :func:`circle_joint_row`, :func:`circle_batch`;
  packed circle ``C`` of :func:`pack_circle`), with the inverse kinematics of
  :func:`solver.ik` operation for operation (:func:`ik_solver_row`);
* the plant FMU's step (:func:`plant_step`: RK4 with held torques, then
  :func:`plant_outputs`: ``q``, ``dq = J_q dX``, the energy) and the
  computed-torque FMU's step (:func:`controller_step`), on the packed
  constants ``K`` (``G``, ``P``, then the gains and the circle).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# ----------------------------------------------------------------------------- layout
#: offsets in the packed model ``G``
MOT, L1, L2, PLAT = 0, 6, 9, 12
#: offsets in the packed parameters ``P``
RP, RD, W, BF, GRAV, COMP = 0, 3, 6, 27, 36, 38
#: rows of the per-leg table ``leg`` (9, 3)
CQ, SQ, RBX, RBY, LX, LY, DEN, DQ, DDQ0 = 0, 1, 2, 3, 4, 5, 6, 7, 8
#: rows of the force table ``f`` (6, 3): task space C_X dX, G_X, F_X; joint space C dq, G, F
CX, GX, FX, CJ, GJ, FJ = 0, 1, 2, 3, 4, 5
#: what a task- or joint-space call returns
MASS, CORIOLIS, GRAVITY, FRICTION, FORWARD, INVERSE, GENERALIZED = 0, 1, 2, 3, 4, 5, 6
#: status codes
OK, BAD_INPUT, OUTSIDE, NOT_ASSEMBLED, SINGULAR = 0, 1, 2, 3, 4

TWO_PI = 2.0 * math.pi


def pack_model(motors, l1, l2, platform) -> np.ndarray:
    """The packed geometry ``G`` (18,) of a :class:`solver.Manipulator`'s arrays."""
    return np.concatenate([np.ravel(motors), l1, l2, np.ravel(platform)]).astype(np.float64)


def pack_params(com_proximal, com_distal, w, b, gravity, com_platform) -> np.ndarray:
    """The packed parameters ``P`` (40,): the fields of :class:`dynamics.model.DynamicParameters`
    with the 21 row weights ``w`` and the 9 friction coefficients ``b`` of ``_constants``."""
    return np.concatenate([com_proximal, com_distal, w, b, gravity, com_platform]).astype(np.float64)


# ----------------------------------------------------------------------------- helpers
@njit(cache=True, error_model="numpy")
def _wrap(a):
    """``pi - mod(pi - a, 2 pi)``: angle in (-pi, pi] (numpy's mod, the sign of the divisor)."""
    return math.pi - (math.pi - a) % TWO_PI


@njit(cache=True, error_model="numpy")
def _finite(v):
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@njit(cache=True, error_model="numpy")
def _gauss(aug, m):
    """Solve in place the 3x3 system of ``aug`` (3, 3 + m) for its ``m`` right-hand columns.

    Gaussian elimination with partial pivoting (the largest pivot of the column,
    as LAPACK's getrf); the solution overwrites the right-hand columns.  False
    if a pivot is exactly zero (the matrix is singular).
    """
    nc = 3 + m
    for c in range(3):
        p = c
        big = abs(aug[c, c])
        for r in range(c + 1, 3):
            if abs(aug[r, c]) > big:
                big, p = abs(aug[r, c]), r
        if big == 0.0:
            return False
        if p != c:
            for j in range(c, nc):
                aug[c, j], aug[p, j] = aug[p, j], aug[c, j]
        for r in range(c + 1, 3):
            f = aug[r, c] / aug[c, c]
            for j in range(c + 1, nc):
                aug[r, j] -= f * aug[c, j]
    for j in range(3, nc):
        for r in range(2, -1, -1):
            s = aug[r, j]
            for k in range(r + 1, 3):
                s -= aug[r, k] * aug[k, j]
            aug[r, j] = s / aug[r, r]
    return True


@njit(cache=True, error_model="numpy")
def _solve(A, transpose, b, x, aug):
    """``x = A^{-1} b`` (or ``A^{-T} b``) for a 3x3 ``A``; False if singular."""
    for r in range(3):
        for c in range(3):
            aug[r, c] = A[c, r] if transpose else A[r, c]
        aug[r, 3] = b[r]
    if not _gauss(aug, 1):
        return False
    for r in range(3):
        x[r] = aug[r, 3]
    return True


@njit(cache=True, error_model="numpy")
def _inverse(A, Ainv, aug):
    """``Ainv = A^{-1}`` for a 3x3 ``A``; False if singular."""
    for r in range(3):
        for c in range(3):
            aug[r, c] = A[r, c]
            aug[r, 3 + c] = 1.0 if r == c else 0.0
    if not _gauss(aug, 3):
        return False
    for r in range(3):
        for c in range(3):
            Ainv[r, c] = aug[r, 3 + c]
    return True


@njit(cache=True)
def _workspace():
    """Work arrays of one configuration (views of one allocation): leg table (9, 3), J_q, J_x,
    V (21, 3), beta (21,), M_X, M, forces (6, 3), V J_x (21, 3), the elimination scratch (3, 6)
    and two 3-vectors."""
    buf = np.empty(27 + 9 + 9 + 63 + 21 + 9 + 9 + 18 + 63 + 18 + 3 + 3)
    return (buf[0:27].reshape(9, 3), buf[27:36].reshape(3, 3), buf[36:45].reshape(3, 3),
            buf[45:108].reshape(21, 3), buf[108:129], buf[129:138].reshape(3, 3), buf[138:147].reshape(3, 3),
            buf[147:165].reshape(6, 3), buf[165:228].reshape(21, 3), buf[228:246].reshape(3, 6),
            buf[246:249], buf[249:252])


# ----------------------------------------------------------------------------- kinematics
@njit(cache=True, error_model="numpy")
def ik_row(G, x, y, phi, bits, q):
    """Inverse kinematics of one pose in the posture with elbow bits ``bits`` (posture - 1),
    as :func:`solver.ik`; writes ``q`` (3,) and returns False if a leg cannot reach."""
    c, s = math.cos(phi), math.sin(phi)
    ok = True
    for i in range(3):
        bx, by = G[PLAT + 2 * i], G[PLAT + 2 * i + 1]
        l1, l2 = G[L1 + i], G[L2 + i]
        dx = x + (c * bx - s * by) - G[MOT + 2 * i]
        dy = y + (s * bx + c * by) - G[MOT + 2 * i + 1]
        rho2 = dx * dx + dy * dy
        rho = math.sqrt(rho2)
        cos_a = (l1 * l1 + rho2 - l2 * l2) / (2.0 * l1 * rho)
        if not abs(cos_a) <= 1.0 + 1e-12:
            ok = False
        alpha = math.acos(min(max(cos_a, -1.0), 1.0)) if math.isfinite(cos_a) else 0.0
        sign = 1.0 - 2.0 * ((bits >> i) & 1)
        q[i] = _wrap(math.atan2(dy, dx) - sign * alpha)
    return ok


@njit(cache=True, error_model="numpy")
def _geometry(G, P, x, y, phi, q, leg, Jq):
    """Per-leg table (cos q, sin q, R b, L = A - D, den = l1 L.n) and ``J_q = dq/dX``.

    Returns ``(R c)_x, (R c)_y`` (platform centre-of-mass offset) and the loop
    residual ``max_i |F_i| / l2_i^2`` (NaN propagates).
    """
    c, s = math.cos(phi), math.sin(phi)
    res = 0.0
    for i in range(3):
        bx, by = G[PLAT + 2 * i], G[PLAT + 2 * i + 1]
        l1, l2 = G[L1 + i], G[L2 + i]
        cq, sq = math.cos(q[i]), math.sin(q[i])
        rbx = c * bx - s * by
        rby = s * bx + c * by
        lx = x + rbx - G[MOT + 2 * i] - l1 * cq
        ly = y + rby - G[MOT + 2 * i + 1] - l1 * sq
        den = l1 * (ly * cq - lx * sq)
        leg[CQ, i], leg[SQ, i], leg[RBX, i], leg[RBY, i] = cq, sq, rbx, rby
        leg[LX, i], leg[LY, i], leg[DEN, i] = lx, ly, den
        Jq[i, 0] = lx / den
        Jq[i, 1] = ly / den
        Jq[i, 2] = (ly * rbx - lx * rby) / den
        l2sq = l2 ** 2
        r = abs(lx ** 2 + ly ** 2 - l2sq) / l2sq
        if not r <= res:
            res = r
    cx, cy = P[COMP], P[COMP + 1]
    return c * cx - s * cy, s * cx + c * cy, res


@njit(cache=True, error_model="numpy")
def _velocity_rows(G, P, rcx, rcy, leg, Jq, V):
    """The 21 body velocity rows ``V`` (21, 3) w.r.t. ``dX``: platform x, y, rot; proximal x3,
    y3, rot3; distal x3, y3, rot3 (the last three are the distal link rates ``W``)."""
    V[0, 0], V[0, 1], V[0, 2] = 1.0, 0.0, -rcy
    V[1, 0], V[1, 1], V[1, 2] = 0.0, 1.0, rcx
    V[2, 0], V[2, 1], V[2, 2] = 0.0, 0.0, 1.0
    for i in range(3):
        l1, l2 = G[L1 + i], G[L2 + i]
        rp, sd, l2sq = P[RP + i], P[RD + i] / l2, l2 ** 2
        cq, sq, lx, ly = leg[CQ, i], leg[SQ, i], leg[LX, i], leg[LY, i]
        for j in range(3):
            jq = Jq[i, j]
            V[3 + i, j] = (-rp * sq) * jq
            V[6 + i, j] = (rp * cq) * jq
            V[9 + i, j] = jq
            vax = 1.0 if j == 0 else (-leg[RBY, i] if j == 2 else 0.0)     # v_A = dP + dphi E R b
            vay = 1.0 if j == 1 else (leg[RBX, i] if j == 2 else 0.0)
            vdx = (-l1 * sq) * jq
            vdy = (l1 * cq) * jq
            dlx, dly = vax - vdx, vay - vdy
            V[12 + i, j] = vdx + sd * dlx
            V[15 + i, j] = vdy + sd * dly
            V[18 + i, j] = (lx * dly - ly * dlx) / l2sq


@njit(cache=True, error_model="numpy")
def _motion(G, P, dx, dy, dphi, rcx, rcy, leg, Jq, beta):
    """Motor rates ``dq``, their velocity-product accelerations ``ddq0`` (into ``leg``) and the 21
    body accelerations ``beta`` at ``ddX = 0``."""
    w2 = dphi * dphi
    beta[0], beta[1], beta[2] = -w2 * rcx, -w2 * rcy, 0.0
    for i in range(3):
        l1, l2 = G[L1 + i], G[L2 + i]
        rp, sd, l2sq = P[RP + i], P[RD + i] / l2, l2 ** 2
        cq, sq, rbx, rby = leg[CQ, i], leg[SQ, i], leg[RBX, i], leg[RBY, i]
        lx, ly, den = leg[LX, i], leg[LY, i], leg[DEN, i]
        dq = Jq[i, 0] * dx + Jq[i, 1] * dy + Jq[i, 2] * dphi
        vax, vay = dx - dphi * rby, dy + dphi * rbx
        vdx, vdy = -l1 * sq * dq, l1 * cq * dq
        dlx, dly = vax - vdx, vay - vdy
        aax, aay = -w2 * rbx, -w2 * rby
        dq2 = dq * dq
        ddq0 = (lx * aax + ly * aay + l1 * dq2 * (lx * cq + ly * sq) + dlx * dlx + dly * dly) / den
        adx = l1 * (-sq * ddq0 - cq * dq2)
        ady = l1 * (cq * ddq0 - sq * dq2)
        ddlx, ddly = aax - adx, aay - ady
        leg[DQ, i], leg[DDQ0, i] = dq, ddq0
        beta[3 + i] = rp * (-sq * ddq0 - cq * dq2)
        beta[6 + i] = rp * (cq * ddq0 - sq * dq2)
        beta[9 + i] = ddq0
        beta[12 + i] = adx + sd * ddlx
        beta[15 + i] = ady + sd * ddly
        beta[18 + i] = (lx * ddly - ly * ddlx) / l2sq


@njit(cache=True, error_model="numpy")
def _row_gravity(P, r):
    """Gravity acceleration ``gamma_r`` of velocity row ``r`` (zero on rotation rows)."""
    if r == 0 or (3 <= r < 6) or (12 <= r < 15):
        return P[GRAV]
    if r == 1 or (6 <= r < 9) or (15 <= r < 18):
        return P[GRAV + 1]
    return 0.0


# ----------------------------------------------------------------------------- task-space terms
@njit(cache=True, error_model="numpy")
def _mass_task(P, V, MX):
    """``M_X = V^T W V``."""
    for a in range(3):
        for b in range(3):
            s = 0.0
            for r in range(21):
                s += V[r, a] * (P[W + r] * V[r, b])
            MX[a, b] = s


@njit(cache=True, error_model="numpy")
def _coriolis_task(P, V, beta, f):
    """``C_X dX = V^T W beta``."""
    for a in range(3):
        s = 0.0
        for r in range(21):
            s += (P[W + r] * V[r, a]) * beta[r]
        f[CX, a] = s


@njit(cache=True, error_model="numpy")
def _gravity_task(P, V, f):
    """``G_X = -V^T W gamma``."""
    for a in range(3):
        s = 0.0
        for r in range(21):
            s += (P[W + r] * V[r, a]) * _row_gravity(P, r)
        f[GX, a] = -s


@njit(cache=True, error_model="numpy")
def _friction_task(P, dx, dy, dphi, Jq, V, f):
    """``F_X = V_f^T B V_f dX``; the 9 friction rows are ``J_q`` (motors), ``W - J_q`` (elbows)
    and ``e_phi - W`` (platform joints)."""
    f[FX, 0], f[FX, 1], f[FX, 2] = 0.0, 0.0, 0.0
    for k in range(9):
        i = k % 3
        r0 = Jq[i, 0] if k < 3 else (V[18 + i, 0] - Jq[i, 0] if k < 6 else 0.0 - V[18 + i, 0])
        r1 = Jq[i, 1] if k < 3 else (V[18 + i, 1] - Jq[i, 1] if k < 6 else 0.0 - V[18 + i, 1])
        r2 = Jq[i, 2] if k < 3 else (V[18 + i, 2] - Jq[i, 2] if k < 6 else 1.0 - V[18 + i, 2])
        rate = P[BF + k] * (r0 * dx + r1 * dy + r2 * dphi)
        f[FX, 0] += r0 * rate
        f[FX, 1] += r1 * rate
        f[FX, 2] += r2 * rate


@njit(cache=True, error_model="numpy")
def task_row(G, P, X, dX, U, q, bits, mode, out, ws):
    """One configuration in task space; ``out`` (9,) receives ``M_X`` (row-major) or a 3-vector.

    ``q`` is computed by inverse kinematics when ``bits >= 0``, else read.
    ``U`` is ``tau`` (FORWARD, GENERALIZED) or ``ddX`` (INVERSE).
    """
    leg, Jq, Jx, V, beta, MX, M, f, VJ, aug, u, v = ws
    if not (_finite(X) and _finite(dX) and _finite(U)):
        return BAD_INPUT
    if bits >= 0:
        if not ik_row(G, X[0], X[1], X[2], bits, q):
            return OUTSIDE
    elif not _finite(q):
        return BAD_INPUT
    dx, dy, dphi = dX[0], dX[1], dX[2]
    rcx, rcy, res = _geometry(G, P, X[0], X[1], X[2], q, leg, Jq)
    _velocity_rows(G, P, rcx, rcy, leg, Jq, V)
    if mode == MASS or mode == FORWARD or mode == INVERSE:
        _mass_task(P, V, MX)
    if mode == CORIOLIS or mode == FORWARD or mode == INVERSE:
        _motion(G, P, dx, dy, dphi, rcx, rcy, leg, Jq, beta)
        _coriolis_task(P, V, beta, f)
    if mode == GRAVITY or mode == FORWARD or mode == INVERSE:
        _gravity_task(P, V, f)
    if mode == FRICTION or mode == FORWARD or mode == INVERSE or mode == GENERALIZED:
        _friction_task(P, dx, dy, dphi, Jq, V, f)
    n = 3
    if mode == MASS:
        n = 9
        for a in range(3):
            for b in range(3):
                out[3 * a + b] = MX[a, b]
    elif mode == CORIOLIS or mode == GRAVITY or mode == FRICTION:
        row = CX if mode == CORIOLIS else (GX if mode == GRAVITY else FX)
        for a in range(3):
            out[a] = f[row, a]
    elif mode == GENERALIZED or mode == FORWARD:
        for a in range(3):          # J_q^T tau - F_X (- C_X dX - G_X)
            u[a] = Jq[0, a] * U[0] + Jq[1, a] * U[1] + Jq[2, a] * U[2] - f[FX, a]
            if mode == FORWARD:
                u[a] = u[a] - f[CX, a] - f[GX, a]
        if mode == GENERALIZED:
            for a in range(3):
                out[a] = u[a]
        elif not _solve(MX, False, u, out, aug):
            return SINGULAR
    elif mode == INVERSE:
        for a in range(3):          # tau = J_q^{-T} (M_X ddX + C_X dX + G_X + F_X)
            u[a] = (MX[a, 0] * U[0] + MX[a, 1] * U[1] + MX[a, 2] * U[2]) + f[CX, a] + f[GX, a] + f[FX, a]
        if not _solve(Jq, True, u, out, aug):
            return SINGULAR
    for a in range(n):
        if not math.isfinite(out[a]):
            return SINGULAR
    return OK


@njit(cache=True, error_model="numpy")
def task_batch(G, P, X, dX, U, q, bits, mode, out):
    """:func:`task_row` over the rows of ``X, dX, U, q`` (n, 3) into ``out`` (n, 3 or 9).

    Returns the status of the first row that is refused, else :data:`OK`.
    """
    ws = _workspace()
    for k in range(X.shape[0]):
        st = task_row(G, P, X[k], dX[k], U[k], q[k], bits, mode, out[k], ws)
        if st != OK:
            return st
    return OK


@njit(cache=True, error_model="numpy")
def _task_rhs_row(G, P, x, tau, bits, q, out, ws):
    """``dx/dt = (dX, ddX)`` of the task-space state ``x = (X, dX)`` (6,)."""
    st = task_row(G, P, x[:3], x[3:], tau, q, bits, FORWARD, out[3:], ws)
    for j in range(3):
        out[j] = x[3 + j]
    return st


@njit(cache=True, error_model="numpy")
def task_rhs_batch(G, P, x, tau, bits, out):
    """Task-space right-hand side over the rows of ``x`` (n, 6) and ``tau`` (n, 3) into ``out`` (n, 6);
    ``q`` by inverse kinematics in the posture of ``bits`` (>= 0)."""
    ws = _workspace()
    q = np.empty(3)
    for k in range(x.shape[0]):
        st = _task_rhs_row(G, P, x[k], tau[k], bits, q, out[k], ws)
        if st != OK:
            return st
    return OK


@njit(cache=True, error_model="numpy")
def rk4_task(G, P, bits, tau, h, xs):
    """Classic RK4 of the task-space dynamics with constant torques ``tau`` (3,).

    ``xs`` (n + 1, 6) holds the initial state in row 0; rows 1..n receive the
    states after each step of ``h``, computed as :func:`dynamics.integrate.rk4_step`
    does (same operations in the same order).  Returns the number of steps
    completed: ``n``, or the index of the step whose right-hand side was refused.
    """
    ws = _workspace()
    q = np.empty(3)
    k1, k2, k3, k4, xt = np.empty(6), np.empty(6), np.empty(6), np.empty(6), np.empty(6)
    half = 0.5 * h
    sixth = h / 6.0
    n = xs.shape[0] - 1
    for k in range(n):
        x = xs[k]
        if _task_rhs_row(G, P, x, tau, bits, q, k1, ws) != OK:
            return k
        for j in range(6):
            xt[j] = x[j] + half * k1[j]
        if _task_rhs_row(G, P, xt, tau, bits, q, k2, ws) != OK:
            return k
        for j in range(6):
            xt[j] = x[j] + half * k2[j]
        if _task_rhs_row(G, P, xt, tau, bits, q, k3, ws) != OK:
            return k
        for j in range(6):
            xt[j] = x[j] + h * k3[j]
        if _task_rhs_row(G, P, xt, tau, bits, q, k4, ws) != OK:
            return k
        for j in range(6):
            xs[k + 1, j] = x[j] + sixth * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    return n


# ----------------------------------------------------------------------------- joint space
@njit(cache=True, error_model="numpy")
def joint_row(G, P, q, dq, X, U, tol, mode, out, ws):
    """One configuration in joint space; ``out`` (9,) receives ``M`` (row-major) or a 3-vector.

    ``U`` is ``tau`` (FORWARD) or ``ddq`` (INVERSE).  The pose ``X`` must close
    the loops of ``q`` to ``tol`` (``inf``: no check).
    """
    leg, Jq, Jx, V, beta, MX, M, f, VJ, aug, u, dX = ws
    if not (_finite(q) and _finite(dq) and _finite(X) and _finite(U)):
        return BAD_INPUT
    rcx, rcy, res = _geometry(G, P, X[0], X[1], X[2], q, leg, Jq)
    if not res <= tol:
        return NOT_ASSEMBLED
    if not _inverse(Jq, Jx, aug):
        return SINGULAR
    for a in range(3):                                  # dX = J_x dq
        dX[a] = Jx[a, 0] * dq[0] + Jx[a, 1] * dq[1] + Jx[a, 2] * dq[2]
    dx, dy, dphi = dX[0], dX[1], dX[2]
    _velocity_rows(G, P, rcx, rcy, leg, Jq, V)
    need_m = mode == MASS or mode == FORWARD or mode == INVERSE
    need_c = mode == CORIOLIS or mode == FORWARD or mode == INVERSE
    need_g = mode == GRAVITY or mode == FORWARD or mode == INVERSE
    need_f = mode == FRICTION or mode == FORWARD or mode == INVERSE
    if need_m:                                          # M = (V J_x)^T W (V J_x)
        for r in range(21):
            for b in range(3):
                VJ[r, b] = V[r, 0] * Jx[0, b] + V[r, 1] * Jx[1, b] + V[r, 2] * Jx[2, b]
        for a in range(3):
            for b in range(3):
                s = 0.0
                for r in range(21):
                    s += VJ[r, a] * (P[W + r] * VJ[r, b])
                M[a, b] = s
    if need_c:                                          # C dq = J_x^T V^T W (beta + V ddX0)
        _motion(G, P, dx, dy, dphi, rcx, rcy, leg, Jq, beta)
        for a in range(3):
            u[a] = -(Jx[a, 0] * leg[DDQ0, 0] + Jx[a, 1] * leg[DDQ0, 1] + Jx[a, 2] * leg[DDQ0, 2])
        for r in range(21):
            beta[r] = beta[r] + (V[r, 0] * u[0] + V[r, 1] * u[1] + V[r, 2] * u[2])
        _coriolis_task(P, V, beta, f)
    if need_g:
        _gravity_task(P, V, f)
    if need_f:
        _friction_task(P, dx, dy, dphi, Jq, V, f)
    for a in range(3):                                  # J_x^T (.)
        if need_c:
            f[CJ, a] = Jx[0, a] * f[CX, 0] + Jx[1, a] * f[CX, 1] + Jx[2, a] * f[CX, 2]
        if need_g:
            f[GJ, a] = Jx[0, a] * f[GX, 0] + Jx[1, a] * f[GX, 1] + Jx[2, a] * f[GX, 2]
        if need_f:
            f[FJ, a] = Jx[0, a] * f[FX, 0] + Jx[1, a] * f[FX, 1] + Jx[2, a] * f[FX, 2]
    n = 3
    if mode == MASS:
        n = 9
        for a in range(3):
            for b in range(3):
                out[3 * a + b] = M[a, b]
    elif mode == CORIOLIS or mode == GRAVITY or mode == FRICTION:
        row = CJ if mode == CORIOLIS else (GJ if mode == GRAVITY else FJ)
        for a in range(3):
            out[a] = f[row, a]
    elif mode == FORWARD:                               # ddq = M^{-1} (tau - C dq - G - F)
        for a in range(3):
            u[a] = U[a] - f[CJ, a] - f[GJ, a] - f[FJ, a]
        if not _solve(M, False, u, out, aug):
            return SINGULAR
    elif mode == INVERSE:                               # tau = M ddq + C dq + G + F
        for a in range(3):
            out[a] = (M[a, 0] * U[0] + M[a, 1] * U[1] + M[a, 2] * U[2]) + f[CJ, a] + f[GJ, a] + f[FJ, a]
    for a in range(n):
        if not math.isfinite(out[a]):
            return SINGULAR
    return OK


@njit(cache=True, error_model="numpy")
def joint_batch(G, P, q, dq, X, U, tol, mode, out):
    """:func:`joint_row` over the rows of ``q, dq, X, U`` (n, 3) into ``out`` (n, 3 or 9)."""
    ws = _workspace()
    for k in range(q.shape[0]):
        st = joint_row(G, P, q[k], dq[k], X[k], U[k], tol, mode, out[k], ws)
        if st != OK:
            return st
    return OK


@njit(cache=True, error_model="numpy")
def joint_rhs_batch(G, P, x, X, tau, tol, out):
    """Joint-space right-hand side (eq. 7): rows of ``x = (q, dq)`` (n, 6), poses ``X`` and torques
    ``tau`` (n, 3) into ``out = (dq, ddq)`` (n, 6)."""
    ws = _workspace()
    for k in range(x.shape[0]):
        st = joint_row(G, P, x[k, :3], x[k, 3:], X[k], tau[k], tol, FORWARD, out[k, 3:], ws)
        if st != OK:
            return st
        for j in range(3):
            out[k, j] = x[k, 3 + j]
    return OK


@njit(cache=True, error_model="numpy")
def computed_torque_batch(G, P, gains, q, dq, X, q_d, dq_d, ddq_d, tol, out):
    """Computed torque ``M (ddq_d + K_d (dq_d - dq) + K_p wrap(q_d - q)) + C dq + G + F`` over the
    rows of the (n, 3) arrays; ``gains`` (6,) is ``(kp, kd)``."""
    ws = _workspace()
    v = np.empty(3)
    for k in range(q.shape[0]):
        if not (_finite(q_d[k]) and _finite(dq_d[k]) and _finite(ddq_d[k])):
            return BAD_INPUT
        for i in range(3):
            v[i] = ddq_d[k, i] + gains[3 + i] * (dq_d[k, i] - dq[k, i]) + gains[i] * _wrap(q_d[k, i] - q[k, i])
        st = joint_row(G, P, q[k], dq[k], X[k], v, tol, INVERSE, out[k], ws)
        if st != OK:
            return st
    return OK


# ----------------------------------------------------------------------------- circle reference
# The time law and geometry of :class:`dynamics.trajectory.CircleTrajectory` (its numpy code is the
# reference, ``CircleTrajectory._reference_task`` / ``_reference_joint``), evaluated with scalar
# code in the same order of operations.  Packed trajectory ``C`` (7,), built by :func:`pack_circle`.
#: offsets in the packed circle ``C``
CCX, CCY, CRAD, CPHI, COMEGA, CRAMP, CSTART = 0, 1, 2, 3, 4, 5, 6


def pack_circle(center, radius, phi, omega, ramp_time, start) -> np.ndarray:
    """The packed circle ``C`` (7,): centre (x, y), radius, orientation, cruise rate ``Omega``,
    ramp time, start angle."""
    return np.array([center[0], center[1], radius, phi, omega, ramp_time, start], dtype=np.float64)


@njit(cache=True, error_model="numpy")
def ik_solver_row(G, x, y, phi, bits, q):
    """Inverse kinematics of one pose with the operations of :func:`solver.ik` (its compiled
    ``ik_batch``), so the angles are that function's to the last bit; writes ``q`` (3,) and returns
    False if a leg cannot reach (``solver.ik`` returns NaN there).  :func:`ik_row` groups the sums
    differently (it is the dynamics kernels' own inverse kinematics)."""
    c, s = math.cos(phi), math.sin(phi)
    for i in range(3):
        bx, by = G[PLAT + 2 * i], G[PLAT + 2 * i + 1]
        dx = x + c * bx - s * by - G[MOT + 2 * i]
        dy = y + s * bx + c * by - G[MOT + 2 * i + 1]
        rho2 = dx * dx + dy * dy
        rho = math.sqrt(rho2)
        if rho == 0.0:
            return False
        l1, l2 = G[L1 + i], G[L2 + i]
        ca = (l1 * l1 + rho2 - l2 * l2) / (2.0 * l1 * rho)
        if not abs(ca) <= 1.0 + 1e-12:
            return False
        alpha = math.acos(min(1.0, max(-1.0, ca)))
        sign = 1.0 - 2.0 * ((bits >> i) & 1)
        q[i] = math.pi - ((math.pi - (math.atan2(dy, dx) - sign * alpha)) % TWO_PI) + 0.0
    return True


@njit(cache=True, error_model="numpy")
def circle_task_row(C, t, X, dX, ddX):
    """Pose, rate and acceleration of the circle at time ``t`` (finite) into ``X, dX, ddX`` (3,)."""
    W, Tr, start = C[COMEGA], C[CRAMP], C[CSTART]
    if Tr == 0.0:
        theta = start + W * max(t, 0.0)
        dth = W if t >= 0 else 0.0
        ddth = 0.0
    else:
        u = min(max(t / Tr, 0.0), 1.0)
        if t < Tr:
            S = u ** 4.0 * (2.5 - 3.0 * u + u * u)           # integral of s
            s = u ** 3.0 * (10.0 - 15.0 * u + 6.0 * u * u)
            ds = 30.0 * u * u * (1.0 - u) ** 2.0
            theta = start + W * Tr * S
            dth = W * s
            ddth = W * ds / Tr
        else:
            theta = start + W * (t - 0.5 * Tr)
            dth = W
            ddth = 0.0
    c, s_ = math.cos(theta), math.sin(theta)
    r = C[CRAD]
    X[0] = C[CCX] + r * c
    X[1] = C[CCY] + r * s_
    X[2] = C[CPHI]
    dX[0] = -r * s_ * dth
    dX[1] = r * c * dth
    dX[2] = 0.0
    dth2 = dth ** 2.0
    ddX[0] = -r * s_ * ddth - r * c * dth2
    ddX[1] = r * c * ddth - r * s_ * dth2
    ddX[2] = 0.0


@njit(cache=True, error_model="numpy")
def circle_joint_row(G, P, C, bits, t, X, dX, ddX, q, dq, ddq, leg, Jq, beta):
    """Task- and joint-space reference at ``t``: ``X, dX, ddX`` as :func:`circle_task_row`,
    ``q = g_j(X)`` (solver's IK), ``dq = J_q dX``, ``ddq = J_q ddX + ddq_0(X, dX)``.

    ``P`` only fills the unused centre-of-mass rows of ``beta``; ``leg, Jq, beta`` are work arrays.
    Returns :data:`OK`, :data:`BAD_INPUT` (``t`` not finite) or :data:`OUTSIDE` (no IK solution).
    """
    if not math.isfinite(t):
        return BAD_INPUT
    circle_task_row(C, t, X, dX, ddX)
    if not ik_solver_row(G, X[0], X[1], X[2], bits, q):
        return OUTSIDE
    rcx, rcy, res = _geometry(G, P, X[0], X[1], X[2], q, leg, Jq)
    _motion(G, P, dX[0], dX[1], dX[2], rcx, rcy, leg, Jq, beta)
    for i in range(3):
        dq[i] = leg[DQ, i]
        ddq[i] = (Jq[i, 0] * ddX[0] + Jq[i, 1] * ddX[1] + Jq[i, 2] * ddX[2]) + leg[DDQ0, i]
    for i in range(3):
        if not (math.isfinite(dq[i]) and math.isfinite(ddq[i])):
            return SINGULAR
    return OK


@njit(cache=True, error_model="numpy")
def circle_batch(G, P, C, bits, t, joint, X, dX, ddX, q, dq, ddq):
    """The circle reference at the times ``t`` (n,) into the (n, 3) arrays; the joint-space part
    only when ``joint``.  Returns the status of the first row refused, else :data:`OK`."""
    ws = _workspace()
    leg, Jq, beta = ws[0], ws[1], ws[4]
    for k in range(t.shape[0]):
        if not math.isfinite(t[k]):
            return BAD_INPUT
        if joint:
            st = circle_joint_row(G, P, C, bits, t[k], X[k], dX[k], ddX[k], q[k], dq[k], ddq[k], leg, Jq, beta)
            if st != OK:
                return st
        else:
            circle_task_row(C, t[k], X[k], dX[k], ddX[k])
    return OK


# ----------------------------------------------------------------------------- FMU slave steps
# One compiled call per communication step of the plant and the controller FMUs
# (fmu_src/RRRPlant.py, fmu_src/ComputedTorqueController.py).  ``K`` is the slave's packed
# constants: ``G`` (18,) then ``P`` (40,), then for the controller the gains (6,) and the circle (7,).
KG, KP, KGAIN, KC = 0, 18, 58, 64


@njit(cache=True, error_model="numpy")
def _energy(G, P, x, y, phi, dx, dy, dphi, rcx, rcy, leg):
    """Kinetic (body by body, ``1/2 sum w v^2``) plus gravitational potential energy of a
    configuration whose per-leg table ``leg`` holds the rates ``dq`` (after :func:`_geometry`)."""
    gx, gy = P[GRAV], P[GRAV + 1]
    w = dphi
    v0, v1 = dx - w * rcy, dy + w * rcx
    ke = P[W] * v0 * v0 + P[W + 1] * v1 * v1 + P[W + 2] * w * w
    pe = P[W] * ((x + rcx) * gx + (y + rcy) * gy)
    for i in range(3):
        l1, l2 = G[L1 + i], G[L2 + i]
        rp, sd = P[RP + i], P[RD + i] / l2
        cq, sq, rbx, rby = leg[CQ, i], leg[SQ, i], leg[RBX, i], leg[RBY, i]
        lx, ly, dq = leg[LX, i], leg[LY, i], leg[DQ, i]
        vdx, vdy = -l1 * sq * dq, l1 * cq * dq
        dlx, dly = (dx - dphi * rby) - vdx, (dy + dphi * rbx) - vdy
        px, py = -rp * sq * dq, rp * cq * dq
        ux, uy = vdx + sd * dlx, vdy + sd * dly
        om = (lx * dly - ly * dlx) / l2 ** 2
        ke += (P[W + 3 + i] * px * px + P[W + 6 + i] * py * py + P[W + 9 + i] * dq * dq
               + P[W + 12 + i] * ux * ux + P[W + 15 + i] * uy * uy + P[W + 18 + i] * om * om)
        mx, my = G[MOT + 2 * i], G[MOT + 2 * i + 1]
        dxp, dyp = mx + l1 * cq, my + l1 * sq                      # elbow D_i
        pe += P[W + 3 + i] * ((mx + rp * cq) * gx + (my + rp * sq) * gy)
        pe += P[W + 12 + i] * ((dxp + sd * lx) * gx + (dyp + sd * ly) * gy)
    return 0.5 * ke - pe


@njit(cache=True, error_model="numpy")
def plant_outputs(K, bits, x, out, ws):
    """Sensor outputs of the task-space state ``x`` (6,): ``out[6:9] = q`` (solver's IK),
    ``out[9:12] = dq = J_q dX``, ``out[12]`` the total energy.  :data:`OUTSIDE` if the pose has no
    inverse kinematics in the posture, :data:`SINGULAR` for a non-finite output, else :data:`OK`."""
    G, P = K[KG:KP], K[KP:KGAIN]
    leg, Jq = ws[0], ws[1]
    q = out[6:9]
    if not (_finite(x) and ik_solver_row(G, x[0], x[1], x[2], bits, q)):
        return OUTSIDE
    rcx, rcy, res = _geometry(G, P, x[0], x[1], x[2], q, leg, Jq)
    for i in range(3):
        d = Jq[i, 0] * x[3] + Jq[i, 1] * x[4] + Jq[i, 2] * x[5]
        leg[DQ, i] = d
        out[9 + i] = d
    out[12] = _energy(G, P, x[0], x[1], x[2], x[3], x[4], x[5], rcx, rcy, leg)
    for j in range(13):
        if not math.isfinite(out[j]):
            return SINGULAR
    return OK


@njit(cache=True, error_model="numpy")
def plant_step(K, bits, tau1, tau2, tau3, h, n, x, out):
    """The plant FMU's doStep: ``n`` RK4 steps of ``h`` of the task-space dynamics from ``x`` (6,)
    with the torques held (as :func:`rk4_task`), then :func:`plant_outputs`.  ``out`` (13,):
    the new state (6,), ``q``, ``dq``, energy; ``x`` is not modified (``n = 0``: the outputs of
    ``x``).  Returns :data:`OK`, or
    :data:`BAD_INPUT` if a Runge-Kutta stage was refused (left the tool space...), or the status of
    :func:`plant_outputs`."""
    G, P = K[KG:KP], K[KP:KGAIN]
    xs = np.empty((n + 1, 6))
    tau = np.empty(3)
    tau[0], tau[1], tau[2] = tau1, tau2, tau3
    for j in range(6):
        xs[0, j] = x[j]
    if rk4_task(G, P, bits, tau, h, xs) != n:
        return BAD_INPUT
    for j in range(6):
        out[j] = xs[n, j]
    return plant_outputs(K, bits, out[:6], out, _workspace())


@njit(cache=True, error_model="numpy")
def controller_step(K, bits, t, q1, q2, q3, dq1, dq2, dq3, x, y, phi, tol, out):
    """The computed-torque FMU's doStep at ``t``: the circle reference at ``t``, ``q_X = g_j(X)``
    unwrapped next to ``q``, and ``tau = M(q_X, X) v + C dq + G + F`` with
    ``v = ddq_d + K_d (dq_d - dq) + K_p wrap(q_d - q)`` (:func:`joint_row`, INVERSE).

    ``out`` (9,): ``tau``, ``X_d``, ``q_d``.  Returns :data:`OK` or the first refusal (the caller
    then runs the numpy code, which raises the documented error).
    """
    G, P, gains, C = K[KG:KP], K[KP:KGAIN], K[KGAIN:KC], K[KC:KC + 7]
    ws = _workspace()
    buf = np.empty(30)
    Xd, dXd, ddXd, qd, dqd, ddqd = buf[0:3], buf[3:6], buf[6:9], buf[9:12], buf[12:15], buf[15:18]
    q, dq, X, v = buf[18:21], buf[21:24], buf[24:27], buf[27:30]
    out9 = np.empty(9)
    tau = out9[0:3]
    st = circle_joint_row(G, P, C, bits, t, Xd, dXd, ddXd, qd, dqd, ddqd, ws[0], ws[1], ws[4])
    if st != OK:
        return st
    q[0], q[1], q[2] = q1, q2, q3
    dq[0], dq[1], dq[2] = dq1, dq2, dq3
    X[0], X[1], X[2] = x, y, phi
    if not (_finite(q) and _finite(dq) and _finite(X)):
        return BAD_INPUT
    qx = out9[3:6]
    if not ik_solver_row(G, x, y, phi, bits, qx):
        return OUTSIDE
    for i in range(3):
        qx[i] = q[i] + _wrap(qx[i] - q[i])              # q_X next to q (2 pi turns)
        v[i] = ddqd[i] + gains[3 + i] * (dqd[i] - dq[i]) + gains[i] * _wrap(qd[i] - q[i])
    st = joint_row(G, P, qx, dq, X, v, tol, INVERSE, out9, ws)
    if st != OK:
        return st
    for i in range(3):
        out[i] = tau[i]
        out[3 + i] = Xd[i]
        out[6 + i] = qd[i]
    return OK
