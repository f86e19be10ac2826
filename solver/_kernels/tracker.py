"""One step of procedure 3 (the tracker), compiled.

One call does a whole step (all DK solutions, the predictor, procedure 2 on the map, the
choice), so the per-step cost is the work, not Python overhead.  :class:`solver.Tracker`
checks inputs, holds the state, packs it (:mod:`.layout`) and calls :func:`tracker_step`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .certify import CERT_NONE, CERT_REACQUIRED, certify, comes_from
from .exclusion import reacquire
from .gates import GATE_PASS, GATE_REFUSE, outlier_gate, reacquire_region, speed_gate
from .direct_kinematics import dk_one
from .kinematics import geometry, jacobian, velocity
from .layout import (F_COND, F_COND_PREV, F_D_BEST, F_D_SECOND, F_DQ, I_AMBIGUOUS, I_JUMP, I_LABEL, I_N_REAL,
                     I_NEAR_BORDER, I_REGION, I_STATUS, INFO_F_SIZE, INFO_I_SIZE, MAP_ORIGIN, MAP_PERIODIC, MAP_R2,
                     MAP_STEP, MAP_WEIGHTS, MODE_PAPER, OUT_INFO, OUT_X, OUT_X_PRED, PARAM_AMBIGUITY, PARAM_JUMP,
                     PARAM_MAX_SUBSTEPS, PARAM_SEGMENT_SINGULAR, PARAM_SINGULAR, PARAM_STRATEGY, PARAM_SUBSTEP_DQ,
                     PARAM_USE_MAP, STATE_DQ_SCALE, STATE_EXT_SCALE, STATE_HISTORY, STATE_Q, STATE_X, STATE_X2,
                     I_CERTAIN, I_CERTIFICATE, I_N_CAND, OUT_CANDS, PARAM_MAX_TESTS, PARAM_POSTURE_BITS, STATE_CANDS,
                     STATE_HAVE_Q2, STATE_N_CAND, STATE_Q2, STATE_VERIFIED, STATE_INTACT, PARAM_JOINT_TOL, I_INTACT,
                     STATUS_OK, F_INNOV, STATE_A_SCALE, STATE_REFUSED, PARAM_GATE, MAX_REFUSED, STATUS_REJECTED,
                     PARAM_SPEED, PARAM_REACQUIRE, STATE_STEP_DT, STATUS_SINGULAR, STATUS_UNREACHABLE,
                     STRATEGY_CONTINUATION, STRATEGY_EXTRAPOLATION, STRATEGY_SEGMENT)
from .linalg import hadamard, wrap
from .choice import continuation, joint_step, nearest, wdist
from .maptensor import label_at_one, near_mask_one

#: Before the speed gate holds the pose or takes another solution (default mode, a trusted sample, one
#: previous candidate), the chain back to that candidate may use this many times ``max_tests`` tests.
LINK_TESTS = 10
#: ... and only over a step of at most this many samples' time (not over a stuck joint's gap, which is
#: at least ``stuck_after`` >= 5 samples for every sensor grade of the benchmark).
LINK_GAP = 4.0


@njit(cache=True)
def certified_choice(mode, chosen, state, qp, dq, ext_scale, poses, real, X_pred, w, params, model_pack,
                     new_cands, info_i, untrusted):
    """The certificates of a step (:mod:`.certify`) and what they change in the choice.

    Updates the candidate set (into ``new_cands``) and writes I_CERTAIN,
    I_CERTIFICATE and I_N_CAND.  In default mode a choice the certificates rule
    out is replaced: by the one candidate left, or by the candidate nearest the
    prediction.  Paper mode keeps its answer and is certain only when it is the
    one candidate left.  An ``untrusted`` sample (its joints may be a glitch) is not
    re-acquired from, vouched for nothing and ends the chain.  Returns the (possibly
    new) chosen solution index, and whether a chain of boxes along the measured joints
    joins it to a previous candidate or it was re-acquired (the speed gate then leaves
    it alone).
    """
    n_cand = int(state[STATE_N_CAND])
    cands = state[STATE_CANDS:STATE_CANDS + 18].reshape((6, 3))
    d2 = np.zeros(3)
    have_par = state[STATE_HAVE_Q2] > 0.0
    if have_par:
        # the parabola through q2 (at s = -r), qp (s = 0) and q (s = 1), r = previous / this time step
        r = 1.0 / ext_scale
        for i in range(3):
            d2[i] = (wrap(state[STATE_Q2 + i] - qp[i]) + r * dq[i]) / (r * (1.0 + r))
    keep = np.empty(6, dtype=np.bool_)
    intact_before = state[STATE_INTACT] > 0.0
    eps = params[PARAM_JOINT_TOL]
    posture_bits = int(params[PARAM_POSTURE_BITS])
    n_new, cert, intact, linked = certify(cands, n_cand, state[STATE_VERIFIED] > 0.0, intact_before, qp, dq, d2,
                                          have_par, eps, poses, real, posture_bits, int(params[PARAM_MAX_TESTS]),
                                          model_pack, new_cands, keep)
    intact = intact and intact_before
    if not (cert != CERT_NONE and intact) and eps > 0.0 and params[PARAM_REACQUIRE] > 0.0 and posture_bits >= 0 \
            and not untrusted:
        # measured joints: re-acquire the branch from this sample alone (see .exclusion)
        region = np.empty(6)
        reacquire_region(params, state, region)
        target = chosen
        if cert != CERT_NONE:                      # the branch along the measured joints
            for k in range(6):
                if keep[k]:
                    target = k
        Xc = np.empty(3)
        for i in range(3):
            Xc[i] = poses[target, i].real
        if region[0] <= region[1] and region[2] <= region[3] and \
                reacquire(Xc, qp + dq, eps, posture_bits, region, int(params[PARAM_REACQUIRE]), model_pack):
            for k in range(6):
                keep[k] = k == target
            new_cands[0, :] = Xc
            n_new, cert, intact, linked = 1, CERT_REACQUIRED, True, True
    certain = False
    if cert != CERT_NONE:        # the choice follows the certificates; vouched only with the chain intact
        sole = 0
        for k in range(6):
            if keep[k]:
                sole = k
        if mode != MODE_PAPER:
            chosen = sole
        certain = chosen == sole and intact
        linked = linked and chosen == sole
    elif mode != MODE_PAPER and not keep[chosen]:
        mask = np.zeros(7, dtype=np.bool_)
        for k in range(6):
            mask[k + 1] = keep[k]
        chosen, _ = nearest(poses, real, X_pred, w, mask, mask, mask, True)
    if untrusted:
        certain, intact, linked = False, False, False
    info_i[I_CERTAIN] = 1 if certain else 0
    info_i[I_CERTIFICATE] = cert
    info_i[I_N_CAND] = n_new
    info_i[I_INTACT] = 1 if intact else 0
    return chosen, linked


@njit(cache=True)
def tracker_step(mode, rule, q, state, model_pack, sample_to_sextic, labels, map_pack, stencil, params,
                 out_real, out_int):
    """One step of procedure 3 (``mode`` MODE_PAPER or MODE_DEFAULT); see :mod:`solver.tracker`.

    Reads the joints ``q`` (3,), the state pack ``state``, the model pack, the map's labels,
    its map pack and procedure-2 ``stencil``, and the options ``params``; writes the step's
    outputs into ``out_real`` (OUT_SIZE,) and ``out_int`` (INFO_I_SIZE,).
    """
    M, l1, l2sq, b = geometry(model_pack)
    Xp, qp, X2 = state[STATE_X:STATE_X + 3], state[STATE_Q:STATE_Q + 3], state[STATE_X2:STATE_X2 + 3]
    hist, dq_scale, ext_scale = int(state[STATE_HISTORY]), state[STATE_DQ_SCALE], state[STATE_EXT_SCALE]
    origin, step = map_pack[MAP_ORIGIN:MAP_ORIGIN + 3], map_pack[MAP_STEP:MAP_STEP + 3]
    periodic, r2, w = map_pack[MAP_PERIODIC] > 0.0, map_pack[MAP_R2], map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3]
    X_out, X_pred = out_real[OUT_X:OUT_X + 3], out_real[OUT_X_PRED:OUT_X_PRED + 3]
    info_f, info_i = out_real[OUT_INFO:OUT_INFO + INFO_F_SIZE], out_int
    dq = np.empty(3)
    dqn = joint_step(q, qp, dq)
    for i in range(INFO_I_SIZE):
        info_i[i] = 0
    for i in range(INFO_F_SIZE):
        info_f[i] = 0.0
    # the outlier gate (measured joints): the step against the one expected from the last two samples
    innov = np.zeros(3)
    if state[STATE_HAVE_Q2] > 0.0:
        for i in range(3):
            innov[i] = dq[i] - ext_scale * wrap(qp[i] - state[STATE_Q2 + i])
    info_f[F_INNOV] = max(abs(innov[0]), max(abs(innov[1]), abs(innov[2])))
    tol = params[PARAM_JOINT_TOL]
    forced = state[STATE_REFUSED] >= MAX_REFUSED
    gated = tol > 0.0 and params[PARAM_GATE] > 0.0 and state[STATE_HAVE_Q2] > 0.0 and not forced
    noise = 2.0 * tol * (1.0 + ext_scale)
    verdict = outlier_gate(innov, noise + params[PARAM_GATE] * state[STATE_A_SCALE], noise, Xp, qp, M, l1, l2sq,
                           b) if gated else GATE_PASS
    # a sample taken after refusals, or off the expected step by more than noise can be (a fast
    # joint the gate lets through, or a serial singularity's swing): it may be a glitch, so it is
    # vouched for by nothing and ends the chain
    untrusted = forced or (gated and info_f[F_INNOV] > noise)
    if verdict == GATE_REFUSE:
        X_out[:] = Xp
        X_pred[:] = Xp
        info_f[F_DQ] = dqn
        info_i[I_STATUS] = STATUS_REJECTED
        info_i[I_N_CAND] = int(state[STATE_N_CAND])
        info_i[I_INTACT] = 1 if state[STATE_INTACT] > 0.0 else 0
        return
    poses = np.empty((6, 3), dtype=np.complex128)
    real = np.empty(6, dtype=np.bool_)
    dk_one(q, model_pack, sample_to_sextic, rule, poses, real)
    qu = np.empty(3)                                   # q unwrapped next to the previous joints
    for i in range(3):
        qu[i] = qp[i] + dq[i]
    # eq. 22: the linear predictor at the previous pose
    dX = np.empty(3)
    cond_prev = velocity(Xp, qp, dq, M, l1, l2sq, b, dX)
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
    info_i[I_NEAR_BORDER] = 1 if n_near > 1 else 0
    info_i[I_N_REAL] = n_real
    info_f[F_COND_PREV] = cond_prev
    info_f[F_DQ] = dqn
    jump = dq_scale > 0.0 and dqn > params[PARAM_JUMP] * dq_scale
    info_i[I_JUMP] = 1 if jump else 0
    if n_real == 0:
        X_out[:] = Xp
        X_pred[:] = X_lin
        info_i[I_STATUS] = STATUS_UNREACHABLE
        info_i[I_N_CAND] = int(state[STATE_N_CAND])
        info_i[I_INTACT] = 1 if state[STATE_INTACT] > 0.0 else 0
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
            chosen, _ = nearest(poses, real, X_lin, w, near_prev, near_prev, near_prev, False)
    else:
        # continuation predictor along the joint segment, guarded near singularities
        nsub = int(min(params[PARAM_MAX_SUBSTEPS], max(1.0, math.ceil(dqn / params[PARAM_SUBSTEP_DQ]))))
        worst = continuation(Xp, qp, dq, nsub, M, l1, l2sq, b, X_pred)
        ok = worst > params[PARAM_SINGULAR]
        for i in range(3):
            ok = ok and math.isfinite(X_pred[i])
        if not ok:
            X_pred[:] = Xp if not (cond_prev > params[PARAM_SINGULAR]) else X_lin
        region = label_at_one(labels, origin, step, periodic, X_pred)
        info_i[I_REGION] = region
        use_map = params[PARAM_USE_MAP] > 0.0
        # tool-space extrapolation from the last two poses, scaled by the ratio of time steps
        have_ext = hist >= 2 and params[PARAM_STRATEGY] != STRATEGY_CONTINUATION
        X_ext = np.empty(3)
        for i in range(3):
            X_ext[i] = Xp[i] + ext_scale * (wrap(Xp[i] - X2[i]) if i == 2 else Xp[i] - X2[i])
        near_pred = np.zeros(7, dtype=np.bool_)
        near_ext = np.zeros(7, dtype=np.bool_)
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
        if have_ext:
            strategy = params[PARAM_STRATEGY]
            if kc == ke:
                chosen = kc
            else:
                ambiguous = True
                if strategy == STRATEGY_EXTRAPOLATION:
                    chosen = ke
                elif strategy == STRATEGY_SEGMENT:
                    chosen = ke if (not ok or worst < params[PARAM_SEGMENT_SINGULAR]) else kc
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
    chosen, linked = certified_choice(mode, chosen, state, qp, dq, ext_scale, poses, real, X_pred, w, params,
                                      model_pack, out_real[OUT_CANDS:OUT_CANDS + 18].reshape((6, 3)), info_i,
                                      untrusted)
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
    if mode != MODE_PAPER and d_best > params[PARAM_AMBIGUITY] * d_second:
        ambiguous = True
    if jump:
        ambiguous = True
    info_f[F_D_BEST] = d_best
    info_f[F_D_SECOND] = d_second
    for i in range(3):
        X_out[i] = Xr[i]
    step_dt = state[STATE_STEP_DT]
    if params[PARAM_JOINT_TOL] > 0.0 and params[PARAM_SPEED] > 0.0 and math.isfinite(step_dt) \
            and not linked:
        # measured joints: a pose the platform cannot have reached since the last sample (the
        # measured joints crossed a fold the robot did not) is not taken; the previous pose is held.
        # A solution a chain of Krawczyk boxes joins to the previous candidate crossed no fold.
        taken = speed_gate(poses, real, chosen, Xp, params, step_dt)
        if taken != chosen and mode != MODE_PAPER and not untrusted and ext_scale <= LINK_GAP and \
                state[STATE_N_CAND] == 1.0 and \
                comes_from(Xr, qu, dq, state[STATE_CANDS:STATE_CANDS + 18].reshape((6, 3)), int(state[STATE_N_CAND]),
                           LINK_TESTS * int(params[PARAM_MAX_TESTS]), model_pack):
            taken = chosen                         # a longer chain joins it to a previous candidate after all
                                                   # (the one candidate; not across a stuck joint's gap)
        if taken >= 0 and taken != chosen:
            # the solution the platform can have reached, if one alone can: taken, not vouched for
            chosen = taken
            for i in range(3):
                Xr[i] = poses[chosen, i].real
                X_out[i] = Xr[i]
            cands_out = out_real[OUT_CANDS:OUT_CANDS + 18].reshape((6, 3))
            cands_out[0, :] = Xr
            info_i[I_N_CAND] = 1
            info_i[I_CERTIFICATE] = CERT_NONE
            info_i[I_CERTAIN] = 0
            info_i[I_INTACT] = 0
            ambiguous = True
        elif taken < 0:
            X_out[:] = Xp
            info_i[I_STATUS] = STATUS_UNREACHABLE
            info_i[I_CERTAIN] = 0
            info_i[I_AMBIGUOUS] = 1
            info_i[I_N_CAND] = int(state[STATE_N_CAND])
            info_i[I_INTACT] = 1 if state[STATE_INTACT] > 0.0 else 0
            return
    J = np.empty((3, 3))
    kd = np.empty(3)
    jacobian(X_out, qu, M, l1, l2sq, b, J, kd)
    cond = hadamard(J)
    info_f[F_COND] = cond
    info_i[I_LABEL] = chosen + 1
    info_i[I_AMBIGUOUS] = 1 if ambiguous else 0
    info_i[I_STATUS] = STATUS_SINGULAR if cond < params[PARAM_SINGULAR] else STATUS_OK
