"""The step budget and anytime tube chains: a proof that stops at a deadline and goes on at the next step.

A tracker with a step budget (``Tracker(step_budget=...)``) gives each step a *deadline* (a cycle
count, :mod:`.clock`); every search of the certify phase (the tube chain, the chains of Krawczyk
boxes, re-acquisition, the set-membership branch and bound, the speed gate's chain back) stops
when it passes, and the step returns its choice, not certain.

The tube chain does not throw its work away.  Its state is a *walk*: the tubes laid so far along
the joint path, where the walk stands on that path (segment, ``s``, the step length, the tests
used), and the path itself, the readings still to reach.  The next step appends its reading and
walks on from there within its own deadline; when the walk covers the last reading's own box, the
step that got there is certain (its proof was complete when it returned: never back-dated).  The
walk is the same computation as :func:`.tube_chain.tube_chain` cut into parts: the tubes of a
segment are checked against every earlier tube of that segment, and at each reading the walk
keeps only that reading's cover, as a certain step does.  A segment that needs more than
``max_tests`` tube tests, or a path longer than :data:`MAX_PATH` readings, ends the walk
(certainty then comes back by re-acquisition, as without a budget).

Re-acquisition (:mod:`.reacquisition`) does not throw its work away either: it goes on from the
reading it began at, with its place in the covers and in the branch and bound, and a walk from
its cover then catches up with the readings since.

The *anytime pack* (:data:`ANY_SIZE` floats) carries the step's deadline in, whether the deadline
cut the step out, and the walk, the continuation and the re-acquisition in and out (read and
rewritten in place by :func:`walk_on`, :func:`cont_on` and :func:`.reacquisition.reacquire_on`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .certify import FOLLOW_DONE, FOLLOW_FAILED, follow_on, tiny_box
from .clock import expired
from .exclusion import PREIMAGE_STACK
from .linalg import wrap
from .scratch import floats
from .tube import TUBE_Q, TUBE_SIZE
from .tube import TUBE_S
from .tube_chain import (COVER_ALL, COVER_ONE, COVER_PARTS, COVER_SLABS, MAX_COVER, MAX_PIECES, SLABS, cover_box,
                         cover_stages, needle_frame, refine, slab_cover)

#: Most readings a walk's path may hold (its start and the readings it has not reached).
MAX_PATH = 256
#: ... and a continuation's.
MAX_KPATH = 64

# the anytime pack
ANY_DEADLINE = 0          # the step's deadline (cycle count, :mod:`.clock`; 0: no budget)
ANY_CUT = 1               # out: 1 when the deadline passed before the step's searches ended
ANY_N = 2                 # the walk's tubes (0: no walk)
ANY_LAST = 3              # where the last piece's cover starts among them
ANY_S = 4                 # how far along the path's first segment the walk stands (0..1)
ANY_STEP = 5              # the next piece's length (fraction of the segment)
ANY_TESTS = 6             # tube tests used on this segment
ANY_N_PATH = 7            # the path's readings (its first: the segment's start)
ANY_C_STAGE = 8           # the cover in progress (:func:`walk_cover`): its stage (0: none or one tube)
ANY_C_K = 9               # ... the next tube of that stage (its tubes so far follow the walk's)
ANY_C_V = 10              # (3, 3) ... the needle's frame of its slabs
ANY_K_ON = 19             # > 0: a continuation (chain of Krawczyk boxes) is under way (:func:`cont_on`)
ANY_K_INTACT = 20         # ... the state's chain was intact where it began
ANY_K_X = 21              # (3,) ... the branch where it stands
ANY_K_PROG = 24           # (3,) ... s on its first segment, the next piece's length, the tests (-1: first the tiny box)
ANY_K_N_PATH = 27         # ... its readings (the first: the segment's start)
ANY_K_PATH = 28           # (MAX_KPATH, 3) ... its path, rad, unwrapped along it
ANY_K_D2 = ANY_K_PATH + 3 * MAX_KPATH  # (MAX_KPATH, 3) ... the parabola's quadratic term to each reading (rad)
ANY_K_PAR = ANY_K_D2 + 3 * MAX_KPATH   # (MAX_KPATH,) ... 1 where that parabola exists (three readings)
ANY_K_X0 = ANY_K_PAR + MAX_KPATH       # (3,) ... the branch at its first segment's start
ANY_K_KIND = ANY_K_X0 + 3              # ... the first segment followed straight (1) or along the parabola (2)
ANY_PATH = ANY_K_KIND + 1  # (MAX_PATH, 3) the walk's path, rad, unwrapped along it
ANY_R = ANY_PATH + 3 * MAX_PATH  # a re-acquisition under way (:mod:`.reacquisition`):
ANY_R_ON = ANY_R          # > 0: its attempt (1.. the covers of REACQUIRE_COVERS, then the Krawczyk box); 0: none
ANY_R_N = ANY_R + 1       # ... the attempt's cover's tubes (0: not made yet)
ANY_R_K = ANY_R + 2       # ... the tube whose exclusion is under way
ANY_R_F = ANY_R + 3       # ... its hull factor (an index into .exclusion.HULL_FACTORS)
ANY_R_PROG = ANY_R + 4    # (2,) ... the branch and bound's stack top (0: not begun) and boxes examined
ANY_R_RETRY = ANY_R + 6   # ... how often the deadline cut this attempt's cover
ANY_R_X = ANY_R + 7       # (3,) ... the solution it re-acquires, at the path's first reading
ANY_R_REGION = ANY_R + 10  # (6,) ... the pose box known to hold the robot at that reading
ANY_R_N_PATH = ANY_R + 16  # ... its readings (the first: the one re-acquired from)
ANY_R_HULL = ANY_R + 17   # (3,) ... the fat box's half-widths about the tube under way (m, m, rad)
ANY_R_PATH = ANY_R + 20   # (MAX_PATH, 3) ... its path, rad, unwrapped along it
ANY_R_STACK = ANY_R_PATH + 3 * MAX_PATH  # (PREIMAGE_STACK, 6) ... the branch and bound's pose boxes
ANY_R_TUBES = ANY_R_STACK + 6 * PREIMAGE_STACK  # (MAX_COVER, TUBE_SIZE) ... the attempt's cover
ANY_PIECES = ANY_R_TUBES + MAX_COVER * TUBE_SIZE   # (MAX_PIECES, TUBE_SIZE) the walk's tubes
ANY_SIZE = ANY_PIECES + MAX_PIECES * TUBE_SIZE

#: What :func:`walk_on` ends with.
WALK_FAILED, WALK_CLOSED, WALK_PENDING = 0, 1, 2


@njit(cache=True)
def walk_floats(anytime: np.ndarray) -> int:
    """How many leading floats of the anytime pack ``anytime`` hold its walk, continuation and
    re-acquisition (0 when it has none)."""
    n = int(anytime[ANY_N])
    if n <= 0 and not anytime[ANY_K_ON] > 0.0 and not anytime[ANY_R_ON] > 0.0:
        return 0
    return ANY_PIECES + (n + int(anytime[ANY_C_K])) * TUBE_SIZE if n > 0 else ANY_PIECES


@njit(cache=True)
def walk_begin(anytime, old, n_old, qp):
    """A new walk from the cover ``old[:n_old]`` (n, TUBE_SIZE) of the reading ``qp`` (3,) (rad)."""
    pieces = anytime[ANY_PIECES:].reshape((MAX_PIECES, TUBE_SIZE))
    for j in range(n_old):
        pieces[j, :] = old[j]
        for i in range(3):                             # the tubes' joints next to qp
            pieces[j, TUBE_Q + i] = qp[i] + wrap(old[j, TUBE_Q + i] - qp[i])
    anytime[ANY_N], anytime[ANY_LAST], anytime[ANY_S], anytime[ANY_STEP] = n_old, 0.0, 0.0, 1.0
    anytime[ANY_TESTS], anytime[ANY_N_PATH] = 0.0, 1.0
    anytime[ANY_C_STAGE], anytime[ANY_C_K] = 0.0, 0.0
    anytime[ANY_PATH:ANY_PATH + 3] = qp


@njit(cache=True)
def walk_append(anytime, q):
    """Add the reading ``q`` (3,) at the path's end (unwrapped next to the last); False when full."""
    return path_append(anytime, ANY_N_PATH, ANY_PATH, MAX_PATH, q)


