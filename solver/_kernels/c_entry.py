"""The tracker's step as one C entry point: a compiled function a C caller runs without the interpreter.

:func:`entry` is a numba ``cfunc`` of C signature ``int64 step(int64 *table, int64 cmd, double t,
double h)``.  ``table`` holds the addresses and shapes of the tracker's arrays (:func:`make_table`;
the rows ``T_*``), so the same machine code serves

- :data:`CMD_ADVANCE`: :func:`.stepper.tracker_advance` on the flat state, joints ``io[IO_Q:IO_Q+3]``,
  ``t`` s after the last sample (NaN: unknown), deadline ``h`` (cycles; 0: none), both also left in
  ``io[IO_DT]``, ``io[IO_DEADLINE]``; returns the step's ``uncertain_since`` (or
  :data:`.stepper.NOT_FINITE`) plus :data:`ADVANCE_OFFSET`, so that a kernel that raised (0) needs no
  read of ``io[IO_DONE]``.  What :meth:`solver.Tracker.step` calls (through
  :func:`.entry_call.call_entry`: one numba dispatch of five scalars instead of a 17-argument one);
- :data:`CMD_PACKED`: the step of a caller that wrote the state and anytime packs itself (the
  TrackerState path, :meth:`solver.TrackerState.pack`);
- :data:`CMD_TRACK`: a whole stream (what :meth:`solver.Tracker.track` calls once): the steps to the joints
  ``qs[k:]`` for ``k`` from ``io[IO_K0]``, each with a budget of ``io[IO_BUDGET]`` cycles (0: none), into
  the stream's result blocks (:func:`.stepper.record`, ``io[IO_RATE]`` the cycle counter's rate); returns the
  number of steps (0 when the table's stream rows are unset or do not agree, or k0 or the rate is
  out of range: :func:`stream_blocks`);
- :data:`CMD_PUBLISH`: a *guarded* step a C host (the DK FMU's loader) takes at time ``t`` over ``h``
  seconds: the joints are read from a value array at the slots ``SLOT_Q*``, the step's outputs are
  written to the value arrays at the other slots (:data:`SLOTS`), and the step is *undone* (the flat
  state restored, :data:`FALL_BACK` returned) whenever it is not routine: joints or times not finite,
  a status other than ``io[IO_EPISODE]`` (an episode to log), an output not finite.  The caller then
  takes the same step on its Python path, which logs and refuses as it always did.

A kernel that raises (numba's error model: a division by zero, say) makes the cfunc print the error
and return 0; ``io[IO_DONE]`` then stays 0.0, which every caller checks (:data:`CMD_ADVANCE`'s caller by
that answer, 0, which no step gives): :meth:`solver.Tracker.step` raises, the loader's lane takes the
step on the Python path from the committed state.

The one entry point is also what keeps the step's machine code compiled, cached and shipped once:
:func:`.stepper.tracker_advance` is compiled into this function only: a stream, an in-process step and an
FMU's step run the same machine code, compiled once.

Shapes are fixed by the table: a C caller cannot hand a wrong array to the kernels, it can only
hand a wrong address, which is why the table is built here from live numpy arrays and kept with them.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import carray, cfunc, njit, types

from .anytime import ANY_CUT
from .clock import cycles
from .pointers import address_pointer
from .layout import (F_COND, I_AMBIGUOUS, I_CERTAIN, I_LABEL, I_N_REAL, I_NEAR_BORDER, I_STATUS, I_TRUST, OUT_BOUND,
                     OUT_INFO, OUT_X, TRACK_BOOLS, TRACK_FLOATS, TRACK_INTS)
from .stepper import copy_state, record, tracker_advance

__all__ = ["entry", "make_table", "stream_table", "CMD_ADVANCE", "CMD_PACKED", "CMD_PUBLISH", "CMD_TRACK", "FALL_BACK",
           "PUBLISHED", "IO_SIZE", "SLOTS", "N_ARRAYS"]

CMD_ADVANCE, CMD_PACKED, CMD_PUBLISH, CMD_TRACK = 0, 1, 2, 3
#: What a :data:`CMD_PUBLISH` step returns when it undid itself (the caller takes the step its own way),
#: and when it published (anything else, 0 from a cfunc whose kernel raised included, is not published).
FALL_BACK, PUBLISHED = 1, 2
#: :data:`CMD_ADVANCE` returns ``uncertain_since + ADVANCE_OFFSET`` (``uncertain_since`` >= NOT_FINITE = -2).
ADVANCE_OFFSET = 3

# the arrays of the table, 4 int64 each: address, then up to three dimensions
(T_A, T_PK, T_MODEL, T_S2S, T_LABELS, T_MAP, T_STENCIL, T_PARAMS, T_OUT_REAL, T_OUT_INT, T_ANYTIME, T_IO, T_BACKUP,
 T_REAL, T_INT, T_BOOL, T_SLOTS, T_QS, T_FLOATS, T_INTS, T_BOOLS) = range(21)
N_ARRAYS = 21
T_MODE, T_RULE = 4 * N_ARRAYS, 4 * N_ARRAYS + 1      # two integers after the arrays
TABLE_SIZE = 4 * N_ARRAYS + 2

# the scalars a call reads and writes (float64 array ``io``)
IO_Q, IO_DT, IO_DEADLINE = 0, 3, 4                   # in: joints (rad), time since the last sample (s), deadline
IO_SHARE, IO_RATE, IO_EPISODE = 5, 6, 7              # publish, in: budget share of h, cycles per second (also
                                                     # track's), status
IO_SINCE_STEP, IO_SINCE_TIME = 8, 9                  # publish, in/out: the uncertain episode (NaN: none), its time
IO_TIME, IO_NO_BOUND, IO_STEPS = 10, 11, 12          # publish, out: t + h; in: the bound of no bound; out: count
IO_DONE = 13                                         # out: 1.0 when the call ran to its end (0.0: it raised)
IO_LAST_Q, IO_LAST_H = 14, 17                        # publish, out: joints (3) and h of the last published step
IO_K0, IO_BUDGET = 18, 19                            # track, in: the first row to step, each step's budget (cycles)
IO_SIZE = 20

#: The slots of a published step: value references in the caller's value arrays (float64 ``real``,
#: int32 ``integer``, int32 ``boolean``), in this order.
SLOTS = ("q1", "q2", "q3", "x", "y", "phi", "region", "near_border", "n_real", "ambiguous", "status", "cond",
         "certain", "uncertain_since", "x_bound", "y_bound", "phi_bound", "trust", "out_of_budget")
(S_Q1, S_Q2, S_Q3, S_X, S_Y, S_PHI, S_REGION, S_NEAR, S_N_REAL, S_AMBIGUOUS, S_STATUS, S_COND, S_CERTAIN, S_SINCE,
 S_XB, S_YB, S_PHIB, S_TRUST, S_OOB) = range(len(SLOTS))


@njit(cache=False)                  # compiled into the entry point only
def _publish(tb, t, h, a, pk, model, s2s, labels, mp, stencil, params, out_real, out_int, anytime, io):
    """The guarded step of :data:`CMD_PUBLISH` (see the module doc); :data:`PUBLISHED` or :data:`FALL_BACK`."""
    backup = carray(address_pointer(tb[4 * T_BACKUP]), (tb[4 * T_BACKUP + 1],), np.float64)
    real = carray(address_pointer(tb[4 * T_REAL]), (tb[4 * T_REAL + 1],), np.float64)
    integer = carray(address_pointer(tb[4 * T_INT]), (tb[4 * T_INT + 1],), np.int32)
    boolean = carray(address_pointer(tb[4 * T_BOOL]), (tb[4 * T_BOOL + 1],), np.int32)
    slots = carray(address_pointer(tb[4 * T_SLOTS]), (tb[4 * T_SLOTS + 1],), np.int64)
    if not (math.isfinite(t) and math.isfinite(h) and h >= 0.0):
        return FALL_BACK
    q = io[IO_Q:IO_Q + 3]
    for i in range(3):
        q[i] = real[slots[S_Q1 + i]]
    dt = h if h > 0.0 else math.nan
    share = io[IO_SHARE]
    deadline = float(cycles()) + share * h * io[IO_RATE] if share > 0.0 and h > 0.0 else 0.0
    copy_state(a, backup, True)
    since = tracker_advance(tb[T_MODE], tb[T_RULE], q, dt, deadline, a, pk, model, s2s, labels, mp, stencil, params,
                            out_real, out_int, anytime, h < 0.0)          # a typed False (see stepper)
    certain = out_int[I_CERTAIN] != 0
    cond = out_real[OUT_INFO + F_COND]
    fine = since >= -1 and out_int[I_STATUS] == io[IO_EPISODE] and math.isfinite(cond)
    for i in range(3):
        fine = fine and math.isfinite(out_real[OUT_X + i]) and (not certain or math.isfinite(out_real[OUT_BOUND + i]))
    if not fine:
        copy_state(backup, a, False)
        return FALL_BACK
    if certain:
        io[IO_SINCE_STEP] = math.nan
    elif io[IO_SINCE_STEP] != since:                      # a new episode (NaN != anything): it begins now
        io[IO_SINCE_STEP] = since
        io[IO_SINCE_TIME] = t + h
    for i in range(3):
        real[slots[S_X + i]] = out_real[OUT_X + i]
        real[slots[S_XB + i]] = out_real[OUT_BOUND + i] if certain else io[IO_NO_BOUND]
    real[slots[S_COND]] = cond
    real[slots[S_SINCE]] = -1.0 if certain else io[IO_SINCE_TIME]
    integer[slots[S_REGION]] = out_int[I_LABEL]
    integer[slots[S_N_REAL]] = out_int[I_N_REAL]
    integer[slots[S_STATUS]] = out_int[I_STATUS]
    integer[slots[S_TRUST]] = out_int[I_TRUST]
    boolean[slots[S_NEAR]] = 1 if out_int[I_NEAR_BORDER] != 0 else 0
    boolean[slots[S_AMBIGUOUS]] = 1 if out_int[I_AMBIGUOUS] != 0 else 0
    boolean[slots[S_CERTAIN]] = 1 if certain else 0
    boolean[slots[S_OOB]] = 1 if deadline > 0.0 and not certain and anytime[ANY_CUT] > 0.0 else 0
    for i in range(3):
        io[IO_LAST_Q + i] = q[i]
    io[IO_LAST_H] = h
    io[IO_TIME] = t + h
    io[IO_STEPS] += 1.0
    return PUBLISHED


@njit(cache=False)                  # compiled into the entry points only
def table_arrays(tb):
    """The arrays of a table (int64 (TABLE_SIZE,)) that a tracker's and a baseline's step both read: ``(a, pk,
    model, s2s, params, out_real, out_int, io)`` (the tracker's map, labels, stencil and anytime pack are its
    own: :func:`_step`)."""
    a = carray(address_pointer(tb[4 * T_A]), (tb[4 * T_A + 1],), np.float64)
    pk = carray(address_pointer(tb[4 * T_PK]), (tb[4 * T_PK + 1],), np.float64)
    model = carray(address_pointer(tb[4 * T_MODEL]), (tb[4 * T_MODEL + 1],), np.float64)
    s2s = carray(address_pointer(tb[4 * T_S2S]), (tb[4 * T_S2S + 1], tb[4 * T_S2S + 2], tb[4 * T_S2S + 3]), np.float64)
    params = carray(address_pointer(tb[4 * T_PARAMS]), (tb[4 * T_PARAMS + 1],), np.float64)
    out_real = carray(address_pointer(tb[4 * T_OUT_REAL]), (tb[4 * T_OUT_REAL + 1],), np.float64)
    out_int = carray(address_pointer(tb[4 * T_OUT_INT]), (tb[4 * T_OUT_INT + 1],), np.int64)
    io = carray(address_pointer(tb[4 * T_IO]), (tb[4 * T_IO + 1],), np.float64)
    return a, pk, model, s2s, params, out_real, out_int, io


@njit(cache=False)                  # compiled into the entry points only
def stream_blocks(tb, io):
    """The stream of a table (:data:`CMD_TRACK`): ``(k0, qs, floats, ints, bools)``, the first step
    ``io[IO_K0]``, the joints (n, 3) and the result blocks (``floats`` (TRACK_FLOATS * n,), ``ints``
    (TRACK_INTS, n) int64, ``bools`` (TRACK_BOOLS, n); :mod:`.layout` ``TF_*``, ``TI_*``, ``TB_*``).
    Nothing to step (k0 = n = 0) when a row is unset, its shape is not that of the ``n`` rows of ``qs``,
    ``io[IO_K0]`` is not a step index 0..n or the cycle counter's rate ``io[IO_RATE]`` is not positive."""
    n = tb[4 * T_QS + 1]
    ok = (tb[4 * T_QS] != 0 and tb[4 * T_QS + 2] == 3 and tb[4 * T_FLOATS] != 0 and tb[4 * T_INTS] != 0
          and tb[4 * T_BOOLS] != 0 and tb[4 * T_FLOATS + 1] == TRACK_FLOATS * n and tb[4 * T_INTS + 1] == TRACK_INTS
          and tb[4 * T_INTS + 2] == n and tb[4 * T_BOOLS + 1] == TRACK_BOOLS and tb[4 * T_BOOLS + 2] == n
          and io[IO_K0] >= 0.0 and io[IO_K0] <= n and io[IO_RATE] > 0.0)
    if not ok:
        n = 0
    qs = carray(address_pointer(tb[4 * T_QS]), (n, 3), np.float64)
    floats = carray(address_pointer(tb[4 * T_FLOATS]), (TRACK_FLOATS * n,), np.float64)
    ints = carray(address_pointer(tb[4 * T_INTS]), (TRACK_INTS, n), np.int64)
    bools = carray(address_pointer(tb[4 * T_BOOLS]), (TRACK_BOOLS, n), np.bool_)
    return int(io[IO_K0]) if ok else 0, qs, floats, ints, bools


