"""Re-acquisition: certainty back from one reading of measured joints, at once or anytime.

With measured joints (``joint_tolerance > 0``) a tracker that lost its chain of certificates
regains certainty from one reading ``q`` alone: the solution it re-acquires is the robot's when,
for the pose box known to hold the robot (the region: :func:`.gates.reacquire_region`), a cover
of the joint box ``q +- tol`` by tubes holds one solution per joint vector and every pose of the
region in the tracker's posture reaching a tube's joints lies in that tube's fat box
(:func:`.exclusion.tube_exclusion`, the covers of :data:`REACQUIRE_COVERS`), or else an
axis-aligned Krawczyk box does (:func:`.exclusion.reacquire`), or else the eliminant shows that one
solution in the tracker's posture has its phi in the region's range (a whole turn without a bound
on phi) for every joint vector of the box (:func:`eliminant_reacquired`, :mod:`.eliminant`).

:func:`reacquired` runs that proof within one step.  With a step budget it is resumable
(:func:`reacquired_anytime`): the proof for the reading it began at keeps its place (attempt,
tube, hull factor, the branch and bound's stack) in the anytime pack (:mod:`.anytime`) and goes on
at the next steps, which append their readings.  Given the time it is the same proof, box for
box.  When it closes on an earlier reading, a walk from that reading's cover (:func:`.anytime.walk_on`)
catches up with the readings since; the step whose walk reaches its own reading is certain, never
an earlier one.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .anytime import (ANY_R_F, ANY_R_HULL, ANY_R_K, ANY_R_N, ANY_R_N_PATH, ANY_R_ON, ANY_R_PATH,
                      ANY_R_PROG, ANY_R_REGION, ANY_R_RETRY, ANY_R_STACK, ANY_R_TUBES, ANY_R_X, MAX_PATH,
                      WALK_CLOSED, path_append, walk_append, walk_begin, walk_on)
from .certify import elbow_bits
from .clock import expired
from .direct_kinematics import EPS
from .eliminant import eliminant_certificate
from .exclusion import (HULL_FACTORS, PREIMAGE_STACK, exclusion_cover, fat_hull, in_region, preimage_on,
                        reacquire, reacquire_box, tube_exclusion)
from .gates import reacquire_region
from .kinematics import geometry
from .krawczyk import PAD, TWO_PI
from .layout import PARAM_JOINT_TOL, PARAM_POSTURE_BITS, PARAM_REACQUIRE
from .linalg import turns_to, wrap
from .scratch import floats, scratch
from .tracker_packs import STEP_QU
from .tube import TUBE_K, TUBE_Q, TUBE_SIZE, TUBE_T, TUBE_X, predictor, spread, tube_test
from .tube_chain import MAX_COVER, pose_bound

#: Re-acquisition by tubes tries the first covers of :data:`.exclusion.EXCLUSION_COVERS`: the reading's
#: joint box whole, in 3 and 8 slabs across the needle, in 2**3 parts.
REACQUIRE_COVERS = 4
#: Anytime: a cover the deadline cuts is made again at the next step, at most this many times.
MAX_RETRIES = 3
#: What :func:`reacquire_on` ends with.
R_FAILED, R_DONE, R_PENDING = 0, 1, 2


@njit(cache=False)
def reacquire_target(chosen, certified, keep, poses, real, params, state, qu, model_pack, Xc, region):
    """The solution to re-acquire: the one real solution (``poses`` (6, 3) complex, ``real`` (6,); or the
    one the certificates kept, ``certified``, ``keep`` (6,), else ``chosen``) inside the region that
    holds the robot in the tracker's posture, if there is exactly one.  Its pose into ``Xc`` (3,) and
    the region (6,) into ``region``.  Returns its index, or -1: the region is empty, no solution
    qualifies, or two do (near a fold, where two assembly modes of the posture meet: no proof can
    single one out there, and the search that would fail is not begun)."""
    reacquire_region(params, state, region)
    target = chosen
    if certified:                                  # the branch along the measured joints
        for k in range(6):
            if keep[k]:
                target = k
    if not (region[0] <= region[1] and region[2] <= region[3]):
        return -1
    M, l1, l2sq, b = geometry(model_pack)
    posture = int(params[PARAM_POSTURE_BITS])
    found = -1                                     # the one solution the region leaves in the posture, if one:
    for k in range(6):                             # with two, no proof can single one out (each would have to
        if not (real[k] or k == target):           # be alone in its tube or in the eliminant's phi range), so
            continue                               # the re-acquisition that would fail is not begun
        for i in range(3):
            Xc[i] = poses[k, i].real
        if elbow_bits(Xc, qu, M, l1, b) == posture and in_region(Xc, region):
            if found >= 0:
                return -1
            found = k
    if found >= 0:
        for i in range(3):
            Xc[i] = poses[found, i].real
    return found


@njit(cache=False)
def region_choice(chosen, poses, real, params, state, qu, model_pack):
    """The solution to take when nothing vouches (a choice, not a proof): ``chosen``, unless it lies
    outside the pose box that holds the robot (:func:`.gates.reacquire_region`) or in another
    posture; then the one real solution (``poses`` (6, 3) complex, ``real`` (6,)) inside it in the
    tracker's posture, if there is exactly one (:func:`reacquire_target`)."""
    Xc, region = floats(3), floats(6)
    keep = scratch(6, np.bool_)
    keep[:] = False
    target = reacquire_target(chosen, False, keep, poses, real, params, state, qu, model_pack, Xc, region)
    return chosen if target < 0 else target