@njit(cache=False)
def path_append(anytime, n_at, path_at, most, q):
    """Add the reading ``q`` (3,) at the end of the path of the anytime pack whose count is at ``n_at``
    and readings (most, 3) at ``path_at``, unwrapped next to the last; False when it holds ``most``."""
    k = int(anytime[n_at])
    if k >= most:
        return False
    for i in range(3):
        prev = anytime[path_at + 3 * (k - 1) + i]
        anytime[path_at + 3 * k + i] = prev + wrap(q[i] - prev)
    anytime[n_at] = k + 1
    return True


@njit(cache=True)
def walk_on(anytime, tol, max_tests, deadline, M, l1, l2sq, b, out):
    """Walk on along the path until the last reading's box is covered, the ``deadline`` passes or the
    walk fails.

    Each segment as :func:`.tube_chain.tube_chain` (pieces of the segment widened by ``tol``, rad,
    each covered as :func:`.tube_chain.cover` does, then the reading's own box), but a cover the
    deadline cuts goes on at the next call from the tube where it stopped (:func:`walk_cover`); at
    an intermediate reading the walk goes on from that reading's cover alone.  Returns
    (WALK_CLOSED, n): ``out[:n]`` (MAX_COVER, TUBE_SIZE) covers the last reading's box and the
    walk is over; (WALK_PENDING, 0): the deadline passed, the pack holds where the walk stands;
    (WALK_FAILED, 0): a segment used ``max_tests`` tests, its pieces got too short or its cover
    too wide (the walk is over).
    """
    pieces = anytime[ANY_PIECES:].reshape((MAX_PIECES, TUBE_SIZE))
    n, last = int(anytime[ANY_N]), int(anytime[ANY_LAST])
    s, step, tests = anytime[ANY_S], anytime[ANY_STEP], int(anytime[ANY_TESTS])
    qc, t, dq, half = floats(3), floats(3), floats(3), floats(3)
    while int(anytime[ANY_N_PATH]) >= 2:
        qp = anytime[ANY_PATH:ANY_PATH + 3]
        for i in range(3):
            dq[i] = anytime[ANY_PATH + 3 + i] - qp[i]
        while s < 1.0:
            if (tests >= max_tests or step < 1.0 / 256.0) and anytime[ANY_C_K] == 0.0:
                anytime[ANY_N] = 0.0
                return WALK_FAILED, 0
            if expired(deadline):
                break
            sb = min(1.0, s + step)
            for i in range(3):
                qc[i] = qp[i] + 0.5 * (s + sb) * dq[i]
                half[i] = 0.5 * abs(dq[i]) * (sb - s)
                t[i] = half[i] + tol
            m, used = walk_cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b, deadline, anytime,
                                 cover_stages(half, tol))
            tests += used
            if m > 0:
                last, n = n, m
                s = sb
                step = min(1.25 * step, 1.0)
            elif m == -1:
                step *= 0.5
            else:                                      # the deadline cut the cover: it goes on next time
                break
        if s < 1.0:
            anytime[ANY_N], anytime[ANY_LAST], anytime[ANY_S], anytime[ANY_STEP] = n, last, s, step
            anytime[ANY_TESTS] = tests
            return WALK_PENDING, 0
        for i in range(3):                             # the reading's own box (else the last piece's cover)
            qc[i] = qp[i] + dq[i]
            t[i] = tol
        m, used = walk_cover(pieces, n, pieces[n - 1], qc, t, M, l1, l2sq, b, deadline, anytime,
                             COVER_ALL if tol <= 0.0 else COVER_SLABS)
        tests += used
        if m < -1:                                     # cut: the reading's cover goes on next time
            anytime[ANY_N], anytime[ANY_LAST], anytime[ANY_S], anytime[ANY_STEP] = n, last, s, step
            anytime[ANY_TESTS] = tests
            return WALK_PENDING, 0
        if m > 0:
            last, n = n, m
        if n - last > MAX_COVER:
            anytime[ANY_N] = 0.0
            return WALK_FAILED, 0
        k = int(anytime[ANY_N_PATH])
        for j in range(n - last):                      # the reading's cover alone, as a certain step keeps
            pieces[j, :] = pieces[last + j]
        n, last, s, step, tests = n - last, 0, 0.0, 1.0, 0
        for j in range(3 * (k - 1)):
            anytime[ANY_PATH + j] = anytime[ANY_PATH + 3 + j]
        anytime[ANY_N_PATH] = k - 1
    for j in range(n):
        out[j, :] = pieces[j]
    if n == 1 and not expired(deadline):
        refine(out, pieces, n, qc, t, M, l1, l2sq, b)
    anytime[ANY_N] = 0.0
    return WALK_CLOSED, n