@njit(cache=False)                  # compiled into the entry point only
def _track(tb, a, pk, model, s2s, labels, mp, stencil, params, out_real, out_int, anytime, io, packed):
    """The stream of :data:`CMD_TRACK` (see the module doc): the number of steps taken."""
    k0, qs, floats, ints, bools = stream_blocks(tb, io)
    n = qs.shape[0]
    budget, rate = io[IO_BUDGET], io[IO_RATE]
    q = io[IO_Q:IO_Q + 3]           # the step's arguments typed as CMD_ADVANCE's: tracker_advance compiles once
    for k in range(k0, n):
        for i in range(3):
            q[i] = qs[k, i]
        c0 = cycles()
        io[IO_DT] = math.nan
        io[IO_DEADLINE] = float(c0) + budget if budget > 0.0 else 0.0
        since = tracker_advance(tb[T_MODE], tb[T_RULE], q, io[IO_DT], io[IO_DEADLINE], a, pk, model, s2s, labels, mp,
                                stencil, params, out_real, out_int, anytime, packed)
        c1 = cycles()
        cut = io[IO_DEADLINE] > 0.0 and out_int[I_CERTAIN] == 0 and anytime[ANY_CUT] > 0.0
        record(k, out_real, out_int, since, cut, c0, c1, rate, floats, ints, bools)
    return max(n - k0, 0)


