"""Compiled steps of the tracker (procedures 2-3) and of the baselines.

One call does a whole step (all DK solutions, the predictor, procedure 2 on
the map, the choice), so the per-step cost is the work, not Python overhead.
The Python classes in :mod:`solver.tracker` and :mod:`solver.baselines` check
inputs, hold the state and call these functions.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._dk_kernel import _residual_step, _wrap, dk_one
from ._map_kernel import label_at_one, near_mask_one

MODE_PAPER = 0
MODE_DEFAULT = 1

STATUS_OK = 0
STATUS_UNREACHABLE = 1
STATUS_SINGULAR = 2
STATUS_REJECTED = 3
STATUS_DIVERGED = 4

# layout of the float info array
F_D_BEST, F_D_SECOND, F_COND_PREV, F_COND, F_DQ = 0, 1, 2, 3, 4
# layout of the int info array
I_LABEL, I_NEAR_BORDER, I_N_REAL, I_AMBIGUOUS, I_STATUS, I_JUMP, I_REGION = 0, 1, 2, 3, 4, 5, 6
# layout of the parameter array
P_AMBIG, P_JUMP, P_SUB_DQ, P_MAX_SUB, P_SING, P_USE_MAP, P_STRATEGY, P_SEG_SING = 0, 1, 2, 3, 4, 5, 6, 7
#: default-mode strategies: continuation only, extrapolation only, arbitrated by the segment's
#: closeness to a singularity, arbitrated by which predictor is more decisive
S_CONT, S_EXT, S_SEG, S_DECISIVE = 0, 1, 2, 3


@njit(cache=True)
def jacobian_rows(X, q, M, l1, b, J, kd):
    """J = dF/dX (3, 3) and the diagonal of K = dF/dq (3,) at (X, q), written in place."""
    c, s = math.cos(X[2]), math.sin(X[2])
    for i in range(3):
        rbx = c * b[i, 0] - s * b[i, 1]
        rby = s * b[i, 0] + c * b[i, 1]
        cq, sq = math.cos(q[i]), math.sin(q[i])
        lx = X[0] + rbx - M[i, 0] - l1[i] * cq
        ly = X[1] + rby - M[i, 1] - l1[i] * sq
        J[i, 0] = 2.0 * lx
        J[i, 1] = 2.0 * ly
        J[i, 2] = 2.0 * (ly * rbx - lx * rby)
        kd[i] = -2.0 * l1[i] * (ly * cq - lx * sq)


@njit(cache=True)
def hadamard(J):
    """|det J| / prod |rows of J|: 0 at a singularity, 1 for orthogonal rows."""
    det = (J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1]) - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
           + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0]))
    norm = 1.0
    for i in range(3):
        norm *= math.sqrt(J[i, 0] ** 2 + J[i, 1] ** 2 + J[i, 2] ** 2)
    return abs(det) / norm if norm > 0 else 0.0


@njit(cache=True)
def solve3(A, r, out):
    """Solve A x = r (3x3) by Cramer's rule into ``out``; returns False if singular."""
    det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
           + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
    if det == 0.0 or not math.isfinite(det):
        return False
    out[0] = (r[0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (r[1] * A[2, 2] - A[1, 2] * r[2])
              + A[0, 2] * (r[1] * A[2, 1] - A[1, 1] * r[2])) / det
    out[1] = (A[0, 0] * (r[1] * A[2, 2] - A[1, 2] * r[2]) - r[0] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
              + A[0, 2] * (A[1, 0] * r[2] - r[1] * A[2, 0])) / det
    out[2] = (A[0, 0] * (A[1, 1] * r[2] - r[1] * A[2, 1]) - A[0, 1] * (A[1, 0] * r[2] - r[1] * A[2, 0])
              + r[0] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])) / det
    return math.isfinite(out[0]) and math.isfinite(out[1]) and math.isfinite(out[2])


@njit(cache=True)
def velocity(X, q, dq, M, l1, b, out):
    """dX = -J^-1 K dq at (X, q) (the velocity model, eq. 20); returns the Hadamard ratio of J."""
    J = np.empty((3, 3))
    kd = np.empty(3)
    jacobian_rows(X, q, M, l1, b, J, kd)
    r = np.empty(3)
    for i in range(3):
        r[i] = -kd[i] * dq[i]
    if not solve3(J, r, out):
        out[:] = 0.0
        return 0.0
    return hadamard(J)


