"""One step of each baseline of the tracker, compiled on the tracker's primitives.

:class:`solver.baselines` classes call :func:`baseline_step` with the tracker's packed
arguments (:mod:`.layout`), so their times compare like with like.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .direct_kinematics import dk_one
from .kinematics import elbows, geometry, newton_step, radius_sq, velocity
from .layout import (BASELINE_CLDK, BASELINE_NEAREST, BASELINE_NEWTON, BASELINE_NEWTON_SEPARATION,
                     BASELINE_SEPARATION, BASELINE_TOL, BASELINE_WEIGHTS, F_COND, F_D_SECOND, I_CERTAIN,
                     F_COND_PREV, F_D_BEST, F_DQ, I_LABEL, I_N_REAL, I_STATUS, INFO_F_SIZE, INFO_I_SIZE, OUT_INFO,
                     OUT_X, OUT_X_PRED, STATE_Q, STATE_X, STATUS_DIVERGED, STATUS_OK, STATUS_UNREACHABLE)
from .linalg import wrap
from .choice import joint_step, nearest, wdist
from .scratch import floats, scratch, scratch2


@njit(cache=True)
def newton(X0, q, M, l1, l2sq, b, damping, max_iter, tol, X_out):
    """Newton (damping 1) or damped Newton iterations on F(X, q) = 0 from X0.

    Returns (residual max|F_i|, iterations, Hadamard ratio at the end).
    """
    D = scratch2(3, 2, np.float64)
    elbows(q, M, l1, D)
    r2 = floats(3)
    for i in range(3):
        r2[i] = radius_sq(l2sq[i], q[i])
    l2sq = r2
    x, y, p = X0[0], X0[1], X0[2]
    res, dx, dy, dp, ok, had = newton_step(x, y, p, D, b, l2sq)
    it = 0
    while it < max_iter and res > tol and ok:
        x += damping * dx
        y += damping * dy
        p += damping * dp
        res, dx, dy, dp, ok, had = newton_step(x, y, p, D, b, l2sq)
        it += 1
    X_out[0], X_out[1], X_out[2] = x, y, wrap(p)
    return res, it, had


@njit(cache=True)
def baseline_step(kind, rule, q, state, model_pack, sample_to_sextic, baseline_params, out_real, out_int):
    """One step of a baseline (``kind``, a BASELINE_* code): Newton from the previous pose, Newton
    from the eq. 22 predictor, CLDK (feed-forward + damped closed-loop correction), or the
    nearest real solution.  Arguments and outputs as :func:`.tracker.tracker_step`."""
    Xp, qp = state[STATE_X:STATE_X + 3], state[STATE_Q:STATE_Q + 3]
    X_out, X_pred = out_real[OUT_X:OUT_X + 3], out_real[OUT_X_PRED:OUT_X_PRED + 3]
    info_f, info_i = out_real[OUT_INFO:OUT_INFO + INFO_F_SIZE], out_int
    for i in range(INFO_I_SIZE):
        info_i[i] = 0
    for i in range(INFO_F_SIZE):
        info_f[i] = 0.0
    dq = floats(3)
    info_f[F_DQ] = joint_step(q, qp, dq)
    info_i[I_N_REAL] = -1
    if kind == BASELINE_NEAREST:
        nearest_step(q, Xp, rule, model_pack, sample_to_sextic, baseline_params, X_out, X_pred, info_f, info_i)
        return
    M, l1, l2sq, b = geometry(model_pack)
    tol = baseline_params[BASELINE_TOL]
    if kind == BASELINE_NEWTON or kind == BASELINE_NEWTON_SEPARATION:
        X_pred[:] = Xp
    else:
        dX = floats(3)
        info_f[F_COND_PREV] = velocity(Xp, qp, dq, M, l1, l2sq, b, dX)
        for i in range(3):
            X_pred[i] = Xp[i] + dX[i]
    if kind == BASELINE_CLDK:
        res, it, had = newton(X_pred, q, M, l1, l2sq, b, 0.5, 200, tol, X_out)
    else:
        res, it, had = newton(X_pred, q, M, l1, l2sq, b, 1.0, 50, tol, X_out)
    info_f[F_COND] = had
    info_i[I_STATUS] = STATUS_OK if res <= tol * 10.0 else STATUS_DIVERGED
    if kind == BASELINE_NEWTON_SEPARATION and info_i[I_STATUS] == STATUS_OK:
        separation_flag(q, Xp, rule, model_pack, sample_to_sextic, baseline_params, X_out, info_f, info_i)


@njit(cache=True)
def nearest_step(q, Xp, rule, model_pack, sample_to_sextic, baseline_params, X_out, X_pred, info_f, info_i):
    """The nearest baseline: all DK solutions at ``q`` (3,), the real one nearest (eq. 19) the
    previous pose ``Xp`` (3,); the previous pose held (unreachable) when none is real."""
    w = baseline_params[BASELINE_WEIGHTS:BASELINE_WEIGHTS + 3]
    poses = scratch2(6, 3, np.complex128)
    real = scratch(6, np.bool_)
    dk_one(q, model_pack, sample_to_sextic, rule, poses, real)
    X_pred[:] = Xp
    info_i[I_N_REAL] = np.count_nonzero(real)
    nothing = scratch(7, np.bool_)
    nothing[:] = False
    kbest, _ = nearest(poses, real, Xp, w, nothing, nothing, nothing, False)
    if kbest < 0:
        X_out[:] = Xp
        info_i[I_STATUS] = STATUS_UNREACHABLE
        return
    for i in range(3):
        X_out[i] = poses[kbest, i].real
    info_i[I_LABEL] = kbest + 1
    info_f[F_D_BEST] = wdist(X_out, Xp, w)
    info_i[I_STATUS] = STATUS_OK


@njit(cache=True)
def separation_flag(q, Xp, rule, model_pack, sample_to_sextic, baseline_params, X_out, info_f, info_i):
    """The separation flag of Newton's answer ``X_out`` (3,): certain when every other real DK solution
    at ``q`` is more than BASELINE_SEPARATION times farther from it than the step from ``Xp``."""
    w = baseline_params[BASELINE_WEIGHTS:BASELINE_WEIGHTS + 3]
    poses = scratch2(6, 3, np.complex128)
    real = scratch(6, np.bool_)
    dk_one(q, model_pack, sample_to_sextic, rule, poses, real)
    info_i[I_N_REAL] = np.count_nonzero(real)
    d_step = wdist(X_out, Xp, w)
    d_other = np.inf
    Xr = floats(3)
    for k in range(6):
        if real[k]:
            for i in range(3):
                Xr[i] = poses[k, i].real
            d = wdist(Xr, X_out, w)
            if d > 1e-9:                            # not the solution Newton found
                d_other = min(d_other, d)
    info_f[F_D_BEST] = d_step
    info_f[F_D_SECOND] = d_other
    info_i[I_CERTAIN] = 1 if d_other > baseline_params[BASELINE_SEPARATION] * d_step else 0
