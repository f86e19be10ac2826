"""One step of procedure 3 (the tracker), compiled, in phases.

One call does a whole step (all DK solutions, the predictor, procedure 2 on the map, the
choice, the certificates), so the per-step cost is the work, not Python overhead.
:class:`solver.Tracker` checks inputs and calls :func:`.stepper.tracker_advance`, which packs
its flat state, calls :func:`tracker_step` and advances the state.

The step runs its phases in order, each reading and writing named fields of the packs
of :mod:`.tracker_packs` (the options, model and map packs, the state pack, this step's
step pack and DK solutions, the result pack) and returning the decisions it makes:

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

from .anytime import ANY_CUT, ANY_DEADLINE, ANY_K_ON, ANY_N, ANY_R_ON
from .certified import certify_phase
from .certify import CERT_NONE, comes_from
from .clock import expired
from .choice import choose_default, choose_paper, joint_step, linear_prediction, predict, wdist
from .direct_kinematics import dk_one
from .gates import GATE_PASS, GATE_REFUSE, outlier_gate, speed_gate, swing
from .kinematics import geometry, jacobian
from .layout import (F_D_BEST, F_D_SECOND, F_DQ, F_COND, F_INNOV, I_AMBIGUOUS, I_CERTAIN, I_CERTIFICATE, I_INTACT,
                     I_JUMP, I_LABEL, I_N_CAND, I_N_REAL, I_NEAR_BORDER, I_STATUS, I_TRUST, INFO_F_SIZE, INFO_I_SIZE,
                     MAP_ORIGIN, MAP_PERIODIC, MAP_R2, MAP_STEP, MAP_WEIGHTS, MAX_REFUSED, MODE_PAPER, OUT_BOUND,
                     OUT_CANDS, OUT_INFO, OUT_X,
                     OUT_X_PRED, PARAM_AMBIGUITY, PARAM_GATE, PARAM_JOINT_TOL, PARAM_JUMP, PARAM_MAX_TESTS,
                     PARAM_SINGULAR, PARAM_SPEED, STATE_A_SCALE, STATE_CANDS, STATE_DQ_SCALE, STATE_EXT_SCALE,
                     STATE_HAVE_Q2, STATE_INTACT, STATE_N_CAND, STATE_Q, STATE_Q2, STATE_REFUSED, STATE_STEP_DT,
                     STATE_N_TUBES, STATE_X, STATUS_OK, STATUS_REJECTED, STATUS_SINGULAR, STATUS_UNREACHABLE,
                     TRUST_LOST, TRUST_POSSIBLE)
from .linalg import hadamard, wrap
from .maptensor import near_mask_one
from .scratch import floats, scratch, scratch2
from .tracker_packs import STEP_DQ, STEP_DQN, STEP_JUMP, STEP_QU, STEP_SIZE, STEP_X_LIN

#: Before the speed gate holds the pose or takes another solution (default mode, a trusted sample, one
#: previous candidate), the chain back to that candidate may use this many times ``max_tests`` tests.
LINK_TESTS = 10
#: ... and only over a step of at most this many samples' time (not over a stuck joint's gap, which is
#: at least ``stuck_after`` >= 5 samples for every sensor grade of the benchmark).
LINK_GAP = 4.0


@njit(cache=False)      # compiled into its one caller, :func:`.stepper.tracker_advance` (cached there, shipped once)
def tracker_step(mode, rule, q, state, model_pack, sample_to_sextic, labels, map_pack, stencil, params,
                 out_real, out_int, anytime):
    """One step of procedure 3 (``mode`` MODE_PAPER or MODE_DEFAULT); see :mod:`solver.tracker`.

    Reads the joints ``q`` (3,) rad, the state pack ``state`` (STATE_SIZE,), the model pack
    and ``sample_to_sextic`` (the DK constants), the map's ``labels``, its map pack and
    procedure-2 ``stencil``, the options ``params`` (PARAM_SIZE,), and the ordering ``rule``;
    writes the result pack ``out_real`` (OUT_SIZE,) and ``out_int`` (INFO_I_SIZE,); reads and
    rewrites the anytime pack ``anytime`` (ANY_SIZE,, :mod:`.anytime`: the step's deadline, the
    walk of the tube chain, whether the deadline cut the step).  The phases: see the module
    docstring.
    """
    work = floats(STEP_SIZE)
    step_pack(q, state, params, out_real, out_int, work)
    anytime[ANY_CUT] = 0.0
    refused, untrusted = gate_phase(state, work, params, model_pack, out_real, out_int)
    if refused and not (params[PARAM_SPEED] > 0.0 and math.isfinite(state[STATE_STEP_DT])):
        refuse(state, out_real, out_int)
        return
    poses = scratch2(6, 3, np.complex128)
    real = scratch(6, np.bool_)
    near_prev = scratch(7, np.bool_)
    near_prev[:] = False
    n_real, n_near, single = solve_phase(q, rule, state, work, model_pack, sample_to_sextic, labels, map_pack,
                                         stencil, poses, real, near_prev, out_int)
    if refused:
        M, l1, l2sq, b = geometry(model_pack)
        noise = 2.0 * params[PARAM_JOINT_TOL] * (1.0 + state[STATE_EXT_SCALE])
        if not swing(poses, real, state[STATE_X:STATE_X + 3], state[STATE_Q:STATE_Q + 3], noise, params,
                     state[STATE_STEP_DT], M, l1, l2sq, b):
            refuse(state, out_real, out_int)
            return
        untrusted = True                       # a joint's swing: taken, vouched for by nothing,
        out_real[OUT_INFO + F_INNOV] = state[STATE_A_SCALE]      # and the gate's envelopes stay as they
        out_real[OUT_INFO + F_DQ] = state[STATE_DQ_SCALE]        # were (a glitch must not open the gate)
    cond_prev = linear_prediction(state, work, model_pack, out_real)
    if n_real == 0:
        out_real[OUT_X_PRED:OUT_X_PRED + 3] = work[STEP_X_LIN:STEP_X_LIN + 3]
        hold(state, out_real, out_int, STATUS_UNREACHABLE)
        return
    ok, worst = predict(mode, state, work, params, model_pack, out_real, cond_prev)
    if mode == MODE_PAPER:
        chosen, ambiguous = choose_paper(poses, real, near_prev, work, labels, map_pack, n_near, single, out_int)
    else:
        chosen, ambiguous = choose_default(poses, real, near_prev, work, state, params, labels, map_pack, stencil,
                                           n_near, ok, worst, out_real, out_int)
    chosen, linked = certify_phase(mode, chosen, untrusted, state, work, poses, real, params, model_pack, map_pack,
                                   out_real, out_int, anytime)
    if margins(mode, chosen, poses, real, work, params, map_pack, out_real):
        ambiguous = True
    taken = speed_gate_phase(mode, chosen, linked, untrusted, state, work, poses, real, params, model_pack,
                             out_real, out_int, anytime[ANY_DEADLINE])
    # the budget ran out before the step's proofs ended: the deadline passed, or an unfinished proof goes on
    anytime[ANY_CUT] = 1.0 if expired(anytime[ANY_DEADLINE]) or anytime[ANY_N] > 0.0 or anytime[ANY_K_ON] > 0.0 \
        or anytime[ANY_R_ON] > 0.0 else 0.0
    if taken < 0:
        return
    publish(taken, ambiguous or taken != chosen, poses, work, params, model_pack, out_real, out_int)


@njit(cache=False)
def step_pack(q, state, params, out_real, out_int, work):
    """The step pack ``work`` (STEP_SIZE,, :mod:`.tracker_packs`) of joints ``q`` (3,): the joint step, its
    size, the unwrapped joints and the jump flag (the predictions are filled by the predict
    phase); the result pack's info fields zeroed."""
    for i in range(INFO_I_SIZE):
        out_int[i] = 0
    for i in range(INFO_F_SIZE):
        out_real[OUT_INFO + i] = 0.0
    for i in range(3):
        out_real[OUT_BOUND + i] = np.inf
    qp = state[STATE_Q:STATE_Q + 3]
    dqn = joint_step(q, qp, work[STEP_DQ:STEP_DQ + 3])
    for i in range(3):
        work[STEP_QU + i] = qp[i] + work[STEP_DQ + i]
    dq_scale = state[STATE_DQ_SCALE]
    work[STEP_DQN] = dqn
    work[STEP_JUMP] = 1.0 if dq_scale > 0.0 and dqn > params[PARAM_JUMP] * dq_scale else 0.0


