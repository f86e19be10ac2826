"""Where each field of a tracker's state sits in its flat form (:meth:`solver.TrackerState.as_array`, the
state the compiled step advances in place, :mod:`.stepper`): :data:`STATE_FLOATS` floats.

The checks a saved array passes are :mod:`solver.state_array`'s; the fields' meaning is
:class:`solver.TrackerState`'s.
"""
from __future__ import annotations

from .anytime import ANY_SIZE
from .layout import PAVE_BOXES
from .tube import TUBE_SIZE
from .tube_chain import MAX_COVER

#: With measured joints and a speed bound: samples held in a row (a pose the platform cannot have
#: reached) after which the next pose is taken whatever its distance (see "Sensors", :mod:`solver.tracker`).
MAX_HELD = 10

#: Fields of TrackerState.as_array: X, q, X2 (NaN after a reset), dq_scale, steps, dt, q2 (NaN after a
#: reset), number of candidates, verified, uncertain_since, candidates (6 x 3, NaN past the number), intact,
#: a_scale, refused, anchor (NaN before the first certain step), anchor_age, skipped, reading (NaN before the
#: first), repeats, clean_lag, the number of tubes and the cover (NaN past them), the anchor's bound, the number
#: of paving boxes and the boxes (NaN past them), skipped_time, clean_time; then the
#: clean state's first _BASE floats (NaN when there is none); then the walk (NaN when there is none).
_X, _Q, _X2, _DQ_SCALE, _STEPS, _DT, _Q2, _N_CAND, _VERIFIED, _SINCE, _CANDS = 0, 3, 6, 9, 10, 11, 12, 15, 16, 17, 18
_INTACT, _A_SCALE, _REFUSED, _ANCHOR, _AGE = _CANDS + 18, _CANDS + 19, _CANDS + 20, _CANDS + 21, _CANDS + 24
_SKIPPED = _AGE + 1
_READING, _REPEATS, _CLEAN_LAG = _SKIPPED + 1, _SKIPPED + 4, _SKIPPED + 7
_N_TUBES = _CLEAN_LAG + 1
_TUBE = _N_TUBES + 1
_ANCHOR_BOUND = _TUBE + MAX_COVER * TUBE_SIZE
_N_PAVE = _ANCHOR_BOUND + 3
_PAVE = _N_PAVE + 1
_SKIPPED_TIME = _PAVE + 6 * PAVE_BOXES
_CLEAN_TIME = _SKIPPED_TIME + 1
_BASE = _CLEAN_TIME + 1
_WALK = 2 * _BASE
STATE_FLOATS = _WALK + ANY_SIZE
_FINITE = [*range(_X, _X + 3), *range(_Q, _Q + 3), _DQ_SCALE, _STEPS, _N_CAND, _VERIFIED, _SINCE, _INTACT, _A_SCALE,
           _REFUSED, _SKIPPED, *range(_REPEATS, _REPEATS + 3), _CLEAN_LAG, _N_PAVE]