def _step(table, cmd, t, h):
    """The entry point's body (module doc)."""
    tb = carray(table, (TABLE_SIZE,), np.int64)
    a, pk, model, s2s, params, out_real, out_int, io = table_arrays(tb)
    labels = carray(address_pointer(tb[4 * T_LABELS]), (tb[4 * T_LABELS + 1], tb[4 * T_LABELS + 2], tb[4 * T_LABELS + 3]),
                    np.int8)
    mp = carray(address_pointer(tb[4 * T_MAP]), (tb[4 * T_MAP + 1],), np.float64)
    stencil = carray(address_pointer(tb[4 * T_STENCIL]), (tb[4 * T_STENCIL + 1], tb[4 * T_STENCIL + 2]), np.int64)
    anytime = carray(address_pointer(tb[4 * T_ANYTIME]), (tb[4 * T_ANYTIME + 1],), np.float64)
    io[IO_DONE] = 0.0
    if cmd == CMD_PUBLISH:
        if tb[4 * T_SLOTS] == 0:
            return FALL_BACK
        r = _publish(tb, t, h, a, pk, model, s2s, labels, mp, stencil, params, out_real, out_int, anytime, io)
    elif cmd == CMD_TRACK:
        r = _track(tb, a, pk, model, s2s, labels, mp, stencil, params, out_real, out_int, anytime, io,
                   cmd == CMD_PACKED)                    # a typed False, as the call below
    else:
        if cmd == CMD_ADVANCE:          # the time step and the deadline come as the call's t and h
            io[IO_DT] = t
            io[IO_DEADLINE] = h
        r = tracker_advance(tb[T_MODE], tb[T_RULE], io[IO_Q:IO_Q + 3], io[IO_DT], io[IO_DEADLINE], a, pk, model, s2s,
                            labels, mp, stencil, params, out_real, out_int, anytime, cmd == CMD_PACKED)
        if cmd == CMD_ADVANCE:
            r += ADVANCE_OFFSET         # at least 1: the 0 of a kernel that raised is never a step's answer
    io[IO_DONE] = 1.0           # (a kernel that raised returns 0 from the cfunc, with this still 0.0)
    return r