@njit(cache=False)
def hold(state, out_real, out_int, status):
    """The previous pose held (a refused or unreachable sample): the pose, the status, and the
    candidates and chain as they were; not certain (no bound), possible while the last step was."""
    out_real[OUT_X:OUT_X + 3] = state[STATE_X:STATE_X + 3]
    out_int[I_TRUST] = TRUST_POSSIBLE if state[STATE_N_TUBES] > 0.0 else TRUST_LOST
    out_int[I_STATUS] = status
    out_int[I_N_CAND] = int(state[STATE_N_CAND])
    out_int[I_INTACT] = 1 if state[STATE_INTACT] > 0.0 else 0


@njit(cache=False)
def gate_phase(state, work, params, model_pack, out_real, out_int):
    """Gate phase (measured joints): the joint step against the one expected from the last two
    samples (:func:`.gates.outlier_gate`).  Writes F_INNOV and F_DQ, and a refused sample's
    result (pose held, status rejected).  Returns (refused, untrusted): an untrusted sample
    (taken after refusals, or off the expected step by more than the gate allows, noise plus
    ``gate`` times the recent envelope, yet let through because it barely moves the pose: a
    serial singularity's swing) may be a glitch, so it is vouched for by nothing and ends the
    chain.  Steps off by less (a joint accelerating as it did in recent samples), and the first
    innovation (no envelope yet to judge it by), are vouched for under the sensor's tolerance like
    any other."""
    Xp, qp, dq = state[STATE_X:STATE_X + 3], state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3]
    ext_scale = state[STATE_EXT_SCALE]
    innov = floats(3)
    innov[:] = 0.0
    if state[STATE_HAVE_Q2] > 0.0:
        for i in range(3):
            innov[i] = dq[i] - ext_scale * wrap(qp[i] - state[STATE_Q2 + i])
    worst = max(abs(innov[0]), max(abs(innov[1]), abs(innov[2])))
    out_real[OUT_INFO + F_INNOV] = worst
    out_real[OUT_INFO + F_DQ] = work[STEP_DQN]
    tol = params[PARAM_JOINT_TOL]
    forced = state[STATE_REFUSED] >= MAX_REFUSED
    gated = tol > 0.0 and params[PARAM_GATE] > 0.0 and state[STATE_HAVE_Q2] > 0.0 and not forced
    noise = 2.0 * tol * (1.0 + ext_scale)
    verdict = GATE_PASS
    if gated:
        M, l1, l2sq, b = geometry(model_pack)
        verdict = outlier_gate(innov, noise + params[PARAM_GATE] * state[STATE_A_SCALE], noise, Xp, qp, M, l1, l2sq,
                               b)
    a_scale = state[STATE_A_SCALE]
    untrusted = forced or (gated and a_scale > 0.0 and worst > noise + params[PARAM_GATE] * a_scale)
    return verdict == GATE_REFUSE, untrusted