@njit(cache=False)
def reacquired(chosen, certified, state, work, poses, real, params, model_pack, new_cands, keep, tubes,
               deadline=0.0):
    """Re-acquire the branch from this sample alone (the module docstring): the solution of
    :func:`reacquire_target`, over the region the robot can be in, by a cover of the reading's joint
    box (:func:`.exclusion.tube_exclusion`, the box whole, then in slabs or parts) or else an
    axis-aligned Krawczyk box whose tube's hull it holds (:func:`box_reacquire`).  On success
    ``keep`` (6,) marks the solution alone, ``new_cands[0]`` holds it and ``tubes`` (MAX_COVER,
    TUBE_SIZE) its cover; returns the number of the cover's tubes (0: not re-acquired)."""
    region, Xc = floats(6), floats(3)
    qu, tol = work[STEP_QU:STEP_QU + 3], params[PARAM_JOINT_TOL]
    target = reacquire_target(chosen, certified, keep, poses, real, params, state, qu, model_pack, Xc, region)
    if target < 0:
        return 0
    M, l1, l2sq, b = geometry(model_pack)
    posture = int(params[PARAM_POSTURE_BITS])
    n = 0
    for attempt in range(1, REACQUIRE_COVERS + 1):
        n = tube_exclusion(Xc, qu, tol, posture, posture + 1, region, int(params[PARAM_REACQUIRE]), attempt, M, l1,
                           l2sq, b, tubes, deadline)
        if n > 0 or expired(deadline):
            break
    if n == 0:
        if expired(deadline):
            return 0
        tq, zero = floats(3), floats(3)
        tq[:] = tol
        zero[:] = 0.0
        if not (tube_test(Xc, qu, tq, zero, M, l1, l2sq, b, tubes[0]) and
                box_reacquire(Xc, qu, tol, posture, region, int(params[PARAM_REACQUIRE]), model_pack, tubes[0],
                              deadline)):
            return 0
        n = 1
    for k in range(6):
        keep[k] = k == target
    new_cands[0, :] = Xc
    return n