#: The stages of a cover (:func:`walk_cover`): one tube, the slab counts of :data:`.tube_chain.SLABS`,
#: then 2**3 .. COVER_PARTS**3 parts (the order of :func:`.tube_chain.cover`).
N_STAGES = 1 + len(SLABS) + COVER_PARTS - 1


@njit(cache=True)
def walk_cover(pieces, n, guess, qc, t, M, l1, l2sq, b, deadline, anytime, stages=COVER_ALL):
    """:func:`.tube_chain.cover` of the joint box ``qc +- t`` (3,) (its ``stages``), resumable: a cover
    the ``deadline`` cuts keeps its stage, next tube and frame in the anytime pack (its tubes so far
    after ``pieces[:n]``) and goes on from there at the next call.  Returns (new count, -1 when every
    stage failed, -2 when cut; tube tests, counted per stage as :func:`.tube_chain.cover` does)."""
    stage, k0 = int(anytime[ANY_C_STAGE]), int(anytime[ANY_C_K])
    V = anytime[ANY_C_V:ANY_C_V + 9].reshape((3, 3))
    tests = 0
    while stage < N_STAGES:
        if stage == 0:
            count = 1
        elif stage <= len(SLABS):
            count = SLABS[stage - 1]
        else:
            count = (stage - len(SLABS) + 1) ** 3
        if k0 == 0:
            tests += count
        if stage == 0:
            r = cover_box(pieces, n, guess, qc, t, 1, M, l1, l2sq, b, deadline, k0)
        elif stage <= len(SLABS):
            if stage == 1 and k0 == 0:                 # the frame of the failed one-tube test's S
                if not (n < pieces.shape[0] and pieces[n, TUBE_S] == pieces[n, TUBE_S]):
                    stage, k0 = len(SLABS) + 1, 0
                    continue
                needle_frame(pieces[n, TUBE_S:TUBE_S + 9].reshape((3, 3)).copy(), V)
            r = slab_cover(pieces, n, guess, qc, t, count, V, M, l1, l2sq, b, deadline, k0)
        else:
            r = cover_box(pieces, n, guess, qc, t, stage - len(SLABS) + 1, M, l1, l2sq, b, deadline, k0)
        if r > 0:
            anytime[ANY_C_STAGE], anytime[ANY_C_K] = 0.0, 0.0
            return r, tests
        if r < -1:                                     # cut before tube -2 - r of this stage
            anytime[ANY_C_STAGE], anytime[ANY_C_K] = stage, -2 - r
            return -2, tests
        if (stages == COVER_ONE and stage == 0) or (stages == COVER_SLABS and stage == len(SLABS)):
            break
        stage, k0 = stage + 1, 0
    anytime[ANY_C_STAGE], anytime[ANY_C_K] = 0.0, 0.0
    return -1, tests