@njit(cache=True)
def continuation(X0, q0, dq, nsub, M, l1, b, out):
    """Integrate J dX = -K dq along the joint segment q0 + s dq, s in [0, 1] (RK4, ``nsub`` steps).

    Writes the end pose to ``out``; returns the smallest Hadamard ratio of J met.
    """
    h = 1.0 / nsub
    X = X0.copy()
    k1, k2, k3, k4 = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    Xs, qs = np.empty(3), np.empty(3)
    worst = 1.0
    for n in range(nsub):
        s0 = n * h
        for i in range(3):
            qs[i] = q0[i] + s0 * dq[i]
        worst = min(worst, velocity(X, qs, dq, M, l1, b, k1))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k1[i]
            qs[i] = q0[i] + (s0 + 0.5 * h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, b, k2))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k2[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, b, k3))
        for i in range(3):
            Xs[i] = X[i] + h * k3[i]
            qs[i] = q0[i] + (s0 + h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, b, k4))
        for i in range(3):
            X[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    out[:] = X
    return worst


@njit(cache=True)
def wdist(a, b, w):
    """Weighted pose distance of eq. 19 with the phi difference wrapped."""
    dp = _wrap(a[2] - b[2])
    return math.sqrt(w[0] * (a[0] - b[0]) ** 2 + w[1] * (a[1] - b[1]) ** 2 + w[2] * dp * dp)


@njit(cache=True)
def _nearest(poses, real, Xref, w, m1, m2, m3, use_map):
    """The real solution nearest to ``Xref`` among those whose label is in one of the masks
    (all real ones if ``use_map`` is off or none qualifies), and its decisiveness
    ``d_best / d_second`` (0 = certain, 1 = a tie)."""
    Xr = np.empty(3)
    best, second, k_best = np.inf, np.inf, -1
    best_any, second_any, k_any = np.inf, np.inf, -1
    for k in range(6):
        if real[k]:
            for i in range(3):
                Xr[i] = poses[k, i].real
            d = wdist(Xr, Xref, w)
            if d < best_any:
                best_any, second_any, k_any = d, best_any, k
            elif d < second_any:
                second_any = d
            if m1[k + 1] or m2[k + 1] or m3[k + 1]:
                if d < best:
                    best, second, k_best = d, best, k
                elif d < second:
                    second = d
    if not use_map or k_best < 0:
        return k_any, best_any / second_any if second_any > 0 else 1.0
    return k_best, best / second if second > 0 else 1.0


@njit(cache=True)
def tracker_step(mode, q, Xp, qp, X2, hist, dq_scale, ext_scale, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol,
                 real_tol, steps, labels, origin, step, periodic, r2, w, stencil, params,
                 X_out, X_pred, info_f, info_i):
    """One step of procedure 3 (``mode`` paper or default); see :mod:`solver.tracker`."""
    poses = np.empty((6, 3), dtype=np.complex128)
    real = np.empty(6, dtype=np.bool_)
    dk_one(q, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps, poses, real)
    dq = np.empty(3)
    dqn = 0.0
    for i in range(3):
        dq[i] = _wrap(q[i] - qp[i])
        dqn = max(dqn, abs(dq[i]))
    qu = np.empty(3)                                   # q unwrapped next to the previous joints
    for i in range(3):
        qu[i] = qp[i] + dq[i]
    # eq. 22: the linear predictor at the previous pose
    dX = np.empty(3)
    cond_prev = velocity(Xp, qp, dq, M, l1, b, dX)
    X_lin = np.empty(3)
    for i in range(3):
        X_lin[i] = Xp[i] + dX[i]
    # procedure 2 at the previous pose
    near_prev = np.zeros(7, dtype=np.bool_)
    near_mask_one(labels, origin, step, periodic, Xp, r2, w, stencil, near_prev)
    n_near = 0
    single = 0
    for lab in range(1, 7):
        if near_prev[lab]:
            n_near += 1
            single = lab
    n_real = 0
    for k in range(6):
        if real[k]:
            n_real += 1
    for i in range(7):
        info_i[i] = 0
    for i in range(5):
        info_f[i] = 0.0
    info_i[I_NEAR_BORDER] = 1 if n_near > 1 else 0
    info_i[I_N_REAL] = n_real
    info_f[F_COND_PREV] = cond_prev
    info_f[F_DQ] = dqn
    jump = dq_scale > 0.0 and dqn > params[P_JUMP] * dq_scale
    info_i[I_JUMP] = 1 if jump else 0
    if n_real == 0:
        X_out[:] = Xp
        X_pred[:] = X_lin
        info_i[I_STATUS] = STATUS_UNREACHABLE
        return
    chosen = -1
    ambiguous = False
    Xr = np.empty(3)
    if mode == MODE_PAPER:
        X_pred[:] = X_lin
        if n_near == 1:
            region = single
        else:
            region = label_at_one(labels, origin, step, periodic, X_lin)
        info_i[I_REGION] = region
        if region >= 1 and real[region - 1]:
            chosen = region - 1
        else:
            ambiguous = True                       # procedure 3 has no answer: nearest to the prediction
            chosen, _ = _nearest(poses, real, X_lin, w, near_prev, near_prev, near_prev, False)
    else:
        # continuation predictor along the joint segment, guarded near singularities
        nsub = int(min(params[P_MAX_SUB], max(1.0, math.ceil(dqn / params[P_SUB_DQ]))))
        worst = continuation(Xp, qp, dq, nsub, M, l1, b, X_pred)
        ok = worst > params[P_SING]
        for i in range(3):
            ok = ok and math.isfinite(X_pred[i])
        if not ok:
            X_pred[:] = Xp if not (cond_prev > params[P_SING]) else X_lin
        region = label_at_one(labels, origin, step, periodic, X_pred)
        info_i[I_REGION] = region
        use_map = params[P_USE_MAP] > 0.0
        # tool-space extrapolation from the last two poses, scaled by the ratio of time steps
        have_ext = hist >= 2 and params[P_STRATEGY] != S_CONT
        X_ext = np.empty(3)
        for i in range(3):
            X_ext[i] = Xp[i] + ext_scale * (_wrap(Xp[i] - X2[i]) if i == 2 else Xp[i] - X2[i])
        near_pred = np.zeros(7, dtype=np.bool_)
        near_ext = np.zeros(7, dtype=np.bool_)
        kc, rc = _nearest(poses, real, X_pred, w, near_prev, near_pred, near_ext, False)
        ke, re = kc, rc
        if have_ext:
            ke, re = _nearest(poses, real, X_ext, w, near_prev, near_pred, near_ext, False)
        # procedure 2 at the predictions only when a candidate's label is not seen near X_prev
        if use_map and n_near > 0 and not (near_prev[kc + 1] and near_prev[ke + 1]):
            near_mask_one(labels, origin, step, periodic, X_pred, r2, w, stencil, near_pred)
            if have_ext:
                near_mask_one(labels, origin, step, periodic, X_ext, r2, w, stencil, near_ext)
            kc, rc = _nearest(poses, real, X_pred, w, near_prev, near_pred, near_ext, True)
            if have_ext:
                ke, re = _nearest(poses, real, X_ext, w, near_prev, near_pred, near_ext, True)
        if have_ext:
            strategy = params[P_STRATEGY]
            if kc == ke:
                chosen = kc
            else:
                ambiguous = True
                if strategy == S_EXT:
                    chosen = ke
                elif strategy == S_SEG:
                    chosen = ke if (not ok or worst < params[P_SEG_SING]) else kc
                else:
                    chosen = ke if re < rc else kc
            if chosen == ke:
                X_pred[:] = X_ext
        else:
            chosen = kc
        if use_map and not (near_prev[chosen + 1] or near_pred[chosen + 1] or near_ext[chosen + 1]) \
                and n_near > 0:
            ambiguous = True                       # no label seen nearby supports the choice
        if not ok:
            ambiguous = True
    # distances to the prediction: chosen and the nearest other real solution
    for i in range(3):
        Xr[i] = poses[chosen, i].real
    d_best = wdist(Xr, X_pred, w)
    d_second = np.inf
    Xo = np.empty(3)
    for k in range(6):
        if real[k] and k != chosen:
            for i in range(3):
                Xo[i] = poses[k, i].real
            d_second = min(d_second, wdist(Xo, X_pred, w))
    if mode != MODE_PAPER and d_best > params[P_AMBIG] * d_second:
        ambiguous = True
    if jump:
        ambiguous = True
    info_f[F_D_BEST] = d_best
    info_f[F_D_SECOND] = d_second
    for i in range(3):
        X_out[i] = Xr[i]
    J = np.empty((3, 3))
    kd = np.empty(3)
    jacobian_rows(X_out, qu, M, l1, b, J, kd)
    cond = hadamard(J)
    info_f[F_COND] = cond
    info_i[I_LABEL] = chosen + 1
    info_i[I_AMBIGUOUS] = 1 if ambiguous else 0
    info_i[I_STATUS] = STATUS_SINGULAR if cond < params[P_SING] else STATUS_OK


# ----------------------------------------------------------------------------- baselines
@njit(cache=True)
def _elbows(q, M, l1, D):
    for i in range(3):
        D[i, 0] = M[i, 0] + l1[i] * math.cos(q[i])
        D[i, 1] = M[i, 1] + l1[i] * math.sin(q[i])


@njit(cache=True)
def newton(X0, q, M, l1, l2sq, b, damping, max_iter, tol, X_out):
    """Newton (damping 1) or damped Newton iterations on F(X, q) = 0 from X0.

    Returns (residual max|F_i|, iterations, Hadamard ratio at the end).
    """
    D = np.empty((3, 2))
    _elbows(q, M, l1, D)
    x, y, p = X0[0], X0[1], X0[2]
    res, dx, dy, dp, ok, had = _residual_step(x, y, p, D, b, l2sq)
    it = 0
    while it < max_iter and res > tol and ok:
        x += damping * dx
        y += damping * dy
        p += damping * dp
        res, dx, dy, dp, ok, had = _residual_step(x, y, p, D, b, l2sq)
        it += 1
    X_out[0], X_out[1], X_out[2] = x, y, _wrap(p)
    return res, it, had


@njit(cache=True)
def baseline_step(kind, q, Xp, qp, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol,
                  steps, w, tol, X_out, X_pred, info_f, info_i):
    """One step of a baseline: 0 Newton from the previous pose, 1 Newton from the eq. 22
    predictor, 2 CLDK (feed-forward + damped closed-loop correction), 3 nearest real solution."""
    for i in range(7):
        info_i[i] = 0
    for i in range(5):
        info_f[i] = 0.0
    dq = np.empty(3)
    dqn = 0.0
    for i in range(3):
        dq[i] = _wrap(q[i] - qp[i])
        dqn = max(dqn, abs(dq[i]))
    info_f[F_DQ] = dqn
    info_i[I_N_REAL] = -1
    if kind == 3:
        poses = np.empty((6, 3), dtype=np.complex128)
        real = np.empty(6, dtype=np.bool_)
        dk_one(q, M, l1, l2sq, b, cos8, sin8, T, psis, rule, snap_tol, real_tol, steps, poses, real)
        X_pred[:] = Xp
        best, kbest, n_real = np.inf, -1, 0
        Xr = np.empty(3)
        for k in range(6):
            if real[k]:
                n_real += 1
                for i in range(3):
                    Xr[i] = poses[k, i].real
                d = wdist(Xr, Xp, w)
                if d < best:
                    best, kbest = d, k
        info_i[I_N_REAL] = n_real
        if kbest < 0:
            X_out[:] = Xp
            info_i[I_STATUS] = STATUS_UNREACHABLE
            return
        for i in range(3):
            X_out[i] = poses[kbest, i].real
        info_i[I_LABEL] = kbest + 1
        info_f[F_D_BEST] = best
        info_i[I_STATUS] = STATUS_OK
        return
    if kind == 0:
        X_pred[:] = Xp
    else:
        dX = np.empty(3)
        info_f[F_COND_PREV] = velocity(Xp, qp, dq, M, l1, b, dX)
        for i in range(3):
            X_pred[i] = Xp[i] + dX[i]
    if kind == 2:
        res, it, had = newton(X_pred, q, M, l1, l2sq, b, 0.5, 200, tol, X_out)
    else:
        res, it, had = newton(X_pred, q, M, l1, l2sq, b, 1.0, 50, tol, X_out)
    info_f[F_COND] = had
    info_i[I_STATUS] = STATUS_OK if res <= tol * 10.0 else STATUS_DIVERGED


# ----------------------------------------------------------------------------- packed entry points
# Few arguments: numba unboxes every argument of a call from Python, and these run once per step.
# geo = [M (6), l1 (3), l2sq (3), b (6), cos8 (8), sin8 (8), psis (8), snap_tol, real_tol, steps]
# st = [X (3), q (3), X2 (3), history, dq_scale, extrapolation scale]; mgeo = [origin (3), step (3), periodic, r2, w (3)]
# out_f = [X (3), X_pred (3), info_f (5)]
@njit(cache=True)
def tracker_step_packed(mode, rule, q, st, geo, T, labels, mgeo, stencil, params, out_f, out_i):
    tracker_step(mode, q, st[0:3], st[3:6], st[6:9], int(st[9]), st[10], st[11], geo[0:6].reshape((3, 2)),
                 geo[6:9], geo[9:12], geo[12:18].reshape((3, 2)), geo[18:26], geo[26:34], T, geo[34:42],
                 rule, geo[42], geo[43], int(geo[44]), labels, mgeo[0:3], mgeo[3:6], mgeo[6] > 0.0, mgeo[7],
                 mgeo[8:11], stencil, params, out_f[0:3], out_f[3:6], out_f[6:11], out_i)


@njit(cache=True)
def baseline_step_packed(kind, rule, q, st, geo, T, bpar, out_f, out_i):
    """bpar = [w (3), tol]."""
    baseline_step(kind, q, st[0:3], st[3:6], geo[0:6].reshape((3, 2)), geo[6:9], geo[9:12],
                  geo[12:18].reshape((3, 2)), geo[18:26], geo[26:34], T, geo[34:42], rule, geo[42], geo[43],
                  int(geo[44]), bpar[0:3], bpar[3], out_f[0:3], out_f[3:6], out_f[6:11], out_i)
