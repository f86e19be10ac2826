"""A whole step on the tracker's flat state, compiled: pack it, step, advance it in place.

The tracker's data is one flat array (:mod:`.state_layout`, the same floats as
:meth:`solver.TrackerState.as_array`).  :func:`pack_state` writes the state pack a step reads
(:mod:`.layout` ``STATE_*``), :func:`advance_state` writes the next state from the step's result pack
into the same array, and :func:`tracker_advance` / :func:`baseline_advance` do the three in one call:
the Python of a step is then the argument checks and one call.  The tracker's stream loop is the C
entry point's (:mod:`.c_entry`, ``CMD_TRACK``: the step compiled once), a baseline's that of its entry
(:mod:`.baseline_entry`).

These are :meth:`solver.TrackerState.pack` and :meth:`solver.TrackerState.after` (the stuck-joint
detector off), float for float: the suites' results are bit-identical whichever runs
(``tests/test_stepper.py``).
"""
from __future__ import annotations

import math

from numba import njit

from .anytime import ANY_DEADLINE, ANY_K_ON, ANY_N, ANY_R_ON, walk_floats
from .baselines import baseline_step
from .certify import CERT_CONTINUATION, CERT_REACQUIRED
from .layout import (F_COND, F_D_BEST, F_D_SECOND, F_DQ, F_INNOV, I_AMBIGUOUS, I_CERTAIN, I_CERTIFICATE, I_INTACT,
                     I_JUMP, I_LABEL, I_N_CAND, I_N_REAL, I_NEAR_BORDER, I_STATUS, I_TRUST, MAX_REFUSED,
                     OUT_BOUND, OUT_CANDS, OUT_INFO, OUT_N_PAVE, OUT_N_TUBES, OUT_PAVE, OUT_REGION, OUT_TUBE, OUT_X,
                     OUT_X_PRED, PAVE_BOXES, STATE_A_SCALE, STATE_ANCHOR, STATE_ANCHOR_AGE, STATE_ANCHOR_BOUND,
                     STATE_CANDS, STATE_DQ_SCALE, STATE_EXT_SCALE, STATE_HAVE_Q2, STATE_HISTORY, STATE_INTACT,
                     STATE_N_CAND, STATE_N_PAVE, STATE_N_TUBES, STATE_PAVE, STATE_Q, STATE_Q2, STATE_REFUSED,
                     STATE_STEP_DT, STATE_TUBE, STATE_VERIFIED, STATE_X, STATE_X2, STATUS_REJECTED,
                     STATUS_UNREACHABLE, TB_AMBIGUOUS, TB_CERTAIN, TB_JUMP, TB_NEAR_BORDER, TB_OUT_OF_BUDGET, TF_BOUND,
                     TF_COND, TF_D_BEST, TF_D_SECOND, TF_SECONDS, TF_X, TF_X_PRED, TI_CERTIFICATE, TI_LABEL, TI_N_CAND,
                     TI_N_REAL, TI_SINCE, TI_STATUS, TI_TRUST)
from .state_layout import (MAX_HELD, _A_SCALE, _AGE, _ANCHOR, _ANCHOR_BOUND, _BASE, _CANDS, _CLEAN_LAG, _CLEAN_TIME,
                           _DQ_SCALE, _DT, _INTACT, _N_CAND, _N_PAVE, _N_TUBES, _PAVE, _Q, _Q2, _READING, _REFUSED,
                           _REPEATS, _SINCE, _SKIPPED, _SKIPPED_TIME, _STEPS, _TUBE, _VERIFIED, _WALK, _X, _X2)
from .tracker import tracker_step
from .tube import TUBE_SIZE
from .tube_chain import MAX_COVER

#: What :func:`tracker_advance` and :func:`baseline_advance` return for joints that are not all finite.
NOT_FINITE = -2


@njit(cache=True)
def finite3(q):
    """Whether the three joints ``q`` (3,) are finite numbers."""
    return math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2])