@njit(cache=True)
def cont_begin(anytime, X0, verified, intact, qp):
    """A continuation (the chain of Krawczyk boxes of :func:`.certify.follow_branch`) from the single
    candidate ``X0`` (3,) at the reading ``qp`` (3,); ``verified``: its tiny box is proved; ``intact``:
    the state's chain of certificates was intact there."""
    anytime[ANY_K_ON], anytime[ANY_K_INTACT] = 1.0, 1.0 if intact else 0.0
    anytime[ANY_K_X:ANY_K_X + 3] = X0
    anytime[ANY_K_PROG], anytime[ANY_K_PROG + 1], anytime[ANY_K_PROG + 2] = 0.0, 1.0, 0.0 if verified else -1.0
    anytime[ANY_K_N_PATH] = 1.0
    anytime[ANY_K_PATH:ANY_K_PATH + 3] = qp
    anytime[ANY_K_X0:ANY_K_X0 + 3] = X0
    anytime[ANY_K_KIND] = 1.0


@njit(cache=True)
def cont_append(anytime, q, d2, have_par):
    """Add the reading ``q`` (3,) at the continuation's path end, with the quadratic term ``d2`` (3,) of the
    parabola through the two readings before it and it (``have_par``: there is one; the step's
    :func:`.certified.parabola`); False (and the continuation ended) when full."""
    k = int(anytime[ANY_K_N_PATH])
    if not path_append(anytime, ANY_K_N_PATH, ANY_K_PATH, MAX_KPATH, q):
        anytime[ANY_K_ON] = 0.0
        return False
    for i in range(3):
        anytime[ANY_K_D2 + 3 * k + i] = d2[i] if have_par else 0.0
    anytime[ANY_K_PAR + k] = 1.0 if have_par else 0.0
    return True