@njit(cache=False)
def refuse(state, out_real, out_int):
    """A refused sample's result: the previous pose held, status rejected (no solutions reported)."""
    out_int[I_N_REAL] = 0
    out_int[I_NEAR_BORDER] = 0
    out_real[OUT_X_PRED:OUT_X_PRED + 3] = state[STATE_X:STATE_X + 3]
    hold(state, out_real, out_int, STATUS_REJECTED)


@njit(cache=False)
def solve_phase(q, rule, state, work, model_pack, sample_to_sextic, labels, map_pack, stencil, poses, real,
                near_prev, out_int):
    """Solve phase: the DK solutions at ``q`` into ``poses`` (6, 3) complex / ``real`` (6,), numbered
    by the ordering ``rule``, and procedure 2 at the previous pose into ``near_prev`` (7,).
    Writes I_N_REAL, I_NEAR_BORDER, I_JUMP.  Returns (real solutions, labels seen near the
    previous pose, the last of them)."""
    dk_one(q, model_pack, sample_to_sextic, rule, poses, real)
    near_mask_one(labels, map_pack[MAP_ORIGIN:MAP_ORIGIN + 3], map_pack[MAP_STEP:MAP_STEP + 3],
                  map_pack[MAP_PERIODIC] > 0.0, state[STATE_X:STATE_X + 3], map_pack[MAP_R2],
                  map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3], stencil, near_prev)
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
    out_int[I_NEAR_BORDER] = 1 if n_near > 1 else 0
    out_int[I_N_REAL] = n_real
    out_int[I_JUMP] = 1 if work[STEP_JUMP] > 0.0 else 0
    return n_real, n_near, single