@njit(cache=True)
def eliminant_reacquired(chosen, certified, state, work, poses, real, params, model_pack, new_cands, keep, bound,
                         deadline=0.0):
    """Re-acquire from this sample by the eliminant (:mod:`.eliminant`): the solution of
    :func:`reacquire_target` is the only one in the tracker's posture whose phi lies in the region's
    phi range (a whole turn when the region does not bound phi) for every joint vector of the
    reading's box (whole, else in 2**3 parts); a solution in another posture is ruled out by its
    box.  Where the tube covers fail on a long, curved needle this one-dimensional test still
    closes.  On success ``keep`` (6,) marks the solution alone, ``new_cands[0]`` holds it, ``bound``
    (3,) the half-widths (m, m, rad) of a box about it holding the robot's pose (the eliminant's box
    cut to the region); returns True."""
    region, Xc = floats(6), floats(3)
    qu, tol = work[STEP_QU:STEP_QU + 3], params[PARAM_JOINT_TOL]
    target = reacquire_target(chosen, certified, keep, poses, real, params, state, qu, model_pack, Xc, region)
    if target < 0:
        return False
    posture = int(params[PARAM_POSTURE_BITS])
    plo, phi = region[4], region[5]
    if not phi - plo < TWO_PI - 1e-9:             # no bound on phi: a whole turn, the posture rules out the rest
        plo, phi = Xc[2] - np.pi, Xc[2] + np.pi
    M, l1, l2sq, b = geometry(model_pack)
    box, part = floats(6), floats(6)
    ok = False
    for n in (1, 2):
        t = floats(3)                             # the parts' half-widths, padded for the rounding of their centres
        for j in range(3):
            t[j] = tol / n + 4.0 * EPS * (abs(qu[j]) + tol)
        qc = floats(3)
        ok = True
        for i in range(n ** 3):
            for j in range(3):
                qc[j] = qu[j] + tol * (-1.0 + (2.0 * ((i // n ** j) % n) + 1.0) / n)
            if not eliminant_certificate(Xc[2] if n == 1 else np.nan, qc, t, plo, phi, M, l1, l2sq, b, part,
                                         deadline, posture):
                ok = False
                break
            for r in range(3):
                box[2 * r] = part[2 * r] if i == 0 else min(box[2 * r], part[2 * r])
                box[2 * r + 1] = part[2 * r + 1] if i == 0 else max(box[2 * r + 1], part[2 * r + 1])
        if ok or expired(deadline):
            break
    if not ok:
        return False
    for r in range(2):                            # the robot is in the region too (its phi range is the box's)
        box[2 * r] = max(box[2 * r], region[2 * r])
        box[2 * r + 1] = min(box[2 * r + 1], region[2 * r + 1])
        if box[2 * r] > box[2 * r + 1]:
            return False                          # the proof and the region disagree: vouch for nothing
    p = Xc[2] + turns_to(Xc[2], 0.5 * (box[4] + box[5]))      # phi beside the box's
    X = (Xc[0], Xc[1], p)
    for r in range(3):
        bound[r] = max(X[r] - box[2 * r], box[2 * r + 1] - X[r])
        if not bound[r] >= 0.0:
            return False
    for k in range(6):
        keep[k] = k == target
    new_cands[0, :] = Xc
    return True


@njit(cache=False)
def box_reacquire(Xc, qu, tol, posture, region, max_boxes, model_pack, tube, deadline=0.0):
    """Re-acquisition by an axis-aligned Krawczyk box (:func:`.exclusion.reacquire`) about ``Xc``; the
    ``tube`` takes over when its hull lies inside that box."""
    box = floats(6)
    return reacquire(Xc, qu, tol, posture, region, max_boxes, model_pack, box, deadline) and hull_inside(tube, tol, box)


@njit(cache=False)
def hull_inside(tube, tol, box):
    """The tube's solutions over its centre joints ``+- tol`` lie in the box ``box`` (centre, half-widths)."""
    for r in range(3):
        hull = tube[TUBE_K + r] + PAD + spread(tube, r, tol)
        d = tube[TUBE_X + r] - box[r]
        if r == 2:
            d = wrap(d)
        if not abs(d) + hull * (1.0 + 1e-9) < box[3 + r]:
            return False
    return True


@njit(cache=True)
def reacquired_anytime(chosen, certified, state, work, poses, real, params, model_pack, new_cands, keep, tubes,
                       anytime, max_tests, deadline):
    """:func:`reacquired` with a step budget (the anytime pack's deadline): the re-acquisition under way
    goes on with this step's reading appended, or one begins at this reading; when it closes on an
    earlier reading, a walk from that reading's cover (at most ``max_tests`` tube tests a segment)
    catches up with this one; all until the ``deadline``.  Returns as :func:`reacquired` (0 also while
    the proof or its walk is under way: the pack holds them)."""
    qu, tol = work[STEP_QU:STEP_QU + 3], params[PARAM_JOINT_TOL]
    if anytime[ANY_R_ON] > 0.0 and not r_append(anytime, qu):
        anytime[ANY_R_ON] = 0.0
    target = -1
    if anytime[ANY_R_ON] <= 0.0:
        Xc, region = floats(3), floats(6)
        target = reacquire_target(chosen, certified, keep, poses, real, params, state, qu, model_pack, Xc, region)
        if target < 0:
            return 0
        reacquire_begin(anytime, Xc, qu, region)
    status, n = reacquire_on(anytime, tol, int(params[PARAM_POSTURE_BITS]), int(params[PARAM_REACQUIRE]), deadline,
                             model_pack)
    if status != R_DONE:
        return 0
    cover = anytime[ANY_R_TUBES:ANY_R_TUBES + MAX_COVER * TUBE_SIZE].reshape((MAX_COVER, TUBE_SIZE))
    if target < 0:                                 # closed on an earlier reading: the walk from there
        walk_begin(anytime, cover, n, anytime[ANY_R_PATH:ANY_R_PATH + 3].copy())
        for j in range(1, int(anytime[ANY_R_N_PATH])):
            walk_append(anytime, anytime[ANY_R_PATH + 3 * j:ANY_R_PATH + 3 * j + 3].copy())
        M, l1, l2sq, b = geometry(model_pack)
        status, n = walk_on(anytime, tol, max_tests, deadline, M, l1, l2sq, b, tubes)
        if status != WALK_CLOSED:
            return 0
        target = cover_solution(tubes, n, qu, tol, poses, real)
        if target < 0:
            return 0
    else:
        for j in range(n):
            tubes[j, :] = cover[j]
    for k in range(6):
        keep[k] = k == target
    for i in range(3):
        new_cands[0, i] = poses[target, i].real
    return n


@njit(cache=False)
def sorts_before(a, b):
    """``a`` comes before ``b`` in an ascending sort with NaN last (numba's and numpy's order)."""
    return a < b or (b != b and a == a)


@njit(cache=False)
def cover_solution(tubes, n, qu, tol, poses, real, bound=None):
    """The index of the real DK solution (``poses`` (6, 3) complex, ``real`` (6,)) that is the solution
    of the cover ``tubes[:n]`` at the reading ``qu`` (3,), or -1; its :func:`.tube_chain.pose_bound`
    into ``bound`` (3,) when given (untouched when -1).

    The solutions are tried nearest first to the first tube's predictor at ``qu`` (the cover holds one
    solution, so the order changes no answer; it saves the other solutions' bounds, each as dear as
    the one kept)."""
    Xr, h, p = floats(3), floats(3), floats(3)
    predictor(tubes[0], qu, p)
    dist = floats(6)
    dist[:] = np.inf
    for k in range(6):
        if real[k]:
            dist[k] = abs(poses[k, 0].real - p[0]) + abs(poses[k, 1].real - p[1]) + abs(wrap(poses[k, 2].real - p[2]))
    order = scratch(6, np.int64)                  # by distance (a stable sort, NaN last: numba's argsort of six)
    for k in range(6):
        j = k
        while j > 0 and sorts_before(dist[k], dist[order[j - 1]]):
            order[j] = order[j - 1]
            j -= 1
        order[j] = k
    for k in order:
        if not real[k]:
            break
        for i in range(3):
            Xr[i] = poses[k, i].real
        if pose_bound(tubes, n, qu, tol, Xr, h):
            if bound is not None:
                bound[:] = h
            return k
    return -1


@njit(cache=True)
def reacquire_begin(anytime, Xc, qu, region):
    """A re-acquisition of the solution ``Xc`` (3,) of the reading ``qu`` (3,, rad) over the pose box
    ``region`` (6,) into the anytime pack."""
    anytime[ANY_R_ON], anytime[ANY_R_N], anytime[ANY_R_K], anytime[ANY_R_F] = 1.0, 0.0, 0.0, 0.0
    anytime[ANY_R_PROG], anytime[ANY_R_PROG + 1], anytime[ANY_R_RETRY] = 0.0, 0.0, 0.0
    anytime[ANY_R_X:ANY_R_X + 3] = Xc
    anytime[ANY_R_REGION:ANY_R_REGION + 6] = region
    anytime[ANY_R_N_PATH] = 1.0
    anytime[ANY_R_PATH:ANY_R_PATH + 3] = qu


@njit(cache=True)
def r_append(anytime, q):
    """Add the reading ``q`` (3,) at the re-acquisition's path end (unwrapped next to the last); False when full."""
    return path_append(anytime, ANY_R_N_PATH, ANY_R_PATH, MAX_PATH, q)


@njit(cache=True)
def reacquire_on(anytime, tol, posture, max_boxes, deadline, model_pack):
    """Go on with the re-acquisition in the anytime pack until it ends or the ``deadline`` passes:
    :func:`reacquired`'s attempts, in its order, on the reading it began at.  Returns (R_DONE, n:
    the pack's cover ``ANY_R_TUBES[:n]`` proves the solution ``ANY_R_X`` the robot's at that reading;
    the re-acquisition is over), (R_PENDING, 0: the pack holds where it stands) or (R_FAILED, 0:
    over)."""
    if expired(deadline):
        return R_PENDING, 0
    M, l1, l2sq, b = geometry(model_pack)
    Xc, qu, region = floats(3), floats(3), floats(6)      # (copies: the pack moves on below)
    Xc[:] = anytime[ANY_R_X:ANY_R_X + 3]
    qu[:] = anytime[ANY_R_PATH:ANY_R_PATH + 3]
    region[:] = anytime[ANY_R_REGION:ANY_R_REGION + 6]
    tubes = anytime[ANY_R_TUBES:ANY_R_TUBES + MAX_COVER * TUBE_SIZE].reshape((MAX_COVER, TUBE_SIZE))
    stack = anytime[ANY_R_STACK:ANY_R_STACK + 6 * PREIMAGE_STACK].reshape((PREIMAGE_STACK, 6))
    prog = anytime[ANY_R_PROG:ANY_R_PROG + 2]
    zero, tq = floats(3), floats(3)
    zero[:] = 0.0
    tq[:] = tol
    while int(anytime[ANY_R_ON]) <= REACQUIRE_COVERS:
        attempt = int(anytime[ANY_R_ON])
        n = int(anytime[ANY_R_N])
        if n == 0:
            point = floats(TUBE_SIZE)
            if not tube_test(Xc, qu, zero, zero, M, l1, l2sq, b, point):
                next_attempt(anytime, REACQUIRE_COVERS + 1)     # no cover about Xc: the Krawczyk box
                continue
            n = exclusion_cover(tubes, point, qu, tq, attempt, M, l1, l2sq, b, deadline)
            if n <= 0:
                if expired(deadline) and anytime[ANY_R_RETRY] < MAX_RETRIES:
                    anytime[ANY_R_RETRY] += 1.0
                    return R_PENDING, 0
                next_attempt(anytime, attempt + 1)
                continue
            anytime[ANY_R_N] = n
        failed = False
        while int(anytime[ANY_R_K]) < n:
            r = tube_excluded(tubes[int(anytime[ANY_R_K])], posture, region, max_boxes, deadline, anytime, stack, prog,
                              M, l1, l2sq, b)
            if r == 0:
                return R_PENDING, 0
            if r < 0:
                failed = True
                break
            anytime[ANY_R_K] += 1.0
        if not failed:
            anytime[ANY_R_ON] = 0.0
            return R_DONE, n
        next_attempt(anytime, attempt + 1)
    box = floats(6)                                     # the Krawczyk box, its tube's hull inside it
    if not (tube_test(Xc, qu, tq, zero, M, l1, l2sq, b, tubes[0])
            and reacquire_box(Xc, qu, tol, posture, region, model_pack, box) and hull_inside(tubes[0], tol, box)):
        anytime[ANY_R_ON] = 0.0
        return R_FAILED, 0
    if prog[0] == 0.0 and prog[1] == 0.0:
        stack[0, :] = region
        prog[0] = 1.0
    r = preimage_on(box[:3].copy(), box[3:].copy(), qu, tol, posture, M, l1, l2sq, b, max_boxes, deadline, stack, prog)
    if r == 0:
        return R_PENDING, 0
    anytime[ANY_R_ON] = 0.0
    return (R_DONE, 1) if r > 0 else (R_FAILED, 0)


@njit(cache=False)
def next_attempt(anytime, attempt):
    """The re-acquisition goes on with ``attempt``, from its start."""
    anytime[ANY_R_ON], anytime[ANY_R_N], anytime[ANY_R_K], anytime[ANY_R_F] = attempt, 0.0, 0.0, 0.0
    anytime[ANY_R_PROG], anytime[ANY_R_PROG + 1], anytime[ANY_R_RETRY] = 0.0, 0.0, 0.0


@njit(cache=True)
def tube_excluded(sub, posture, region, max_boxes, deadline, anytime, stack, prog, M, l1, l2sq, b):
    """:func:`.exclusion.hull_excludes` for the tube ``sub`` in the tracker's posture, resumable: the hull
    factor under way and the branch and bound's place are in the anytime pack.  Returns 1 (proved),
    -1 (not) or 0 (cut by the ``deadline``)."""
    q, xc = sub[TUBE_Q:TUBE_Q + 3].copy(), sub[TUBE_X:TUBE_X + 3].copy()
    eps = max(sub[TUBE_T], max(sub[TUBE_T + 1], sub[TUBE_T + 2]))
    hull = anytime[ANY_R_HULL:ANY_R_HULL + 3]
    while int(anytime[ANY_R_F]) < len(HULL_FACTORS):
        if prog[0] == 0.0 and prog[1] == 0.0:           # not begun at this factor: its fat tube first
            if not fat_hull(sub, HULL_FACTORS[int(anytime[ANY_R_F])], M, l1, l2sq, b, hull):
                anytime[ANY_R_F] += 1.0
                continue
            stack[0, :] = region
            prog[0] = 1.0
        r = preimage_on(xc, hull.copy(), q, eps, posture, M, l1, l2sq, b, max_boxes, deadline, stack, prog)
        if r == 0:
            return 0
        prog[0], prog[1], anytime[ANY_R_F] = 0.0, 0.0, 0.0
        return r
    anytime[ANY_R_F] = 0.0
    return -1
