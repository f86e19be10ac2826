"""A baseline's step as one compiled call of four scalars: what :class:`solver.baselines.NewtonTracker` and
the other baselines call from Python.

:func:`baseline_entry` reads the baseline's arrays from a table of addresses (the layout of the
tracker's C entry point, :func:`.c_entry.make_table`: rows ``T_*``, the baseline's kind in the mode
row), so a step from Python is one numba dispatch of ``(table address, command, t, h)``: four
scalars, about 0.3 us less than dispatching :func:`.stepper.baseline_advance`'s twelve arguments
(whose seven arrays numba types and unboxes at every call), measured in ``bench/bench_step.py``.
Commands (:mod:`.c_entry`'s codes):

- ``CMD_ADVANCE``: :func:`.stepper.baseline_advance` on the flat state, joints ``io[IO_Q:IO_Q+3]``,
  ``t`` s after the last sample (NaN: unknown); returns the step's ``uncertain_since`` (or
  :data:`.stepper.NOT_FINITE`);
- ``CMD_PACKED``: the step of a caller that wrote the state pack itself (the TrackerState path);
- ``CMD_TRACK``: the steps to the joints ``qs[k:]`` for ``k`` from ``io[IO_K0]``, into the stream's result
  blocks (:func:`.c_entry.stream_table`, :func:`.stepper.record`; ``io[IO_RATE]`` the cycle counter's rate);
  returns the number of steps (0 when the table's stream rows are unset or do not agree, or k0 or the
  rate is out of range: :func:`.c_entry.stream_blocks`).

Any other command does nothing and returns :data:`UNKNOWN_COMMAND`.

A baseline has no step budget and no C caller: this is a numba function (its errors raise in Python
as any kernel's), not a ``cfunc``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import carray, njit

from .c_entry import (CMD_ADVANCE, CMD_PACKED, CMD_TRACK, IO_Q, IO_RATE, T_MODE, T_RULE, TABLE_SIZE, stream_blocks,
                      table_arrays)
from .clock import cycles
from .pointers import address_pointer
from .stepper import baseline_advance, record

__all__ = ["baseline_entry", "UNKNOWN_COMMAND"]

#: What :func:`baseline_entry` returns for a command it does not know (nothing done).
UNKNOWN_COMMAND = -3


@njit(cache=True)
def baseline_entry(table_address, cmd, t, h):
    """The baseline's step (module doc): ``table_address`` of a :func:`.c_entry.make_table` table (int64),
    ``cmd`` a command code, ``t`` the time step (s; NaN: unknown); ``h`` is unused (no budget)."""
    tb = carray(address_pointer(table_address), (TABLE_SIZE,), np.int64)
    a, pk, model, s2s, params, out_real, out_int, io = table_arrays(tb)
    kind, rule = tb[T_MODE], tb[T_RULE]
    q = io[IO_Q:IO_Q + 3]
    packed = cmd == CMD_PACKED
    if cmd == CMD_ADVANCE or cmd == CMD_PACKED:
        dt = t if cmd == CMD_ADVANCE else math.nan
        return baseline_advance(kind, rule, q, dt, a, pk, model, s2s, params, out_real, out_int, packed)
    if cmd != CMD_TRACK:
        return UNKNOWN_COMMAND
    k0, qs, floats, ints, bools = stream_blocks(tb, io)
    n = qs.shape[0]
    rate = io[IO_RATE]
    for k in range(k0, n):
        for i in range(3):
            q[i] = qs[k, i]
        c0 = cycles()
        since = baseline_advance(kind, rule, q, math.nan, a, pk, model, s2s, params, out_real, out_int, packed)
        c1 = cycles()
        record(k, out_real, out_int, since, False, c0, c1, rate, floats, ints, bools)
    return max(n - k0, 0)