_SIGNATURE = types.int64(types.voidptr, types.int64, types.float64, types.float64)


@lru_cache(maxsize=None)
def entry():
    """The compiled entry point (numba ``CFunc``, cached on disk; made on first use, not at import: a
    process that never steps a tracker never loads it).  ``entry().address`` is its C address,
    ``entry().ctypes`` a ctypes function."""
    return cfunc(_SIGNATURE, cache=True)(_step)


def _row(table: np.ndarray, k: int, array: np.ndarray) -> None:
    if not (array.flags.c_contiguous and array.flags.writeable):
        raise ValueError(f"entry table row {k}: expected a C-contiguous writable array, got flags "
                         f"{array.flags.c_contiguous, array.flags.writeable}")
    table[4 * k] = array.ctypes.data
    table[4 * k + 1:4 * k + 1 + array.ndim] = array.shape


def make_table(mode: int, rule: int, arrays: dict) -> np.ndarray:
    """The table (TABLE_SIZE,) int64 of :func:`entry` for a tracker's ``arrays`` (name -> array: ``a``,
    ``pk``, ``model``, ``s2s``, ``labels``, ``map``, ``stencil``, ``params``, ``out_real``, ``out_int``,
    ``anytime``, ``io``, ``backup``; a publishing caller adds ``real``, ``integer``, ``boolean``, ``slots``
    with :func:`set_rows`, a tracking one ``qs``, ``floats``, ``ints``, ``bools`` with :func:`stream_table`).
    The caller keeps the arrays alive as long as the table."""
    table = np.zeros(TABLE_SIZE, dtype=np.int64)
    set_rows(table, arrays)
    table[T_MODE], table[T_RULE] = int(mode), int(rule)
    return table


