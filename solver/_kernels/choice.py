"""The tracker's predictor and choice rules, compiled: the joint step, the continuation along it,
and the eq. 19 distance with the nearest solution to a prediction (shared with the baselines); the
predict and choose phases of a tracker step (:mod:`.tracker`, packs: :mod:`.tracker_packs`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import geometry, velocity
from .layout import (F_COND_PREV, I_REGION, MAP_ORIGIN, MAP_PERIODIC, MAP_R2, MAP_STEP, MAP_WEIGHTS, MODE_PAPER,
                     OUT_INFO, OUT_X_PRED, PARAM_MAX_SUBSTEPS, PARAM_SEGMENT_SINGULAR, PARAM_SINGULAR, PARAM_STRATEGY,
                     PARAM_SUBSTEP_DQ, PARAM_USE_MAP, STATE_EXT_SCALE, STATE_HISTORY, STATE_Q, STATE_X, STATE_X2,
                     STRATEGY_CONTINUATION, STRATEGY_EXTRAPOLATION, STRATEGY_SEGMENT)
from .linalg import wrap
from .maptensor import label_at_one, near_mask_one
from .scratch import floats, scratch
from .tracker_packs import STEP_DQ, STEP_DQN, STEP_X_EXT, STEP_X_LIN


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
    X = floats(3)
    X[:] = X0
    k1, k2, k3, k4 = floats(3), floats(3), floats(3), floats(3)
    Xs, qs = floats(3), floats(3)
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
    Xr = floats(3)
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
@njit(cache=False)
def linear_prediction(state, work, model_pack, out_real):
    """Predict phase, eq. 22: the linear predictor at the previous pose into STEP_X_LIN; writes
    F_COND_PREV and returns the Hadamard ratio of J there."""
    M, l1, l2sq, b = geometry(model_pack)
    Xp = state[STATE_X:STATE_X + 3]
    dX = floats(3)
    cond_prev = velocity(Xp, state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3], M, l1, l2sq, b, dX)
    for i in range(3):
        work[STEP_X_LIN + i] = Xp[i] + dX[i]
    out_real[OUT_INFO + F_COND_PREV] = cond_prev
    return cond_prev


@njit(cache=False)
def predict(mode, state, work, params, model_pack, out_real, cond_prev):
    """Predict phase, the prediction OUT_X_PRED a choice is compared with.

    Paper mode: eq. 22 (STEP_X_LIN).  Default mode: the continuation along the joint
    segment, guarded near singularities (eq. 22, or the previous pose, where it meets one),
    and the tool-space extrapolation from the last two poses into STEP_X_EXT (scaled by the
    ratio of time steps).  Returns (the continuation met no singularity, the smallest
    Hadamard ratio it met); (True, 1.0) in paper mode.
    """
    X_pred = out_real[OUT_X_PRED:OUT_X_PRED + 3]
    if mode == MODE_PAPER:
        X_pred[:] = work[STEP_X_LIN:STEP_X_LIN + 3]
        return True, 1.0
    M, l1, l2sq, b = geometry(model_pack)
    Xp, X2 = state[STATE_X:STATE_X + 3], state[STATE_X2:STATE_X2 + 3]
    nsub = int(min(params[PARAM_MAX_SUBSTEPS], max(1.0, math.ceil(work[STEP_DQN] / params[PARAM_SUBSTEP_DQ]))))
    worst = continuation(Xp, state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3], nsub, M, l1, l2sq, b, X_pred)
    ok = worst > params[PARAM_SINGULAR]
    for i in range(3):
        ok = ok and math.isfinite(X_pred[i])
    if not ok:
        X_pred[:] = Xp if not (cond_prev > params[PARAM_SINGULAR]) else work[STEP_X_LIN:STEP_X_LIN + 3]
    ext_scale = state[STATE_EXT_SCALE]
    for i in range(3):
        work[STEP_X_EXT + i] = Xp[i] + ext_scale * (wrap(Xp[i] - X2[i]) if i == 2 else Xp[i] - X2[i])
    return ok, worst


@njit(cache=False)
def choose_paper(poses, real, near_prev, work, labels, map_pack, n_near, single, out_int):
    """Choose phase, paper mode (procedure 3): the solution numbered by the region, the one label
    seen near the previous pose or the label at the eq. 22 prediction; where that solution is not
    real, the nearest to the prediction, ambiguous.  Writes I_REGION; returns (chosen, ambiguous)."""
    X_lin = work[STEP_X_LIN:STEP_X_LIN + 3]
    if n_near == 1:
        region = single
    else:
        region = label_at_one(labels, map_pack[MAP_ORIGIN:MAP_ORIGIN + 3], map_pack[MAP_STEP:MAP_STEP + 3],
                              map_pack[MAP_PERIODIC] > 0.0, X_lin)
    out_int[I_REGION] = region
    if region >= 1 and real[region - 1]:
        return region - 1, False
    chosen, _ = nearest(poses, real, X_lin, map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3], near_prev, near_prev, near_prev,
                        False)
    return chosen, True                                # procedure 3 has no answer: nearest to the prediction


@njit(cache=False)
def choose_default(poses, real, near_prev, work, state, params, labels, map_pack, stencil, n_near, ok, worst,
                   out_real, out_int):
    """Choose phase, default mode: the real solution nearest the continuation and the one nearest
    the extrapolation (among the labels procedure 2 sees near the previous pose or the prediction,
    looked at only when a nearest one's label is not seen near the previous pose), arbitrated by
    the strategy.  Writes I_REGION (and OUT_X_PRED = STEP_X_EXT when the extrapolation wins);
    returns (chosen, ambiguous)."""
    origin, step, periodic = map_pack[MAP_ORIGIN:MAP_ORIGIN + 3], map_pack[MAP_STEP:MAP_STEP + 3], \
        map_pack[MAP_PERIODIC] > 0.0
    r2, w = map_pack[MAP_R2], map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3]
    X_pred, X_ext = out_real[OUT_X_PRED:OUT_X_PRED + 3], work[STEP_X_EXT:STEP_X_EXT + 3]
    out_int[I_REGION] = label_at_one(labels, origin, step, periodic, X_pred)
    use_map = params[PARAM_USE_MAP] > 0.0
    have_ext = int(state[STATE_HISTORY]) >= 2 and params[PARAM_STRATEGY] != STRATEGY_CONTINUATION
    near_pred = scratch(7, np.bool_)
    near_pred[:] = False
    near_ext = scratch(7, np.bool_)
    near_ext[:] = False
    kc, rc = nearest(poses, real, X_pred, w, near_prev, near_pred, near_ext, False)
    ke, re = kc, rc
    if have_ext:
        ke, re = nearest(poses, real, X_ext, w, near_prev, near_pred, near_ext, False)
    # procedure 2 at the predictions only when a candidate's label is not seen near X_prev
    if use_map and n_near > 0 and not (near_prev[kc + 1] and near_prev[ke + 1]):
        near_mask_one(labels, origin, step, periodic, X_pred, r2, w, stencil, near_pred)
        if have_ext:
            near_mask_one(labels, origin, step, periodic, X_ext, r2, w, stencil, near_ext)
        kc, rc = nearest(poses, real, X_pred, w, near_prev, near_pred, near_ext, True)
        if have_ext:
            ke, re = nearest(poses, real, X_ext, w, near_prev, near_pred, near_ext, True)
    ambiguous = False
    chosen = kc
    if have_ext:
        chosen, ambiguous = arbitrate(params, kc, rc, ke, re, ok, worst)
        if chosen == ke:
            X_pred[:] = X_ext
    if use_map and not (near_prev[chosen + 1] or near_pred[chosen + 1] or near_ext[chosen + 1]) and n_near > 0:
        ambiguous = True                           # no label seen nearby supports the choice
    return chosen, ambiguous or not ok


@njit(cache=False)
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
