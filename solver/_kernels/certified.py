"""The certify phase of a tracker step (:mod:`.tracker`), compiled: the certificates
(:func:`.candidates.certify`), re-acquisition (:func:`.exclusion.reacquire`), and what they change
in the choice.

The phase reads the state pack (the candidates, whether the chain is verified and intact),
the step pack (the joint step; :mod:`.tracker_packs`) and the DK solutions, and writes the
new candidates (OUT_CANDS) and the I_CERTAIN, I_CERTIFICATE, I_N_CAND, I_INTACT fields of the
result pack.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .anytime import (ANY_DEADLINE, ANY_K_INTACT, ANY_K_ON, ANY_N, ANY_R_ON, WALK_CLOSED, cont_append, cont_begin, cont_on,
                      walk_append, walk_begin, walk_on)
from .candidates import certify
from .certify import CERT_CONTINUATION, CERT_NONE, CERT_REACQUIRED, CERT_TUBE, FOLLOW_CUT, FOLLOW_DONE, same_pose
from .choice import nearest
from .clock import cycles, expired
from .kinematics import as_built, geometry
from .layout import (I_CERTAIN, I_CERTIFICATE, I_INTACT, I_N_CAND, I_TRUST, MAP_WEIGHTS, MODE_PAPER, OUT_BOUND,
                     OUT_CANDS, OUT_N_PAVE, OUT_N_TUBES, OUT_REGION, OUT_TUBE, OUT_X_PRED, PARAM_JOINT_TOL,
                     PARAM_MAX_TESTS, PARAM_POSTURE_BITS, PARAM_REACQUIRE, PAVE_BOXES, STATE_CANDS, STATE_EXT_SCALE,
                     STATE_HAVE_Q2, STATE_INTACT, STATE_N_CAND, STATE_N_TUBES, STATE_Q, STATE_Q2, STATE_TUBE,
                     STATE_VERIFIED, TRUST_CERTAIN, TRUST_LOST, TRUST_POSSIBLE)
from .linalg import turns_to, wrap
from .paving import region_step
from .reacquisition import cover_solution, eliminant_reacquired, reacquired, reacquired_anytime, region_choice
from .scratch import floats, scratch
from .tracker_packs import STEP_DQ, STEP_QU
from .tube import TUBE_SIZE, tube_test
from .tube_chain import MAX_COVER, pose_bound, tube_chain

#: Tube tests one step's tube chain may use (a step far from singularities uses two).
TUBE_TESTS = 1200
#: With a step budget: the share of the time left that a walk from a certain step's cover may use first
#: (it usually ends in a few tests), then the share of the rest that the chains of boxes (the choice) may
#: use before the walk goes on (:func:`budgeted`).
WALK_SHARE, CHAIN_SHARE = 0.3, 0.6
#: With measured joints, while a walk is under way: the chains of boxes only steer the choice and the
#: walk is what brings certainty back, so the chains get this share; and the share of the step's time
#: kept for the set-membership step (:func:`region_step`) after the walk and re-acquisition.
PENDING_CHAIN_SHARE, REGION_SHARE = 0.25, 0.15


@njit(cache=True)
def share(deadline, fraction):
    """A deadline ``fraction`` of the way from now to ``deadline`` (:mod:`.clock`; 0.0 stays none)."""
    if deadline <= 0.0:
        return 0.0
    now = float(cycles())
    return now + fraction * max(deadline - now, 0.0)


@njit(cache=False)
def certify_phase(mode, chosen, untrusted, state, work, poses, real, params, model_pack, map_pack, out_real,
                  out_int, anytime):
    """The certificates of a step and what they change in the choice.

    First the tube chain (:func:`tube_step`) from the last certain step's tube; then the
    chains of boxes along the measured joints (:func:`chains`: continuation, elimination,
    posture), which vouch with exact joints; with measured joints (``joint_tolerance > 0``)
    they only steer the choice, and certainty comes back by re-acquisition from this sample
    alone.  Updates the candidate set (OUT_CANDS) and writes I_CERTAIN, I_CERTIFICATE, I_N_CAND,
    I_INTACT, I_TRUST, the step's cover of tubes (OUT_TUBE, OUT_N_TUBES) and the pose bound (OUT_BOUND, inf when not
    certain).  In default mode a choice the certificates rule out is replaced: by the one
    candidate left, or by the candidate nearest the prediction.  Paper mode keeps its answer
    and is certain only when it is the one candidate left.  An ``untrusted`` sample (its
    joints may be a glitch) is not re-acquired from, vouched for nothing and ends the chain.
    Returns the (possibly new) chosen solution index, and whether a chain of boxes joins it to
    a previous candidate or it was re-acquired (the speed gate then leaves it alone).

    With a step budget (the anytime pack's deadline, :mod:`.anytime`) every search stops at the
    deadline; the tube chain is a walk that the next steps continue, and it shares the time with
    the chains of boxes, which steer the choice (:func:`budgeted`); re-acquisition and the
    set-membership step get what is left.
    """
    new_cands = out_real[OUT_CANDS:OUT_CANDS + 18].reshape((6, 3))
    tubes = out_real[OUT_TUBE:OUT_TUBE + MAX_COVER * TUBE_SIZE].reshape((MAX_COVER, TUBE_SIZE))
    bound = out_real[OUT_BOUND:OUT_BOUND + 3]
    n_tubes = 0
    boxed = False                              # re-acquired by the eliminant: the bound is its box, no tubes
    for r in range(3):
        bound[r] = np.inf
    keep = scratch(6, np.bool_)
    tol = params[PARAM_JOINT_TOL]
    measured = is_measured(params, model_pack)
    sol = -1
    deadline = anytime[ANY_DEADLINE]
    if untrusted or deadline <= 0.0:           # a glitch may break the path the walk assumes; a step
        anytime[ANY_N] = 0.0                   # without a budget carries no unfinished proof on
        anytime[ANY_K_ON] = 0.0
        anytime[ANY_R_ON] = 0.0
    if deadline > 0.0:
        sol, n_tubes, n_new, cert, intact, linked = budgeted(untrusted, state, work, poses, real, params, model_pack,
                                                             new_cands, keep, tubes, anytime, bound)
    elif state[STATE_N_TUBES] > 0.0 and not untrusted:
        sol, n_tubes = tube_step(state, work, poses, real, tol, model_pack, tubes, bound)
    if sol >= 0:
        n_new, cert, intact, linked = 1, CERT_TUBE, True, True
        for k in range(6):
            keep[k] = k == sol
        new_cands[0, :] = poses[sol].real
    else:
        if deadline <= 0.0:
            n_new, cert, intact, linked = chains(state, work, poses, real, params, model_pack, new_cands, keep)
        if measured:                           # along the measured joints: a choice, not a proof
            intact = False
            if params[PARAM_REACQUIRE] > 0.0 and int(params[PARAM_POSTURE_BITS]) >= 0 and not untrusted:
                if deadline > 0.0:             # resumable (a proof the deadline cuts goes on next step),
                    n_tubes = 0                # and not while a walk from the last certain step is under way
                    if anytime[ANY_N] <= 0.0:
                        n_tubes = reacquired_anytime(chosen, cert != CERT_NONE, state, work, poses, real, params,
                                                     model_pack, new_cands, keep, tubes, anytime, TUBE_TESTS,
                                                     share(deadline, 1.0 - REGION_SHARE))
                else:
                    n_tubes = reacquired(chosen, cert != CERT_NONE, state, work, poses, real, params, model_pack,
                                         new_cands, keep, tubes)
                if n_tubes > 0:
                    n_new, cert, intact, linked = 1, CERT_REACQUIRED, True, True
                elif not expired(deadline) and eliminant_reacquired(chosen, cert != CERT_NONE, state, work, poses,
                                                                    real, params, model_pack, new_cands, keep,
                                                                    bound, deadline):
                    n_new, cert, intact, linked, boxed = 1, CERT_REACQUIRED, True, True, True
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
        mask = scratch(7, np.bool_)
        mask[0] = False
        for k in range(6):
            mask[k + 1] = keep[k]
        chosen, _ = nearest(poses, real, out_real[OUT_X_PRED:OUT_X_PRED + 3], map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3],
                            mask, mask, mask, True)
    if not certain and measured and mode != MODE_PAPER and not untrusted and \
            int(params[PARAM_POSTURE_BITS]) >= 0:    # not a pose the robot cannot be at
        taken = region_choice(chosen, poses, real, params, state, work[STEP_QU:STEP_QU + 3], model_pack)
        if taken != chosen:
            chosen, n_new, cert, intact, linked = taken, 1, CERT_NONE, False, True
            for i in range(3):
                new_cands[0, i] = poses[taken, i].real
    if untrusted:
        certain, intact, linked = False, False, False
    Xc = floats(3)
    for i in range(3):
        Xc[i] = poses[chosen, i].real
    qu = work[STEP_QU:STEP_QU + 3]
    if certain and cert != CERT_TUBE and cert != CERT_REACQUIRED:       # exact joints: the point's tube
        M, l1, l2sq, b = geometry(model_pack)
        zero = floats(3)
        zero[:] = 0.0
        certain = tube_test(Xc, qu, zero, zero, M, l1, l2sq, b, tubes[0])
        n_tubes = 1
    if certain and not boxed and not (cert == CERT_TUBE and chosen == sol):     # (the tube chain's own: its
        certain = pose_bound(tubes, n_tubes, qu, tol, Xc, bound)                 # bound is written already)
    if not certain:                            # (also an eliminant's bound about a solution not taken)
        for r in range(3):
            bound[r] = np.inf
    out_real[OUT_N_TUBES] = n_tubes if certain else 0
    out_real[OUT_REGION:OUT_REGION + 6], out_real[OUT_N_PAVE] = np.nan, 0.0
    if not certain and measured and not untrusted:
        region_step(state, qu, params, model_pack, out_real[OUT_REGION:OUT_REGION + 6],
                    out_real[OUT_N_PAVE:OUT_N_PAVE + 1 + 6 * PAVE_BOXES], deadline)
    elif certain and boxed:
        paving_cut(state, qu, params, model_pack, Xc, bound, out_real, deadline)
    if certain or n_tubes > 0:
        anytime[ANY_N] = 0.0                   # certain (or re-acquired): no walk, continuation or
        anytime[ANY_K_ON] = 0.0                # re-acquisition left
        anytime[ANY_R_ON] = 0.0
    out_int[I_CERTAIN] = 1 if certain else 0
    out_int[I_CERTIFICATE] = cert
    out_int[I_N_CAND] = n_new
    out_int[I_INTACT] = 1 if intact else 0
    out_int[I_TRUST] = TRUST_CERTAIN if certain else (TRUST_POSSIBLE if linked or n_new == 1 else TRUST_LOST)
    return chosen, linked


@njit(cache=False)
def budgeted(untrusted, state, work, poses, real, params, model_pack, new_cands, keep, tubes, anytime, bound):
    """The tube chain and the chains of boxes of a step with a budget (the anytime pack's deadline).

    A walk from the last certain step's cover first (within :data:`WALK_SHARE` of the time left: it
    usually ends in a few tests); when it does not end, the chains of boxes (:func:`chains`, the
    choice; within :data:`CHAIN_SHARE` of the time left), then the walk on (a walk the last steps
    left goes on after the chains).  Returns (the tube chain's solution or -1, its tubes, then as
    :func:`chains`; their candidates in ``new_cands``, ``keep``; the solution's pose bound in ``bound``)."""
    deadline = anytime[ANY_DEADLINE]
    sol, n_tubes = -1, 0
    n_new, cert, intact, linked = 0, CERT_NONE, False, False
    fresh = anytime[ANY_N] <= 0.0
    if fresh and not untrusted:
        sol, n_tubes = walk_step(state, work, poses, real, tol_of(params), model_pack, tubes, anytime, True,
                                 share(deadline, WALK_SHARE), bound)
        if sol >= 0:
            return sol, n_tubes, n_new, cert, intact, linked
    measured = is_measured(params, model_pack)
    chain_share = PENDING_CHAIN_SHARE if measured and anytime[ANY_N] > 0.0 else CHAIN_SHARE
    n_new, cert, intact, linked = anytime_chains(untrusted, state, work, poses, real, params, model_pack, new_cands,
                                                 keep, anytime, True, share(deadline, chain_share))
    if not untrusted and (anytime[ANY_N] > 0.0 or not fresh):
        sol, n_tubes = walk_step(state, work, poses, real, tol_of(params), model_pack, tubes, anytime, not fresh,
                                 share(deadline, 1.0 - REGION_SHARE) if measured else deadline, bound)
    if sol < 0 and anytime[ANY_K_ON] > 0.0 and not expired(deadline):     # the continuation on, with the rest
        n_new, cert, intact, linked = anytime_chains(untrusted, state, work, poses, real, params, model_pack,
                                                     new_cands, keep, anytime, False, deadline)
    return sol, n_tubes, n_new, cert, intact, linked


@njit(cache=False)
def anytime_chains(untrusted, state, work, poses, real, params, model_pack, new_cands, keep, anytime, append,
                   deadline):
    """The chains of boxes of a step with a budget: the continuation from a single candidate is resumable
    (:func:`.anytime.cont_on`: one the deadline cuts goes on at the next steps, along their readings);
    while it is under way the step keeps every real solution as a candidate; when it ends on one
    solution, that is the step's (as :func:`.candidates.certify`'s continuation, intact if the
    state's chain was where it began).  Otherwise, and when it fails, :func:`chains`.  ``append``:
    this step's reading is not on the continuation's path yet (the first call of a step)."""
    if untrusted:
        anytime[ANY_K_ON] = 0.0
    elif append and anytime[ANY_K_ON] <= 0.0 and int(state[STATE_N_CAND]) == 1:
        cont_begin(anytime, state[STATE_CANDS:STATE_CANDS + 3], state[STATE_VERIFIED] > 0.0,
                   state[STATE_INTACT] > 0.0, state[STATE_Q:STATE_Q + 3])
    d2 = floats(3)
    d2[:] = 0.0
    if anytime[ANY_K_ON] > 0.0 and (not append or cont_append(anytime, work[STEP_QU:STEP_QU + 3], d2,
                                                                parabola(state, work, d2))):
        M, l1, l2sq, b = geometry(model_pack)
        end, Xr = floats(3), floats(3)
        status = cont_on(anytime, int(params[PARAM_MAX_TESTS]), deadline, M, l1, b, l2sq, end)
        if status == FOLLOW_CUT:
            n = 0
            for k in range(6):
                keep[k] = real[k]
                if real[k]:
                    new_cands[n, :] = poses[k].real
                    n += 1
            return n, CERT_NONE, False, False
        if status == FOLLOW_DONE:
            hit = -1
            for k in range(6):
                if real[k]:
                    for i in range(3):
                        Xr[i] = poses[k, i].real
                    if same_pose(Xr, end):
                        hit = k if hit < 0 else 6          # 6: two solutions match (cannot tell)
            if 0 <= hit < 6:
                for k in range(6):
                    keep[k] = k == hit
                new_cands[0, :] = end
                return 1, CERT_CONTINUATION, anytime[ANY_K_INTACT] > 0.0, True
    return chains(state, work, poses, real, params, model_pack, new_cands, keep, deadline)


@njit(cache=False)
def tol_of(params):
    return params[PARAM_JOINT_TOL]


@njit(cache=False)
def is_measured(params, model_pack):
    """Whether the robot's pose may lie off the model's DK solutions of the readings: joints read within a
    tolerance, or a robot as built (its legs' offsets): the chains along the readings then only steer the
    choice, and certainty comes from the tube chain and re-acquisition, which bound both."""
    return tol_of(params) > 0.0 or as_built(geometry(model_pack)[2])


@njit(cache=False)
def tube_step(state, work, poses, real, tol, model_pack, tubes, bound):
    """The tube chain (:func:`.tube_chain.tube_chain`) over this step's joints from the last step's cover
    (state pack), into ``tubes`` (MAX_COVER, TUBE_SIZE).  Returns (the index of the real DK solution
    that is the cover's solution at the measured joints, or -1 when the chain did not close; the
    number of tubes of the new cover); that solution's pose bound (:func:`.tube_chain.pose_bound`) into
    ``bound`` (3,)."""
    M, l1, l2sq, b = geometry(model_pack)
    n_old = int(state[STATE_N_TUBES])
    old = state[STATE_TUBE:STATE_TUBE + MAX_COVER * TUBE_SIZE].reshape((MAX_COVER, TUBE_SIZE))
    tests, n = tube_chain(old, n_old, state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3], tol, TUBE_TESTS,
                          M, l1, l2sq, b, tubes)
    if tests <= 0:
        return -1, 0
    return cover_solution(tubes, n, work[STEP_QU:STEP_QU + 3], tol, poses, real, bound), n


@njit(cache=False)
def walk_step(state, work, poses, real, tol, model_pack, tubes, anytime, append, deadline, bound):
    """The tube chain as a walk (a step budget, :mod:`.anytime`): the walk the last steps left, or a new
    one from the last step's cover (state pack), with this step's reading appended (``append``),
    walked on until the ``deadline``.  Returns as :func:`tube_step` (-1 also while the walk is
    pending)."""
    M, l1, l2sq, b = geometry(model_pack)
    qu = work[STEP_QU:STEP_QU + 3]
    if append and anytime[ANY_N] <= 0.0:
        n_old = int(state[STATE_N_TUBES])
        if n_old <= 0:
            return -1, 0
        old = state[STATE_TUBE:STATE_TUBE + MAX_COVER * TUBE_SIZE].reshape((MAX_COVER, TUBE_SIZE))
        walk_begin(anytime, old, n_old, state[STATE_Q:STATE_Q + 3])
    if anytime[ANY_N] <= 0.0 or (append and not walk_append(anytime, qu)):
        anytime[ANY_N] = 0.0
        return -1, 0
    status, n = walk_on(anytime, tol, TUBE_TESTS, deadline, M, l1, l2sq, b, tubes)
    if status != WALK_CLOSED:
        return -1, 0
    return cover_solution(tubes, n, qu, tol, poses, real, bound), n


@njit(cache=False)
def parabola(state, work, d2):
    """The quadratic term ``d2`` (3,, rad) of the parabola ``qp + s (dq - d2) + s^2 d2`` through the
    reading before the last (at ``s = -r``, r = previous / this time step), the last (``s = 0``) and
    this one (``s = 1``); False (``d2`` zero) before there are three."""
    if not state[STATE_HAVE_Q2] > 0.0:
        for i in range(3):
            d2[i] = 0.0
        return False
    qp, dq = state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3]
    r = 1.0 / state[STATE_EXT_SCALE]
    for i in range(3):
        d2[i] = (wrap(state[STATE_Q2 + i] - qp[i]) + r * dq[i]) / (r * (1.0 + r))
    return True


