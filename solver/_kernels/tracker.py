"""One step of procedure 3 (the tracker), compiled, in phases.

One call does a whole step (all DK solutions, the predictor, procedure 2 on the map, the
choice, the certificates), so the per-step cost is the work, not Python overhead.
:class:`solver.Tracker` checks inputs, holds the state (which packs itself,
:meth:`solver.tracker_state.TrackerState.pack`) and calls :func:`tracker_step`.

The step runs its phases in order, each reading and writing the named packs of
:mod:`.tracker_packs` (the constant :data:`StepConfig`, the state pack, this step's
:data:`StepData`, the result pack's :data:`StepResult` views) and returning the decisions
it makes:

1. gate (:func:`gate_phase`): the outlier gate on measured joints; a refused sample ends the step;
2. solve (:func:`solve_phase`): all DK solutions, procedure 2 at the previous pose;
3. predict (:func:`.choice.linear_prediction`, :func:`.choice.predict`): eq. 22, the
   continuation, the extrapolation; no real solution ends the step;
4. choose (:func:`.choice.choose_paper`, :func:`.choice.choose_default`), then the margin
   to the other solutions (:func:`margins`);
5. certify (:func:`.certified.certify_phase`): the certificates and what they change in the choice;
6. speed gate (:func:`speed_gate_phase`): a pose the platform cannot have reached is not taken;
7. publish (:func:`publish`): the pose, its conditioning, label, flags and status.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .certified import certify_phase
from .certify import CERT_NONE, comes_from
from .choice import choose_default, choose_paper, linear_prediction, predict, wdist
from .direct_kinematics import dk_one
from .gates import GATE_PASS, GATE_REFUSE, outlier_gate, speed_gate
from .kinematics import jacobian
from .layout import (F_D_BEST, F_D_SECOND, F_DQ, F_COND, F_INNOV, I_AMBIGUOUS, I_CERTAIN, I_CERTIFICATE, I_INTACT,
                     I_JUMP, I_LABEL, I_N_CAND, I_N_REAL, I_NEAR_BORDER, I_STATUS, MAX_REFUSED, MODE_PAPER,
                     PARAM_AMBIGUITY, PARAM_GATE, PARAM_JOINT_TOL, PARAM_MAX_TESTS, PARAM_SINGULAR, PARAM_SPEED,
                     STATE_A_SCALE, STATE_CANDS, STATE_HAVE_Q2, STATE_INTACT, STATE_N_CAND, STATE_Q2, STATE_REFUSED,
                     STATE_STEP_DT, STATUS_OK, STATUS_REJECTED, STATUS_SINGULAR, STATUS_UNREACHABLE)
from .linalg import hadamard, wrap
from .maptensor import near_mask_one
from .tracker_packs import step_config, step_data, step_result

#: Before the speed gate holds the pose or takes another solution (default mode, a trusted sample, one
#: previous candidate), the chain back to that candidate may use this many times ``max_tests`` tests.
LINK_TESTS = 10
#: ... and only over a step of at most this many samples' time (not over a stuck joint's gap, which is
#: at least ``stuck_after`` >= 5 samples for every sensor grade of the benchmark).
LINK_GAP = 4.0


@njit(cache=True)
def tracker_step(mode, rule, q, state, model_pack, sample_to_sextic, labels, map_pack, stencil, params,
                 out_real, out_int):
    """One step of procedure 3 (``mode`` MODE_PAPER or MODE_DEFAULT); see :mod:`solver.tracker`.

    Reads the joints ``q`` (3,) rad, the state pack ``state`` (STATE_SIZE,), the model pack
    and ``sample_to_sextic`` (the DK constants), the map's ``labels``, its map pack and
    procedure-2 ``stencil``, the options ``params`` (PARAM_SIZE,), and the ordering ``rule``;
    writes the result pack ``out_real`` (OUT_SIZE,) and ``out_int`` (INFO_I_SIZE,).  The
    phases: see the module docstring.
    """
    cfg = step_config(mode, rule, model_pack, sample_to_sextic, labels, map_pack, stencil, params)
    st = step_data(q, state, params)
    res = step_result(out_real, out_int)
    refused, untrusted = gate_phase(cfg, st, state, res)
    if refused:
        return
    n_real, n_near, single = solve_phase(cfg, st, state, res)
    cond_prev = linear_prediction(cfg, st, res)
    if n_real == 0:
        res.X_pred[:] = st.X_lin
        hold(st, state, res, STATUS_UNREACHABLE)
        return
    ok, worst = predict(cfg, st, res, cond_prev)
    if mode == MODE_PAPER:
        chosen, ambiguous = choose_paper(cfg, st, res, n_near, single)
    else:
        chosen, ambiguous = choose_default(cfg, st, state, res, n_near, ok, worst)
    chosen, linked = certify_phase(cfg, st, state, res, chosen, untrusted)
    if margins(cfg, st, res, chosen):
        ambiguous = True
    taken = speed_gate_phase(cfg, st, state, res, chosen, linked, untrusted)
    if taken < 0:
        return
    publish(cfg, st, res, taken, ambiguous or taken != chosen)


@njit(cache=True)
def hold(st, state, res, status):
    """The previous pose held (a refused or unreachable sample): the pose, the status, and the
    candidates and chain as they were."""
    res.X[:] = st.Xp
    res.info_i[I_STATUS] = status
    res.info_i[I_N_CAND] = int(state[STATE_N_CAND])
    res.info_i[I_INTACT] = 1 if state[STATE_INTACT] > 0.0 else 0


@njit(cache=True)
def gate_phase(cfg, st, state, res):
    """Gate phase (measured joints): the joint step against the one expected from the last two
    samples (:func:`.gates.outlier_gate`).  Writes F_INNOV and F_DQ, and a refused sample's
    result (pose held, status rejected).  Returns (refused, untrusted): an untrusted sample
    (taken after refusals, or off the expected step by more than noise can be: a fast joint
    the gate lets through, or a serial singularity's swing) may be a glitch, so it is vouched
    for by nothing and ends the chain."""
    params, info_f = cfg.params, res.info_f
    innov = np.zeros(3)
    if state[STATE_HAVE_Q2] > 0.0:
        for i in range(3):
            innov[i] = st.dq[i] - st.ext_scale * wrap(st.qp[i] - state[STATE_Q2 + i])
    info_f[F_INNOV] = max(abs(innov[0]), max(abs(innov[1]), abs(innov[2])))
    info_f[F_DQ] = st.dqn
    tol = params[PARAM_JOINT_TOL]
    forced = state[STATE_REFUSED] >= MAX_REFUSED
    gated = tol > 0.0 and params[PARAM_GATE] > 0.0 and state[STATE_HAVE_Q2] > 0.0 and not forced
    noise = 2.0 * tol * (1.0 + st.ext_scale)
    verdict = outlier_gate(innov, noise + params[PARAM_GATE] * state[STATE_A_SCALE], noise, st.Xp, st.qp, cfg.M,
                           cfg.l1, cfg.l2sq, cfg.b) if gated else GATE_PASS
    untrusted = forced or (gated and info_f[F_INNOV] > noise)
    if verdict == GATE_REFUSE:
        res.X_pred[:] = st.Xp
        hold(st, state, res, STATUS_REJECTED)
        return True, untrusted
    return False, untrusted


@njit(cache=True)
def solve_phase(cfg, st, state, res):
    """Solve phase: the DK solutions at ``st.q`` (``st.poses``, ``st.real``, numbered by the
    rule) and procedure 2 at the previous pose (``st.near_prev``).  Writes I_N_REAL,
    I_NEAR_BORDER, I_JUMP.  Returns (real solutions, labels seen near the previous pose, the
    last of them)."""
    dk_one(st.q, cfg.model_pack, cfg.sample_to_sextic, cfg.rule, st.poses, st.real)
    near_mask_one(cfg.labels, cfg.origin, cfg.step, cfg.periodic, st.Xp, cfg.r2, cfg.w, cfg.stencil, st.near_prev)
    n_near = 0
    single = 0
    for lab in range(1, 7):
        if st.near_prev[lab]:
            n_near += 1
            single = lab
    n_real = 0
    for k in range(6):
        if st.real[k]:
            n_real += 1
    res.info_i[I_NEAR_BORDER] = 1 if n_near > 1 else 0
    res.info_i[I_N_REAL] = n_real
    res.info_i[I_JUMP] = 1 if st.jump else 0
    return n_real, n_near, single


@njit(cache=True)
def margins(cfg, st, res, chosen):
    """Choose phase, the margin: weighted distances (m) from the prediction to the chosen and to
    the nearest other real solution (F_D_BEST, F_D_SECOND).  Returns whether the choice is
    ambiguous for it (default mode: d_best > ambiguity_ratio d_second; or a jump)."""
    w, X_pred = cfg.w, res.X_pred
    Xr = np.empty(3)
    for i in range(3):
        Xr[i] = st.poses[chosen, i].real
    d_best = wdist(Xr, X_pred, w)
    d_second = np.inf
    for k in range(6):
        if st.real[k] and k != chosen:
            for i in range(3):
                Xr[i] = st.poses[k, i].real
            d_second = min(d_second, wdist(Xr, X_pred, w))
    res.info_f[F_D_BEST] = d_best
    res.info_f[F_D_SECOND] = d_second
    return (cfg.mode != MODE_PAPER and d_best > cfg.params[PARAM_AMBIGUITY] * d_second) or st.jump


@njit(cache=True)
def speed_gate_phase(cfg, st, state, res, chosen, linked, untrusted):
    """Speed gate phase (measured joints, a speed bound): a pose the platform cannot have reached
    since the last sample (the measured joints crossed a fold the robot did not) is not taken.

    Not applied to a solution a chain of Krawczyk boxes joins to a previous candidate
    (``linked``: it crossed no fold) or that was re-acquired.  Before it acts (default mode, a
    trusted sample, one previous candidate, not across a stuck joint's gap) a longer chain
    back may still link it.  Returns the solution taken: ``chosen``; the one within reach
    (its result written: one candidate, no certificate, not vouched for); or -1 when the pose
    is held (result written: status unreachable).
    """
    params = cfg.params
    step_dt = state[STATE_STEP_DT]
    if not (params[PARAM_JOINT_TOL] > 0.0 and params[PARAM_SPEED] > 0.0 and math.isfinite(step_dt)) or linked:
        return chosen
    taken = speed_gate(st.poses, st.real, chosen, st.Xp, params, step_dt)
    if taken != chosen and cfg.mode != MODE_PAPER and not untrusted and st.ext_scale <= LINK_GAP and \
            state[STATE_N_CAND] == 1.0:
        Xr = np.empty(3)
        for i in range(3):
            Xr[i] = st.poses[chosen, i].real
        if comes_from(Xr, st.qu, st.dq, state[STATE_CANDS:STATE_CANDS + 18].reshape((6, 3)),
                      int(state[STATE_N_CAND]), LINK_TESTS * int(params[PARAM_MAX_TESTS]), cfg.model_pack):
            taken = chosen
    info_i = res.info_i
    if taken >= 0 and taken != chosen:
        for i in range(3):
            res.cands[0, i] = st.poses[taken, i].real
        info_i[I_N_CAND] = 1
        info_i[I_CERTIFICATE] = CERT_NONE
        info_i[I_CERTAIN] = 0
        info_i[I_INTACT] = 0
    elif taken < 0:
        hold(st, state, res, STATUS_UNREACHABLE)
        info_i[I_CERTAIN] = 0
        info_i[I_AMBIGUOUS] = 1
    return taken


@njit(cache=True)
def publish(cfg, st, res, chosen, ambiguous):
    """Publish phase: the pose of solution ``chosen`` (res.X), the Hadamard ratio of J there
    (F_COND), the label, the ambiguity and the status (singular below ``singular_tol``)."""
    for i in range(3):
        res.X[i] = st.poses[chosen, i].real
    J = np.empty((3, 3))
    kd = np.empty(3)
    jacobian(res.X, st.qu, cfg.M, cfg.l1, cfg.l2sq, cfg.b, J, kd)
    cond = hadamard(J)
    res.info_f[F_COND] = cond
    res.info_i[I_LABEL] = chosen + 1
    res.info_i[I_AMBIGUOUS] = 1 if ambiguous else 0
    res.info_i[I_STATUS] = STATUS_SINGULAR if cond < cfg.params[PARAM_SINGULAR] else STATUS_OK