_ROWS = {"a": T_A, "pk": T_PK, "model": T_MODEL, "s2s": T_S2S, "labels": T_LABELS, "map": T_MAP,
         "stencil": T_STENCIL, "params": T_PARAMS, "out_real": T_OUT_REAL, "out_int": T_OUT_INT,
         "anytime": T_ANYTIME, "io": T_IO, "backup": T_BACKUP, "real": T_REAL, "integer": T_INT, "boolean": T_BOOL,
         "slots": T_SLOTS, "qs": T_QS, "floats": T_FLOATS, "ints": T_INTS, "bools": T_BOOLS}
_DTYPES = {"labels": np.int8, "stencil": np.int64, "out_int": np.int64, "integer": np.int32, "boolean": np.int32,
           "slots": np.int64, "ints": np.int64, "bools": np.bool_}
_NDIM = {"s2s": 3, "labels": 3, "stencil": 2, "qs": 2, "ints": 2, "bools": 2}


def stream_table(table: np.ndarray, qs: np.ndarray, floats: np.ndarray, ints: np.ndarray,
                 bools: np.ndarray) -> np.ndarray:
    """A copy of ``table`` whose stream rows (:data:`CMD_TRACK`) point at the joints ``qs`` (n, 3) and the
    result blocks ``floats`` (TRACK_FLOATS * n,), ``ints`` (TRACK_INTS, n) int64, ``bools`` (TRACK_BOOLS, n)
    (:func:`solver.step_info.track_blocks`); shapes and dtypes checked (the loop also refuses a table whose
    rows disagree)."""
    n = qs.shape[0] if qs.ndim == 2 else -1
    want = {"qs": (n, 3), "floats": (TRACK_FLOATS * n,), "ints": (TRACK_INTS, n), "bools": (TRACK_BOOLS, n)}
    arrays = {"qs": qs, "floats": floats, "ints": ints, "bools": bools}
    for name, array in arrays.items():
        if getattr(array, "shape", None) != want[name]:
            raise ValueError(f"stream table {name!r}: expected shape {want[name]}, got {getattr(array, 'shape', None)}")
    out = table.copy()
    set_rows(out, arrays)
    return out


def set_rows(table: np.ndarray, arrays: dict) -> None:
    """Point the rows of ``table`` named in ``arrays`` at those arrays (dtype and dimensions checked)."""
    for name, array in arrays.items():
        want = np.dtype(_DTYPES.get(name, np.float64))
        if not isinstance(array, np.ndarray) or array.dtype != want or array.ndim != _NDIM.get(name, 1):
            raise ValueError(f"entry table {name!r}: expected a {_NDIM.get(name, 1)}-D {want} array, got "
                             f"{getattr(array, 'dtype', type(array).__name__)} {getattr(array, 'shape', '')}")
        _row(table, _ROWS[name], array)