@njit(cache=True)
def pack_state(a, dt, pk):
    """Write the state pack ``pk`` (STATE_SIZE,) a step from the flat state ``a`` reads, the sample ``dt``
    seconds after the last one read (NaN: uniformly spaced samples, no speed gate).  As
    :meth:`solver.TrackerState.pack` with the stuck-joint detector off."""
    gap_s = a[_SKIPPED_TIME] + dt                        # NaN when dt or the skipped time is unknown
    for i in range(3):
        pk[STATE_X + i] = a[_X + i]
        pk[STATE_Q + i] = a[_Q + i]
    have_x2 = not math.isnan(a[_X2])
    for i in range(3):
        pk[STATE_X2 + i] = a[_X2 + i] if have_x2 else a[_X + i]
    pk[STATE_HISTORY] = 2.0 if have_x2 else 1.0
    pk[STATE_DQ_SCALE] = a[_DQ_SCALE]
    pk[STATE_EXT_SCALE] = gap_s / a[_DT] if math.isfinite(gap_s) and math.isfinite(a[_DT]) else a[_SKIPPED] + 1.0
    gate_on = not math.isnan(dt) and a[_REFUSED] < MAX_REFUSED and a[_SKIPPED] < MAX_HELD
    pk[STATE_STEP_DT] = gap_s if gate_on else math.nan
    if math.isnan(a[_Q2]):
        pk[STATE_HAVE_Q2] = 0.0
    else:
        for i in range(3):
            pk[STATE_Q2 + i] = a[_Q2 + i]
        pk[STATE_HAVE_Q2] = 1.0
    n = int(a[_N_CAND])
    if n == 0:                                           # right after a reset: the initial pose
        for i in range(3):
            pk[STATE_CANDS + i] = a[_X + i]
        pk[STATE_N_CAND] = 1.0
    else:
        for i in range(3 * n):
            pk[STATE_CANDS + i] = a[_CANDS + i]
        pk[STATE_N_CAND] = n
    pk[STATE_VERIFIED] = a[_VERIFIED]
    n = int(a[_N_TUBES])
    if n > 0 and a[_SINCE] < 0:
        for i in range(n * TUBE_SIZE):
            pk[STATE_TUBE + i] = a[_TUBE + i]
        pk[STATE_N_TUBES] = n
    else:
        pk[STATE_N_TUBES] = 0.0
    pk[STATE_INTACT] = a[_INTACT]
    pk[STATE_A_SCALE] = a[_A_SCALE]
    pk[STATE_REFUSED] = a[_REFUSED]
    if math.isnan(a[_ANCHOR]):
        for i in range(3):
            pk[STATE_ANCHOR + i] = a[_X + i]
        pk[STATE_ANCHOR_AGE] = math.nan
    else:
        for i in range(3):
            pk[STATE_ANCHOR + i] = a[_ANCHOR + i]
        pk[STATE_ANCHOR_AGE] = a[_AGE] + gap_s
    for i in range(3):
        pk[STATE_ANCHOR_BOUND + i] = a[_ANCHOR_BOUND + i]
    n = int(a[_N_PAVE])
    pk[STATE_N_PAVE] = n
    for i in range(6 * n):
        pk[STATE_PAVE + i] = a[_PAVE + i]


@njit(cache=True)
def load_walk(a, anytime, deadline):
    """The anytime pack ``anytime`` of a step from the flat state ``a``: its walk (none: no walk, no
    continuation, no re-acquisition under way) and the step's ``deadline`` (a cycle count; 0.0 none)."""
    if math.isnan(a[_WALK + ANY_N]):
        anytime[ANY_N] = 0.0
        anytime[ANY_K_ON] = 0.0
        anytime[ANY_R_ON] = 0.0
    else:
        n = walk_floats(a[_WALK:])
        for i in range(n):
            anytime[i] = a[_WALK + i]
    anytime[ANY_DEADLINE] = deadline