@njit(cache=False)
def chains(state, work, poses, real, params, model_pack, new_cands, keep, deadline=0.0):
    """:func:`.candidates.certify` on the previous candidates (state pack) over the joint step and,
    with three samples, the parabola through them (time-scaled).  Writes ``new_cands`` (6, 3) and
    ``keep`` (6,); returns (candidates, certificate code, chain intact since the reset, linked)."""
    qp, dq = state[STATE_Q:STATE_Q + 3], work[STEP_DQ:STEP_DQ + 3]
    d2 = floats(3)
    d2[:] = 0.0
    have_par = parabola(state, work, d2)
    intact_before = state[STATE_INTACT] > 0.0
    n_new, cert, intact, linked = certify(state[STATE_CANDS:STATE_CANDS + 18].reshape((6, 3)),
                                          int(state[STATE_N_CAND]), state[STATE_VERIFIED] > 0.0, intact_before, qp,
                                          dq, d2, have_par, 0.0, poses, real,
                                          int(params[PARAM_POSTURE_BITS]), int(params[PARAM_MAX_TESTS]), model_pack,
                                          new_cands, keep, deadline)
    return n_new, cert, intact and intact_before, linked


@njit(cache=False)
def paving_cut(state, qu, params, model_pack, Xc, bound, out_real, deadline):
    """A step the eliminant re-acquired: its box about ``Xc`` (3,), half-widths ``bound`` (3,), cut to the
    hull of the set-membership paving of this reading (:func:`.paving.region_step`), which holds the
    robot too and follows the needle more closely.  ``bound`` narrowed in place; the paving stays in the
    result pack (OUT_REGION, OUT_PAVE): the next step's region grows from it, not from the box."""
    hull = out_real[OUT_REGION:OUT_REGION + 6]
    region_step(state, qu, params, model_pack, hull, out_real[OUT_N_PAVE:OUT_N_PAVE + 1 + 6 * PAVE_BOXES], deadline)
    if hull[0] <= hull[1] and hull[2] <= hull[3] and hull[4] <= hull[5]:
        shift = turns_to(0.5 * (hull[4] + hull[5]), Xc[2])
        b = floats(3)
        ok = True
        for r in range(3):
            s = shift if r == 2 else 0.0
            lo, hi = max(Xc[r] - bound[r], hull[2 * r] + s), min(Xc[r] + bound[r], hull[2 * r + 1] + s)
            if r == 2 and not hull[5] - hull[4] + 2.0 * bound[2] < np.pi:
                lo, hi = Xc[2] - bound[2], Xc[2] + bound[2]      # another turn's copy of the hull could be the robot's
            b[r] = max(abs(Xc[r] - lo), abs(hi - Xc[r]))
            ok = ok and lo <= hi
        if ok:
            for r in range(3):
                bound[r] = min(bound[r], b[r])
