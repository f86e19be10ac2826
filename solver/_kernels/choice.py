"""The tracker's predictor and choice rules, compiled: the joint step, the continuation along it,
and the eq. 19 distance with the nearest solution to a prediction (shared with the baselines); the
predict and choose phases of a tracker step (:mod:`.tracker`, packs: :mod:`.tracker_packs`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import velocity
from .layout import (F_COND_PREV, I_REGION, MODE_PAPER, PARAM_MAX_SUBSTEPS, PARAM_SEGMENT_SINGULAR, PARAM_SINGULAR,
                     PARAM_STRATEGY, PARAM_SUBSTEP_DQ, PARAM_USE_MAP, STATE_HISTORY, STRATEGY_CONTINUATION,
                     STRATEGY_EXTRAPOLATION, STRATEGY_SEGMENT)
from .linalg import wrap
from .maptensor import label_at_one, near_mask_one


@njit(cache=True)
def joint_step(q, qp, dq):
    """The joint step ``dq = q - qp`` (3,) with wrapped angles, written in place; returns max|dq_i|."""
    dqn = 0.0
    for i in range(3):
        dq[i] = wrap(q[i] - qp[i])
        dqn = max(dqn, abs(dq[i]))
    return dqn


@njit(cache=True)
def continuation(X0, q0, dq, nsub, M, l1, l2sq, b, out):
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
        worst = min(worst, velocity(X, qs, dq, M, l1, l2sq, b, k1))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k1[i]
            qs[i] = q0[i] + (s0 + 0.5 * h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k2))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k2[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k3))
        for i in range(3):
            Xs[i] = X[i] + h * k3[i]
            qs[i] = q0[i] + (s0 + h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k4))
        for i in range(3):
            X[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    out[:] = X
    return worst


@njit(cache=True)
def wdist(a, b, w):
    """Weighted pose distance of eq. 19 with the phi difference wrapped."""
    dp = wrap(a[2] - b[2])
    return math.sqrt(w[0] * (a[0] - b[0]) ** 2 + w[1] * (a[1] - b[1]) ** 2 + w[2] * dp * dp)


@njit(cache=True)
def nearest(poses, real, Xref, w, m1, m2, m3, use_map):
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


# ----------------------------------------------------------------------------- the tracker's phases
@njit(cache=True)
def linear_prediction(cfg, st, res):
    """Predict phase, eq. 22: ``st.X_lin`` = the linear predictor at the previous pose; writes
    F_COND_PREV and returns the Hadamard ratio of J there."""
    dX = np.empty(3)
    cond_prev = velocity(st.Xp, st.qp, st.dq, cfg.M, cfg.l1, cfg.l2sq, cfg.b, dX)
    for i in range(3):
        st.X_lin[i] = st.Xp[i] + dX[i]
    res.info_f[F_COND_PREV] = cond_prev
    return cond_prev


@njit(cache=True)
def predict(cfg, st, res, cond_prev):
    """Predict phase, the prediction ``res.X_pred`` a choice is compared with.

    Paper mode: eq. 22 (``st.X_lin``).  Default mode: the continuation along the joint
    segment, guarded near singularities (eq. 22, or the previous pose, where it meets one),
    and the tool-space extrapolation from the last two poses into ``st.X_ext`` (scaled by the
    ratio of time steps).  Returns (the continuation met no singularity, the smallest
    Hadamard ratio it met); (True, 1.0) in paper mode.
    """
    params, X_pred = cfg.params, res.X_pred
    if cfg.mode == MODE_PAPER:
        X_pred[:] = st.X_lin
        return True, 1.0
    nsub = int(min(params[PARAM_MAX_SUBSTEPS], max(1.0, math.ceil(st.dqn / params[PARAM_SUBSTEP_DQ]))))
    worst = continuation(st.Xp, st.qp, st.dq, nsub, cfg.M, cfg.l1, cfg.l2sq, cfg.b, X_pred)
    ok = worst > params[PARAM_SINGULAR]
    for i in range(3):
        ok = ok and math.isfinite(X_pred[i])
    if not ok:
        X_pred[:] = st.Xp if not (cond_prev > params[PARAM_SINGULAR]) else st.X_lin
    Xp, X2 = st.Xp, st.X2
    for i in range(3):
        st.X_ext[i] = Xp[i] + st.ext_scale * (wrap(Xp[i] - X2[i]) if i == 2 else Xp[i] - X2[i])
    return ok, worst


@njit(cache=True)
def choose_paper(cfg, st, res, n_near, single):
    """Choose phase, paper mode (procedure 3): the solution numbered by the region, the one label
    seen near the previous pose or the label at the eq. 22 prediction; where that solution is not
    real, the nearest to the prediction, ambiguous.  Writes I_REGION; returns (chosen, ambiguous)."""
    if n_near == 1:
        region = single
    else:
        region = label_at_one(cfg.labels, cfg.origin, cfg.step, cfg.periodic, st.X_lin)
    res.info_i[I_REGION] = region
    if region >= 1 and st.real[region - 1]:
        return region - 1, False
    chosen, _ = nearest(st.poses, st.real, st.X_lin, cfg.w, st.near_prev, st.near_prev, st.near_prev, False)
    return chosen, True                                # procedure 3 has no answer: nearest to the prediction


@njit(cache=True)
def choose_default(cfg, st, state, res, n_near, ok, worst):
    """Choose phase, default mode: the real solution nearest the continuation and the one nearest
    the extrapolation (among the labels procedure 2 sees near the previous pose or the prediction,
    looked at only when a nearest one's label is not seen near the previous pose), arbitrated by
    the strategy.  Writes I_REGION (and ``res.X_pred = st.X_ext`` when the extrapolation wins);
    returns (chosen, ambiguous)."""
    params, X_pred, near_prev = cfg.params, res.X_pred, st.near_prev
    res.info_i[I_REGION] = label_at_one(cfg.labels, cfg.origin, cfg.step, cfg.periodic, X_pred)
    use_map = params[PARAM_USE_MAP] > 0.0
    have_ext = int(state[STATE_HISTORY]) >= 2 and params[PARAM_STRATEGY] != STRATEGY_CONTINUATION
    near_pred = np.zeros(7, dtype=np.bool_)
    near_ext = np.zeros(7, dtype=np.bool_)
    kc, rc = nearest(st.poses, st.real, X_pred, cfg.w, near_prev, near_pred, near_ext, False)
    ke, re = kc, rc
    if have_ext:
        ke, re = nearest(st.poses, st.real, st.X_ext, cfg.w, near_prev, near_pred, near_ext, False)
    # procedure 2 at the predictions only when a candidate's label is not seen near X_prev
    if use_map and n_near > 0 and not (near_prev[kc + 1] and near_prev[ke + 1]):
        near_mask_one(cfg.labels, cfg.origin, cfg.step, cfg.periodic, X_pred, cfg.r2, cfg.w, cfg.stencil, near_pred)
        if have_ext:
            near_mask_one(cfg.labels, cfg.origin, cfg.step, cfg.periodic, st.X_ext, cfg.r2, cfg.w, cfg.stencil,
                          near_ext)
        kc, rc = nearest(st.poses, st.real, X_pred, cfg.w, near_prev, near_pred, near_ext, True)
        if have_ext:
            ke, re = nearest(st.poses, st.real, st.X_ext, cfg.w, near_prev, near_pred, near_ext, True)
    ambiguous = False
    chosen = kc
    if have_ext:
        chosen, ambiguous = arbitrate(params, kc, rc, ke, re, ok, worst)
        if chosen == ke:
            X_pred[:] = st.X_ext
    if use_map and not (near_prev[chosen + 1] or near_pred[chosen + 1] or near_ext[chosen + 1]) and n_near > 0:
        ambiguous = True                           # no label seen nearby supports the choice
    return chosen, ambiguous or not ok


@njit(cache=True)
def arbitrate(params, kc, rc, ke, re, ok, worst):
    """The continuation's choice ``kc`` or the extrapolation's ``ke`` (decisiveness ``rc``, ``re``:
    d_best / d_second) by the strategy (PARAM_STRATEGY); returns (chosen, they disagree)."""
    if kc == ke:
        return kc, False
    strategy = params[PARAM_STRATEGY]
    if strategy == STRATEGY_EXTRAPOLATION:
        return ke, True
    if strategy == STRATEGY_SEGMENT:
        return (ke if (not ok or worst < params[PARAM_SEGMENT_SINGULAR]) else kc), True
    return (ke if re < rc else kc), True