@njit(cache=True)
def advance_state(a, q, dt, out_real, out_int, anytime, walks):
    """Write into the flat state ``a`` the state after its step to joints ``q`` (3,), ``dt`` seconds after
    the last sample read (NaN: unknown), from the step's result pack; ``anytime`` the step's anytime pack
    (its walk kept when ``walks`` and the step is accepted, not certain).  As
    :meth:`solver.TrackerState.after` with the stuck-joint detector off.

    Returns the step's ``uncertain_since`` (:meth:`solver.TrackerState.since`).
    """
    certain = out_int[I_CERTAIN] != 0
    since = -1 if certain else (int(a[_SINCE]) if a[_SINCE] >= 0 else int(a[_STEPS]) + 1)
    gap_s = a[_SKIPPED_TIME] + dt
    status = out_int[I_STATUS]
    if status == STATUS_REJECTED or status == STATUS_UNREACHABLE:   # only the counts move
        if status == STATUS_REJECTED:
            a[_REFUSED] += 1.0
        a[_SKIPPED] += 1.0
        a[_SKIPPED_TIME] = gap_s
        return since
    steps = a[_STEPS]
    dqn, innov = out_real[OUT_INFO + F_DQ], out_real[OUT_INFO + F_INNOV]
    scale = dqn if steps == 0 else 0.8 * a[_DQ_SCALE] + 0.2 * dqn
    if steps >= 2:
        mean = 0.8 * a[_A_SCALE] + 0.2 * innov
        innov = mean if mean > innov else innov              # Python's max(innov, mean)
    have_anchor = not math.isnan(a[_ANCHOR])
    age = a[_AGE] + gap_s
    paved = True                                         # the set-membership step's paving holds the robot now
    for i in range(6):
        if not math.isfinite(out_real[OUT_REGION + i]):
            paved = False
    boxed = certain and not paved                        # a certain step's bound starts the next region
    # the pose before: the previous one
    for i in range(3):
        a[_X2 + i] = a[_X + i]
        a[_Q2 + i] = a[_Q + i]
        a[_X + i] = out_real[OUT_X + i]
        a[_Q + i] = q[i]
    a[_DQ_SCALE] = scale
    a[_STEPS] = steps + 1.0
    a[_DT] = gap_s
    n = out_int[I_N_CAND]
    a[_N_CAND] = n
    for i in range(3 * n):
        a[_CANDS + i] = out_real[OUT_CANDS + i]
    for i in range(3 * n, 18):
        a[_CANDS + i] = math.nan
    cert = out_int[I_CERTIFICATE]
    a[_VERIFIED] = 1.0 if cert == CERT_CONTINUATION or cert == CERT_REACQUIRED else 0.0
    a[_SINCE] = since
    a[_INTACT] = 1.0 if out_int[I_INTACT] != 0 else 0.0
    a[_A_SCALE] = innov
    a[_REFUSED] = 0.0
    if paved:
        region = out_real[OUT_REGION:OUT_REGION + 6]
        for i in range(3):
            a[_ANCHOR + i] = 0.5 * (region[2 * i] + region[2 * i + 1])
            a[_ANCHOR_BOUND + i] = 0.5 * (region[2 * i + 1] - region[2 * i])
        age = 0.0
        m = out_real[OUT_N_PAVE]
        if 1 <= m <= PAVE_BOXES:
            a[_N_PAVE] = int(m)
            for i in range(6 * int(m)):
                a[_PAVE + i] = out_real[OUT_PAVE + i]
        else:
            a[_N_PAVE] = 0.0
        have_anchor = True
    elif boxed:
        for i in range(3):
            a[_ANCHOR + i] = out_real[OUT_X + i]
            a[_ANCHOR_BOUND + i] = out_real[OUT_BOUND + i]
        a[_N_PAVE] = 0.0
    elif not have_anchor:
        for i in range(3):
            a[_ANCHOR_BOUND + i] = math.inf
    a[_AGE] = 0.0 if certain else age
    a[_SKIPPED] = 0.0
    a[_SKIPPED_TIME] = 0.0
    a[_CLEAN_TIME] = 0.0
    a[_CLEAN_LAG] = 0.0
    for i in range(3):
        a[_READING + i] = math.nan
        a[_REPEATS + i] = 0.0
    if not math.isnan(a[_BASE]):                         # no clean state (the stuck-joint detector is off)
        for i in range(_BASE, 2 * _BASE):
            a[i] = math.nan
    m = out_real[OUT_N_TUBES]
    if certain and math.isfinite(m) and 1 <= m <= MAX_COVER:
        a[_N_TUBES] = int(m)
        for i in range(int(m) * TUBE_SIZE):
            a[_TUBE + i] = out_real[OUT_TUBE + i]
    else:
        a[_N_TUBES] = 0.0
    n = walk_floats(anytime) if walks and not certain else 0
    if n == 0:
        a[_WALK + ANY_N] = math.nan
    else:
        for i in range(n):
            a[_WALK + i] = anytime[i]
    return since


@njit(cache=False)  # compiled into its one caller, the C entry point (c_entry)
def tracker_advance(mode, rule, q, dt, deadline, a, pk, model_pack, sample_to_sextic, labels, map_pack, stencil,
                    params, out_real, out_int, anytime, packed):
    """One tracker step (:func:`.tracker.tracker_step`) from the flat state ``a``, advanced in place:
    joints ``q`` (3,) rad, ``dt`` s after the last sample read (NaN: unknown), ``deadline`` a cycle count
    (0.0: none); ``pk`` the state pack (scratch).  Returns the step's ``uncertain_since``, or
    :data:`NOT_FINITE` (nothing done, ``a`` unchanged) when ``q`` has a NaN or an infinity.

    ``packed``: the caller wrote the state pack ``pk`` and the anytime pack (the step of a
    :class:`solver.TrackerState` object, :meth:`solver.TrackerState.pack`): only the step runs, ``a`` is
    not read nor written (returns 0).  Compiled into its one caller only (``cache=False``): the C entry
    point :func:`.c_entry.entry`, which every step and stream of a :class:`solver.Tracker` and the DK
    FMU's loader call; its machine code is cached and shipped inside it.
    """
    if packed:
        tracker_step(mode, rule, q, pk, model_pack, sample_to_sextic, labels, map_pack, stencil, params, out_real,
                     out_int, anytime)
        return 0
    if not finite3(q):
        return NOT_FINITE
    pack_state(a, dt, pk)
    load_walk(a, anytime, deadline)
    tracker_step(mode, rule, q, pk, model_pack, sample_to_sextic, labels, map_pack, stencil, params, out_real,
                 out_int, anytime)
    return advance_state(a, q, dt, out_real, out_int, anytime, True)