@njit(cache=False)
def margins(mode, chosen, poses, real, work, params, map_pack, out_real):
    """Choose phase, the margin: weighted distances (m) from the prediction to the chosen and to
    the nearest other real solution (F_D_BEST, F_D_SECOND).  Returns whether the choice is
    ambiguous for it (default mode: d_best > ambiguity_ratio d_second; or a jump)."""
    w, X_pred = map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3], out_real[OUT_X_PRED:OUT_X_PRED + 3]
    Xr = floats(3)
    for i in range(3):
        Xr[i] = poses[chosen, i].real
    d_best = wdist(Xr, X_pred, w)
    d_second = np.inf
    for k in range(6):
        if real[k] and k != chosen:
            for i in range(3):
                Xr[i] = poses[k, i].real
            d_second = min(d_second, wdist(Xr, X_pred, w))
    out_real[OUT_INFO + F_D_BEST] = d_best
    out_real[OUT_INFO + F_D_SECOND] = d_second
    return (mode != MODE_PAPER and d_best > params[PARAM_AMBIGUITY] * d_second) or work[STEP_JUMP] > 0.0


@njit(cache=False)
def speed_gate_phase(mode, chosen, linked, untrusted, state, work, poses, real, params, model_pack, out_real,
                     out_int, deadline=0.0):
    """Speed gate phase (measured joints, a speed bound): a pose the platform cannot have reached
    since the last sample (the measured joints crossed a fold the robot did not) is not taken.

    Not applied to a solution a chain of Krawczyk boxes joins to a previous candidate
    (``linked``: it crossed no fold) or that was re-acquired.  Before it acts (default mode, a
    trusted sample, one previous candidate, not across a stuck joint's gap) a longer chain
    back may still link it.  Returns the solution taken: ``chosen``; the one within reach
    (its result written: one candidate, no certificate, not vouched for); or -1 when the pose
    is held (result written: status unreachable).
    """
    step_dt = state[STATE_STEP_DT]
    if not (params[PARAM_JOINT_TOL] > 0.0 and params[PARAM_SPEED] > 0.0 and math.isfinite(step_dt)) or linked:
        return chosen
    taken = speed_gate(poses, real, chosen, state[STATE_X:STATE_X + 3], params, step_dt)
    if taken != chosen and mode != MODE_PAPER and not untrusted and state[STATE_EXT_SCALE] <= LINK_GAP and \
            state[STATE_N_CAND] == 1.0:
        Xr = floats(3)
        for i in range(3):
            Xr[i] = poses[chosen, i].real
        if comes_from(Xr, work[STEP_QU:STEP_QU + 3], work[STEP_DQ:STEP_DQ + 3],
                      state[STATE_CANDS:STATE_CANDS + 18].reshape((6, 3)), int(state[STATE_N_CAND]),
                      LINK_TESTS * int(params[PARAM_MAX_TESTS]), model_pack, deadline):
            taken = chosen
    if taken >= 0 and taken != chosen:
        for i in range(3):
            out_real[OUT_CANDS + i] = poses[taken, i].real
        out_int[I_N_CAND] = 1
        out_int[I_CERTIFICATE] = CERT_NONE
        out_int[I_CERTAIN] = 0
        out_int[I_INTACT] = 0
        out_int[I_TRUST] = TRUST_LOST
        for i in range(3):
            out_real[OUT_BOUND + i] = np.inf
    elif taken < 0:
        hold(state, out_real, out_int, STATUS_UNREACHABLE)
        out_int[I_CERTAIN] = 0
        out_int[I_AMBIGUOUS] = 1
        for i in range(3):
            out_real[OUT_BOUND + i] = np.inf
    return taken


@njit(cache=False)
def publish(chosen, ambiguous, poses, work, params, model_pack, out_real, out_int):
    """Publish phase: the pose of solution ``chosen`` (OUT_X), the Hadamard ratio of J there
    (F_COND), the label, the ambiguity and the status (singular below ``singular_tol``)."""
    M, l1, l2sq, b = geometry(model_pack)
    X = out_real[OUT_X:OUT_X + 3]
    for i in range(3):
        X[i] = poses[chosen, i].real
    J = scratch2(3, 3, np.float64)
    kd = floats(3)
    jacobian(X, work[STEP_QU:STEP_QU + 3], M, l1, l2sq, b, J, kd)
    cond = hadamard(J)
    out_real[OUT_INFO + F_COND] = cond
    out_int[I_LABEL] = chosen + 1
    out_int[I_AMBIGUOUS] = 1 if ambiguous else 0
    out_int[I_STATUS] = STATUS_SINGULAR if cond < params[PARAM_SINGULAR] else STATUS_OK