@njit(cache=True)
def cont_on(anytime, max_tests, deadline, M, l1, b, l2sq, out):
    """Go on with the continuation along its path, each segment between two readings as
    :func:`.candidates.continue_single` follows a step's (straight, then, when that fails and there
    are three readings, along the parabola through them; exact joints on them), with at most
    ``max_tests`` Krawczyk tests each, until the ``deadline``.  Returns FOLLOW_DONE (``out`` (3,):
    the branch at the last reading, within TINY of the only solution there; the continuation is
    over), FOLLOW_CUT (it goes on at the next call) or FOLLOW_FAILED (over)."""
    x = anytime[ANY_K_X:ANY_K_X + 3]
    prog = anytime[ANY_K_PROG:ANY_K_PROG + 3]
    zero, d1, d2 = floats(3), floats(3), floats(3)
    zero[:] = 0.0
    d2[:] = 0.0
    while int(anytime[ANY_K_N_PATH]) >= 2:
        q0 = anytime[ANY_K_PATH:ANY_K_PATH + 3]
        parabola = anytime[ANY_K_KIND] > 1.0
        for i in range(3):
            d1[i] = anytime[ANY_K_PATH + 3 + i] - q0[i]
            d2[i] = anytime[ANY_K_D2 + 3 + i] if parabola else 0.0
            d1[i] -= d2[i]                             # q(s) = q0 + s d1 + s^2 d2 ends at the reading
        if prog[2] < 0.0:                              # the start's tiny box first
            if not tiny_box(x, q0, d1, zero, M, l1, b, l2sq):
                anytime[ANY_K_ON] = 0.0
                return FOLLOW_FAILED
            prog[2] = 1.0
        status = follow_on(x, q0, d1, d2, 0.0, M, l1, b, l2sq, max_tests, deadline, prog)
        if status == FOLLOW_FAILED and not parabola and anytime[ANY_K_PAR + 1] > 0.0:
            x[:] = anytime[ANY_K_X0:ANY_K_X0 + 3]      # the segment failed: its parabola from the start
            prog[0], prog[1], prog[2] = 0.0, 1.0, 0.0
            anytime[ANY_K_KIND] = 2.0
            continue
        if status != FOLLOW_DONE:
            if status == FOLLOW_FAILED:
                anytime[ANY_K_ON] = 0.0
            return status
        k = int(anytime[ANY_K_N_PATH])
        for j in range(3 * (k - 1)):
            anytime[ANY_K_PATH + j] = anytime[ANY_K_PATH + 3 + j]
            anytime[ANY_K_D2 + j] = anytime[ANY_K_D2 + 3 + j]
        for j in range(k - 1):
            anytime[ANY_K_PAR + j] = anytime[ANY_K_PAR + 1 + j]
        anytime[ANY_K_N_PATH] = k - 1
        anytime[ANY_K_X0:ANY_K_X0 + 3] = x
        anytime[ANY_K_KIND] = 1.0
        prog[0], prog[1], prog[2] = 0.0, 1.0, 0.0
    out[:] = x
    anytime[ANY_K_ON] = 0.0
    return FOLLOW_DONE
