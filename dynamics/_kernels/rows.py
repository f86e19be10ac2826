r"""The dynamics of one configuration, compiled: loop geometry, body rows, task- and joint-space terms.

The derivation is in :mod:`dynamics.model` (and :mod:`dynamics.geometry` for the kinematics).
Every formula there -- the loop geometry and ``J_q``, the 21 body velocity rows ``V``, the
velocity-product accelerations ``beta``, the nine friction rows, ``M_X = V^T W V``,
``C_X dX = V^T W beta``, ``G_X = -V^T W gamma``, ``F_X = V_f^T B V_f dX`` and the joint-space
forms ``M = (V J_x)^T W (V J_x)``, ``C dq = J_x^T V^T W (beta + V ddX_0)``, ``G = J_x^T G_X``,
``F = J_x^T F_X`` -- is evaluated for one configuration with scalar loops over small fixed-size
work arrays.  :func:`task_row` and :func:`joint_row` return one term (``mode``); the batch entry
points run them over rows ``(n, 3)`` and return :data:`OK` or the refusal code of the first row
refused.  A single configuration is a batch of one, so both go through the same code.

Why compiled: the same formulas in numpy spend ~150 array operations on arrays of 3 to 63
numbers, ~200 us per configuration, while the plant and the controller evaluate the dynamics at
every RK4 stage and every controller period (1 ms).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from solver._kernels.kinematics import leg_row
from solver._kernels.linalg import inverse3, solve3

from .base import code, finite, ik_arm, new_workspace
from .layout import (ARM_L1, ARM_L2, ARM_MOTORS, ARM_PLATFORM, BAD_INPUT, BODY_COM_DISTAL, BODY_COM_PLATFORM,
                     BODY_COM_PROXIMAL, BODY_FRICTION, BODY_GRAVITY, BODY_WEIGHTS, CORIOLIS, FORCE_CJ, FORCE_CX,
                     FORCE_FJ, FORCE_FX, FORCE_GJ, FORCE_GX, FORWARD, FRICTION, GENERALIZED, GRAVITY, INVERSE,
                     LEG_COS_Q, LEG_DDQ0, LEG_DEN, LEG_DQ, LEG_LX, LEG_LY, LEG_RBX, LEG_RBY, LEG_SIN_Q, MASS,
                     N_FRICTION, N_ROWS, NOT_ASSEMBLED, OK, OUTSIDE, ROW_DISTAL_ROT, ROW_DISTAL_X, ROW_DISTAL_Y,
                     ROW_PLATFORM_ROT, ROW_PLATFORM_X, ROW_PLATFORM_Y, ROW_PROXIMAL_ROT, ROW_PROXIMAL_X,
                     ROW_PROXIMAL_Y, SINGULAR)


# ----------------------------------------------------------------------------- kinematics
@njit(cache=True, error_model="numpy")
def geometry_row(arm, bodies, x, y, phi, q, leg, Jq):
    """Per-leg table (cos q, sin q, R b, L = A - D, den = l1 L.n) and ``J_q = dq/dX``, from the
    kinematics core's :func:`solver._kernels.kinematics.leg_row`.

    Returns ``(R c)_x, (R c)_y`` (platform centre-of-mass offset) and the loop residual
    ``max_i |F_i| / l2_i^2`` (NaN propagates).
    """
    c, s = math.cos(phi), math.sin(phi)
    res = 0.0
    for i in range(3):
        cq, sq, rbx, rby, lx, ly, lr, den = leg_row(x, y, c, s, q[i], arm[ARM_MOTORS + 2 * i],
                                                    arm[ARM_MOTORS + 2 * i + 1], arm[ARM_L1 + i],
                                                    arm[ARM_PLATFORM + 2 * i], arm[ARM_PLATFORM + 2 * i + 1])
        leg[LEG_COS_Q, i], leg[LEG_SIN_Q, i], leg[LEG_RBX, i], leg[LEG_RBY, i] = cq, sq, rbx, rby
        leg[LEG_LX, i], leg[LEG_LY, i], leg[LEG_DEN, i] = lx, ly, den
        Jq[i, 0] = lx / den
        Jq[i, 1] = ly / den
        Jq[i, 2] = lr / den
        l2sq = arm[ARM_L2 + i] ** 2
        r = abs(lx ** 2 + ly ** 2 - l2sq) / l2sq
        if not r <= res:
            res = r
    cx, cy = bodies[BODY_COM_PLATFORM], bodies[BODY_COM_PLATFORM + 1]
    return c * cx - s * cy, s * cx + c * cy, res


@njit(cache=True, error_model="numpy")
def _velocity_rows(arm, bodies, rcx, rcy, leg, Jq, V):
    """The 21 body velocity rows ``V`` (21, 3) w.r.t. ``dX`` (the distal rotation rows are the
    distal link rates ``W``)."""
    V[ROW_PLATFORM_X, 0], V[ROW_PLATFORM_X, 1], V[ROW_PLATFORM_X, 2] = 1.0, 0.0, -rcy
    V[ROW_PLATFORM_Y, 0], V[ROW_PLATFORM_Y, 1], V[ROW_PLATFORM_Y, 2] = 0.0, 1.0, rcx
    V[ROW_PLATFORM_ROT, 0], V[ROW_PLATFORM_ROT, 1], V[ROW_PLATFORM_ROT, 2] = 0.0, 0.0, 1.0
    for i in range(3):
        l1, l2 = arm[ARM_L1 + i], arm[ARM_L2 + i]
        rp, sd, l2sq = bodies[BODY_COM_PROXIMAL + i], bodies[BODY_COM_DISTAL + i] / l2, l2 ** 2
        cq, sq, lx, ly = leg[LEG_COS_Q, i], leg[LEG_SIN_Q, i], leg[LEG_LX, i], leg[LEG_LY, i]
        for j in range(3):
            jq = Jq[i, j]
            V[ROW_PROXIMAL_X + i, j] = (-rp * sq) * jq
            V[ROW_PROXIMAL_Y + i, j] = (rp * cq) * jq
            V[ROW_PROXIMAL_ROT + i, j] = jq
            vax = 1.0 if j == 0 else (-leg[LEG_RBY, i] if j == 2 else 0.0)     # v_A = dP + dphi E R b
            vay = 1.0 if j == 1 else (leg[LEG_RBX, i] if j == 2 else 0.0)
            vdx = (-l1 * sq) * jq
            vdy = (l1 * cq) * jq
            dlx, dly = vax - vdx, vay - vdy
            V[ROW_DISTAL_X + i, j] = vdx + sd * dlx
            V[ROW_DISTAL_Y + i, j] = vdy + sd * dly
            V[ROW_DISTAL_ROT + i, j] = (lx * dly - ly * dlx) / l2sq


@njit(cache=True, error_model="numpy")
def motion_row(arm, bodies, dx, dy, dphi, rcx, rcy, leg, Jq, beta):
    """Motor rates ``dq``, their velocity-product accelerations ``ddq0`` (into ``leg``) and the 21
    body accelerations ``beta`` at ``ddX = 0``."""
    w2 = dphi * dphi
    beta[ROW_PLATFORM_X], beta[ROW_PLATFORM_Y], beta[ROW_PLATFORM_ROT] = -w2 * rcx, -w2 * rcy, 0.0
    for i in range(3):
        l1, l2 = arm[ARM_L1 + i], arm[ARM_L2 + i]
        rp, sd, l2sq = bodies[BODY_COM_PROXIMAL + i], bodies[BODY_COM_DISTAL + i] / l2, l2 ** 2
        cq, sq, rbx, rby = leg[LEG_COS_Q, i], leg[LEG_SIN_Q, i], leg[LEG_RBX, i], leg[LEG_RBY, i]
        lx, ly, den = leg[LEG_LX, i], leg[LEG_LY, i], leg[LEG_DEN, i]
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
        leg[LEG_DQ, i], leg[LEG_DDQ0, i] = dq, ddq0
        beta[ROW_PROXIMAL_X + i] = rp * (-sq * ddq0 - cq * dq2)
        beta[ROW_PROXIMAL_Y + i] = rp * (cq * ddq0 - sq * dq2)
        beta[ROW_PROXIMAL_ROT + i] = ddq0
        beta[ROW_DISTAL_X + i] = adx + sd * ddlx
        beta[ROW_DISTAL_Y + i] = ady + sd * ddly
        beta[ROW_DISTAL_ROT + i] = (lx * ddly - ly * ddlx) / l2sq


# ----------------------------------------------------------------------------- task-space terms
@njit(cache=True, error_model="numpy")
def _mass_task(bodies, V, MX):
    """``M_X = V^T W V``: the weighted Gram matrix of ``V``'s columns, W the bodies' row weights.

    Each entry is ``sum_r V[r, a] (w_r V[r, b])`` summed over the rows in order; the nine sums run side
    by side in one pass (nine independent chains of additions instead of one after another: the
    same operations in the same order for each entry, so the same bits; measured in a compiled loop,
    this term 0.11 -> 0.04 us, with the Coriolis and gravity terms written the same way 0.31 -> 0.12 us,
    the whole task-space right-hand side 0.87 -> 0.60 us)."""
    m00 = m01 = m02 = m10 = m11 = m12 = m20 = m21 = m22 = 0.0
    for r in range(N_ROWS):
        w = bodies[BODY_WEIGHTS + r]
        v0, v1, v2 = V[r, 0], V[r, 1], V[r, 2]
        w0, w1, w2 = w * v0, w * v1, w * v2
        m00 += v0 * w0
        m01 += v0 * w1
        m02 += v0 * w2
        m10 += v1 * w0
        m11 += v1 * w1
        m12 += v1 * w2
        m20 += v2 * w0
        m21 += v2 * w1
        m22 += v2 * w2
    MX[0, 0], MX[0, 1], MX[0, 2] = m00, m01, m02
    MX[1, 0], MX[1, 1], MX[1, 2] = m10, m11, m12
    MX[2, 0], MX[2, 1], MX[2, 2] = m20, m21, m22


@njit(cache=True, error_model="numpy")
def _row_gravity(bodies, r):
    """Gravity acceleration ``gamma_r`` of velocity row ``r`` (zero on rotation rows)."""
    if r == ROW_PLATFORM_X or (ROW_PROXIMAL_X <= r < ROW_PROXIMAL_Y) or (ROW_DISTAL_X <= r < ROW_DISTAL_Y):
        return bodies[BODY_GRAVITY]
    if r == ROW_PLATFORM_Y or (ROW_PROXIMAL_Y <= r < ROW_PROXIMAL_ROT) or (ROW_DISTAL_Y <= r < ROW_DISTAL_ROT):
        return bodies[BODY_GRAVITY + 1]
    return 0.0


@njit(cache=True, error_model="numpy")
def _coriolis_task(bodies, V, beta, f):
    """``C_X dX = V^T W beta`` (the three sums side by side, each over the rows in order)."""
    s0 = s1 = s2 = 0.0
    for r in range(N_ROWS):
        w, b = bodies[BODY_WEIGHTS + r], beta[r]
        s0 += (w * V[r, 0]) * b
        s1 += (w * V[r, 1]) * b
        s2 += (w * V[r, 2]) * b
    f[FORCE_CX, 0], f[FORCE_CX, 1], f[FORCE_CX, 2] = s0, s1, s2


@njit(cache=True, error_model="numpy")
def _gravity_task(bodies, V, f):
    """``G_X = -V^T W gamma`` (the three sums side by side, each over the rows in order)."""
    s0 = s1 = s2 = 0.0
    for r in range(N_ROWS):
        w, g = bodies[BODY_WEIGHTS + r], _row_gravity(bodies, r)
        s0 += (w * V[r, 0]) * g
        s1 += (w * V[r, 1]) * g
        s2 += (w * V[r, 2]) * g
    f[FORCE_GX, 0], f[FORCE_GX, 1], f[FORCE_GX, 2] = -s0, -s1, -s2


@njit(cache=True, error_model="numpy")
def _friction_task(bodies, dx, dy, dphi, Jq, V, f):
    """``F_X = V_f^T B V_f dX``; the 9 friction rows are ``J_q`` (motors), ``W - J_q`` (elbows)
    and ``e_phi - W`` (platform joints)."""
    f[FORCE_FX, 0], f[FORCE_FX, 1], f[FORCE_FX, 2] = 0.0, 0.0, 0.0
    for k in range(N_FRICTION):
        i = k % 3
        w = ROW_DISTAL_ROT + i
        r0 = Jq[i, 0] if k < 3 else (V[w, 0] - Jq[i, 0] if k < 6 else 0.0 - V[w, 0])
        r1 = Jq[i, 1] if k < 3 else (V[w, 1] - Jq[i, 1] if k < 6 else 0.0 - V[w, 1])
        r2 = Jq[i, 2] if k < 3 else (V[w, 2] - Jq[i, 2] if k < 6 else 1.0 - V[w, 2])
        rate = bodies[BODY_FRICTION + k] * (r0 * dx + r1 * dy + r2 * dphi)
        f[FORCE_FX, 0] += r0 * rate
        f[FORCE_FX, 1] += r1 * rate
        f[FORCE_FX, 2] += r2 * rate


@njit(cache=True, error_model="numpy")
def _copy_term(mode, matrix, f, first_force, out):
    """Write the term of a MASS (``matrix`` row-major, 9 entries), CORIOLIS, GRAVITY or FRICTION
    (a row of the force table ``f``: the one of ``first_force`` + 0, 1, 2) evaluation into ``out``;
    returns how many entries it wrote (0 for the other modes)."""
    if mode == MASS:
        for a in range(3):
            for b in range(3):
                out[3 * a + b] = matrix[a, b]
        return 9
    if mode == CORIOLIS or mode == GRAVITY or mode == FRICTION:
        row = first_force + (0 if mode == CORIOLIS else (1 if mode == GRAVITY else 2))
        for a in range(3):
            out[a] = f[row, a]
    return 3


@njit(cache=True, error_model="numpy")
def task_row(arm, bodies, X, dX, U, q, bits, mode, out, ws):
    """One configuration in task space; ``out`` (9,) receives ``M_X`` (row-major) or a 3-vector.

    ``q`` is computed by inverse kinematics when ``bits >= 0``, else read.
    ``U`` is ``tau`` (FORWARD, GENERALIZED) or ``ddX`` (INVERSE).  Returns a status.
    """
    leg, Jq, Jx, V, beta, MX, M, f, VJ, aug, u, v = ws
    if not (finite(X) and finite(dX) and finite(U)):
        return BAD_INPUT
    if bits >= 0:
        if not ik_arm(arm, X[0], X[1], X[2], bits, q):
            return OUTSIDE
    elif not finite(q):
        return BAD_INPUT
    dx, dy, dphi = dX[0], dX[1], dX[2]
    rcx, rcy, res = geometry_row(arm, bodies, X[0], X[1], X[2], q, leg, Jq)
    _velocity_rows(arm, bodies, rcx, rcy, leg, Jq, V)
    if mode == MASS or mode == FORWARD or mode == INVERSE:
        _mass_task(bodies, V, MX)
    if mode == CORIOLIS or mode == FORWARD or mode == INVERSE:
        motion_row(arm, bodies, dx, dy, dphi, rcx, rcy, leg, Jq, beta)
        _coriolis_task(bodies, V, beta, f)
    if mode == GRAVITY or mode == FORWARD or mode == INVERSE:
        _gravity_task(bodies, V, f)
    if mode == FRICTION or mode == FORWARD or mode == INVERSE or mode == GENERALIZED:
        _friction_task(bodies, dx, dy, dphi, Jq, V, f)
    n = _copy_term(mode, MX, f, FORCE_CX, out)
    if mode == GENERALIZED or mode == FORWARD:
        for a in range(3):          # J_q^T tau - F_X (- C_X dX - G_X)
            u[a] = Jq[0, a] * U[0] + Jq[1, a] * U[1] + Jq[2, a] * U[2] - f[FORCE_FX, a]
            if mode == FORWARD:
                u[a] = u[a] - f[FORCE_CX, a] - f[FORCE_GX, a]
        if mode == GENERALIZED:
            for a in range(3):
                out[a] = u[a]
        elif not solve3(MX, u, out):
            return SINGULAR
    elif mode == INVERSE:
        for a in range(3):          # tau = J_q^{-T} (M_X ddX + C_X dX + G_X + F_X)
            u[a] = ((MX[a, 0] * U[0] + MX[a, 1] * U[1] + MX[a, 2] * U[2]) + f[FORCE_CX, a] + f[FORCE_GX, a]
                    + f[FORCE_FX, a])
        for a in range(3):
            for k in range(3):
                aug[a, k] = Jq[k, a]
        if not solve3(aug, u, out):
            return SINGULAR
    return OK if finite(out[:n]) else SINGULAR


@njit(cache=True, error_model="numpy")
def task_batch(arm, bodies, X, dX, U, q, bits, mode, out):
    """:func:`task_row` over the rows of ``X, dX, U, q`` (n, 3) into ``out`` (n, 3 or 9)."""
    ws = new_workspace()
    for k in range(X.shape[0]):
        st = task_row(arm, bodies, X[k], dX[k], U[k], q[k], bits, mode, out[k], ws)
        if st != OK:
            return code(st, k)
    return OK


@njit(cache=True, error_model="numpy")
def task_rhs_row(ctx, t, x, out):
    """``dx/dt = (dX, ddX)`` of the task-space state ``x = (X, dX)`` (6,) into ``out``; ``ctx`` is
    ``(arm, bodies, bits, tau, q, ws)`` (torques held, ``t`` unused).  Returns ``(status, out)``."""
    arm, bodies, bits, tau, q, ws = ctx
    st = task_row(arm, bodies, x[:3], x[3:], tau, q, bits, FORWARD, out[3:], ws)
    for j in range(3):
        out[j] = x[3 + j]
    return st, out


@njit(cache=True, error_model="numpy")
def task_rhs_batch(arm, bodies, x, tau, bits, out):
    """Task-space right-hand side over the rows of ``x`` (n, 6) and ``tau`` (n, 3) into ``out`` (n, 6);
    ``q`` by inverse kinematics in the posture of ``bits`` (>= 0)."""
    ws = new_workspace()
    q = np.empty(3)
    for k in range(x.shape[0]):
        st, _ = task_rhs_row((arm, bodies, bits, tau[k], q, ws), 0.0, x[k], out[k])
        if st != OK:
            return code(st, k)
    return OK


@njit(cache=True, error_model="numpy")
def _mass_joint(bodies, V, Jx, VJ, M):
    """``M = (V J_x)^T W (V J_x)``, with ``V J_x`` into ``VJ`` (21, 3): :func:`_mass_task` of ``V J_x``."""
    for r in range(N_ROWS):
        for b in range(3):
            VJ[r, b] = V[r, 0] * Jx[0, b] + V[r, 1] * Jx[1, b] + V[r, 2] * Jx[2, b]
    _mass_task(bodies, VJ, M)


@njit(cache=False)
def _column_dot(Jx, a, f, row):
    """``(J_x^T f[row])_a``: column ``a`` of ``J_x`` dotted with a row of the force table."""
    return Jx[0, a] * f[row, 0] + Jx[1, a] * f[row, 1] + Jx[2, a] * f[row, 2]


# ----------------------------------------------------------------------------- joint space
@njit(cache=True, error_model="numpy")
def joint_row(arm, bodies, q, dq, X, U, tol, mode, out, ws):
    """One configuration in joint space; ``out`` (9,) receives ``M`` (row-major) or a 3-vector.

    ``U`` is ``tau`` (FORWARD) or ``ddq`` (INVERSE).  The pose ``X`` must close the loops of
    ``q`` to ``tol`` (``inf``: no check).  Returns a status.
    """
    leg, Jq, Jx, V, beta, MX, M, f, VJ, aug, u, dX = ws
    if not (finite(q) and finite(dq) and finite(X) and finite(U)):
        return BAD_INPUT
    rcx, rcy, res = geometry_row(arm, bodies, X[0], X[1], X[2], q, leg, Jq)
    if not res <= tol:
        return NOT_ASSEMBLED
    if not inverse3(Jq, Jx):
        return SINGULAR
    for a in range(3):                                  # dX = J_x dq
        dX[a] = Jx[a, 0] * dq[0] + Jx[a, 1] * dq[1] + Jx[a, 2] * dq[2]
    dx, dy, dphi = dX[0], dX[1], dX[2]
    _velocity_rows(arm, bodies, rcx, rcy, leg, Jq, V)
    need_m = mode == MASS or mode == FORWARD or mode == INVERSE
    need_c = mode == CORIOLIS or mode == FORWARD or mode == INVERSE
    need_g = mode == GRAVITY or mode == FORWARD or mode == INVERSE
    need_f = mode == FRICTION or mode == FORWARD or mode == INVERSE
    if need_m:
        _mass_joint(bodies, V, Jx, VJ, M)
    if need_c:                                          # C dq = J_x^T V^T W (beta + V ddX0)
        motion_row(arm, bodies, dx, dy, dphi, rcx, rcy, leg, Jq, beta)
        for a in range(3):
            u[a] = -(Jx[a, 0] * leg[LEG_DDQ0, 0] + Jx[a, 1] * leg[LEG_DDQ0, 1] + Jx[a, 2] * leg[LEG_DDQ0, 2])
        for r in range(N_ROWS):
            beta[r] = beta[r] + (V[r, 0] * u[0] + V[r, 1] * u[1] + V[r, 2] * u[2])
        _coriolis_task(bodies, V, beta, f)
    if need_g:
        _gravity_task(bodies, V, f)
    if need_f:
        _friction_task(bodies, dx, dy, dphi, Jq, V, f)
    for a in range(3):                                  # J_x^T (.)
        if need_c:
            f[FORCE_CJ, a] = _column_dot(Jx, a, f, FORCE_CX)
        if need_g:
            f[FORCE_GJ, a] = _column_dot(Jx, a, f, FORCE_GX)
        if need_f:
            f[FORCE_FJ, a] = _column_dot(Jx, a, f, FORCE_FX)
    n = _copy_term(mode, M, f, FORCE_CJ, out)
    if mode == FORWARD:                               # ddq = M^{-1} (tau - C dq - G - F)
        for a in range(3):
            u[a] = U[a] - f[FORCE_CJ, a] - f[FORCE_GJ, a] - f[FORCE_FJ, a]
        if not solve3(M, u, out):
            return SINGULAR
    elif mode == INVERSE:                               # tau = M ddq + C dq + G + F
        for a in range(3):
            out[a] = ((M[a, 0] * U[0] + M[a, 1] * U[1] + M[a, 2] * U[2]) + f[FORCE_CJ, a] + f[FORCE_GJ, a]
                      + f[FORCE_FJ, a])
    return OK if finite(out[:n]) else SINGULAR


@njit(cache=True, error_model="numpy")
def joint_batch(arm, bodies, q, dq, X, U, tol, mode, out):
    """:func:`joint_row` over the rows of ``q, dq, X, U`` (n, 3) into ``out`` (n, 3 or 9)."""
    ws = new_workspace()
    for k in range(q.shape[0]):
        st = joint_row(arm, bodies, q[k], dq[k], X[k], U[k], tol, mode, out[k], ws)
        if st != OK:
            return code(st, k)
    return OK


@njit(cache=True, error_model="numpy")
def joint_rhs_batch(arm, bodies, x, X, tau, tol, out):
    """Joint-space right-hand side (eq. 7): rows of ``x = (q, dq)`` (n, 6), poses ``X`` and torques
    ``tau`` (n, 3) into ``out = (dq, ddq)`` (n, 6)."""
    ws = new_workspace()
    for k in range(x.shape[0]):
        st = joint_row(arm, bodies, x[k, :3], x[k, 3:], X[k], tau[k], tol, FORWARD, out[k, 3:], ws)
        if st != OK:
            return code(st, k)
        for j in range(3):
            out[k, j] = x[k, 3 + j]
    return OK