@njit(cache=False)  # compiled into its callers: the baselines' entry (baseline_entry) and the bench's loop
def baseline_advance(kind, rule, q, dt, a, pk, model_pack, sample_to_sextic, params, out_real, out_int, packed):
    """One baseline step (:func:`.baselines.baseline_step`) from the flat state ``a``, advanced in place
    (arguments and result as :func:`tracker_advance`)."""
    if packed:
        baseline_step(kind, rule, q, pk, model_pack, sample_to_sextic, params, out_real, out_int)
        return 0
    if not finite3(q):
        return NOT_FINITE
    pack_state(a, dt, pk)
    baseline_step(kind, rule, q, pk, model_pack, sample_to_sextic, params, out_real, out_int)
    return advance_state(a, q, dt, out_real, out_int, out_real, False)


@njit(cache=True)
def record(k, out_real, out_int, since, cut, c0, c1, rate, floats, ints, bools):
    """Step ``k`` of a stream into its result blocks (:mod:`.layout` ``TF_*``, ``TI_*``, ``TB_*``: ``floats``
    (TRACK_FLOATS * n,), ``ints`` (TRACK_INTS, n) int64, ``bools`` (TRACK_BOOLS, n)) from the step's result
    pack: ``since`` its ``uncertain_since``, ``cut`` out of budget, ``c0``, ``c1`` the cycle counter before
    and after the step, ``rate`` the counter's cycles per second."""
    n = ints.shape[1]
    certain = out_int[I_CERTAIN] != 0
    for i in range(3):
        floats[TF_X * n + 3 * k + i] = out_real[OUT_X + i]
        floats[TF_X_PRED * n + 3 * k + i] = out_real[OUT_X_PRED + i]
        floats[TF_BOUND * n + 3 * k + i] = out_real[OUT_BOUND + i] if certain else math.inf
    floats[TF_COND * n + k] = out_real[OUT_INFO + F_COND]
    floats[TF_D_BEST * n + k] = out_real[OUT_INFO + F_D_BEST]
    floats[TF_D_SECOND * n + k] = out_real[OUT_INFO + F_D_SECOND]
    floats[TF_SECONDS * n + k] = (c1 - c0) / rate
    ints[TI_LABEL, k] = out_int[I_LABEL]
    ints[TI_N_REAL, k] = out_int[I_N_REAL]
    ints[TI_STATUS, k] = out_int[I_STATUS]
    ints[TI_CERTIFICATE, k] = out_int[I_CERTIFICATE]
    ints[TI_N_CAND, k] = out_int[I_N_CAND]
    ints[TI_SINCE, k] = since
    ints[TI_TRUST, k] = out_int[I_TRUST]
    bools[TB_NEAR_BORDER, k] = out_int[I_NEAR_BORDER] != 0
    bools[TB_AMBIGUOUS, k] = out_int[I_AMBIGUOUS] != 0
    bools[TB_JUMP, k] = out_int[I_JUMP] != 0
    bools[TB_CERTAIN, k] = certain
    bools[TB_OUT_OF_BUDGET, k] = cut


@njit(cache=True)
def copy_state(src, dst, fresh):
    """Copy the flat state ``src`` into ``dst`` (both STATE_FLOATS,): its fields, its clean state (NaN when it
    has none: written when ``dst`` is ``fresh``, uninitialised, or had one), its walk; the floats past the
    counts of candidates, tubes, boxes and walk are left as they are (nothing reads them)."""
    for i in range(_BASE):
        dst[i] = src[i]
    if not math.isnan(src[_BASE]):
        for i in range(_BASE, 2 * _BASE):
            dst[i] = src[i]
    elif fresh or not math.isnan(dst[_BASE]):
        for i in range(_BASE, 2 * _BASE):
            dst[i] = math.nan
    if math.isnan(src[_WALK + ANY_N]):
        dst[_WALK + ANY_N] = math.nan
    else:
        for i in range(_WALK, _WALK + walk_floats(src[_WALK:])):
            dst[i] = src[i]
