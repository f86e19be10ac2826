"""A C entry point called through one numba dispatch (:mod:`solver._kernels.entry_call`): the arguments
reach the C function in order, its answer comes back, the GIL is released around it as ctypes does, and a
tracker's step through it is the step through ctypes, bit for bit."""
from __future__ import annotations

import copy
import ctypes
import sys
import threading

import numpy as np
import pytest
from numba import carray, cfunc, types
from numba.core.errors import TypingError

from solver import Manipulator, Tracker, cached_map, circle_path, ik
from solver._kernels.c_entry import ADVANCE_OFFSET, CMD_ADVANCE
from solver._kernels.entry_call import call_entry

_SIG = types.int64(types.voidptr, types.int64, types.float64, types.float64)

_gil_held = ctypes.pythonapi.PyGILState_Check
_gil_held.restype, _gil_held.argtypes = ctypes.c_int, []


@cfunc(_SIG)
def _echo(table, cmd, t, h):
    """Writes what it received into the table (int64 (4,)) and answers 1000 cmd + table[0]."""
    tb = carray(table, (4,), np.int64)
    first = tb[0]
    tb[1], tb[2], tb[3] = cmd, int(t * 1000.0), int(h * 1000.0)
    return 1000 * cmd + first


@cfunc(_SIG)
def _gil_state(table, cmd, t, h):
    """1 when the calling thread holds the GIL, 0 when it does not."""
    return _gil_held()


@cfunc(_SIG)
def _raises(table, cmd, t, h):
    """A kernel that raises (numba reports the error through sys.unraisablehook; the C function answers 0)."""
    if cmd > 0:
        raise ValueError("a kernel raised")
    return 5


def test_call_entry_hands_its_arguments_to_the_c_function_in_order_and_returns_its_answer():
    table = np.array([7, 0, 0, 0], dtype=np.int64)
    r = call_entry(_echo.address, table.ctypes.data, 3, 0.25, 1.5)
    assert r == 3007
    assert table.tolist() == [7, 3, 250, 1500]
    # the same function through ctypes answers the same
    assert _echo.ctypes(table.ctypes.data, 4, 0.0, 0.0) == 4007


def test_call_entry_releases_the_gil_around_the_call_as_ctypes_does():
    assert _gil_held() == 1                                 # here, in Python, we hold it
    assert call_entry(_gil_state.address, 0, 0, 0.0, 0.0) == 0
    assert _gil_state.ctypes(None, 0, 0.0, 0.0) == 0


def test_call_entry_has_one_signature_other_argument_types_are_refused_not_compiled():
    table = np.zeros(4, dtype=np.int64)
    with pytest.raises(TypingError, match="expected \\(int64, int64, int64, float64, float64\\)"):
        call_entry(_echo.address, table.ctypes.data, 3, 1, 0.0)          # an int for t
    assert len(call_entry.signatures) == 1


def test_a_kernel_that_raises_inside_the_call_answers_0_from_a_worker_thread_and_python_lives_on(monkeypatch):
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))   # where numba reports it
    answers = []
    worker = threading.Thread(target=lambda: answers.append(
        (call_entry(_raises.address, 0, 1, 0.0, 0.0), call_entry(_raises.address, 0, 0, 0.0, 0.0))))
    worker.start()
    worker.join()
    assert answers == [(0, 5)]                              # the error's answer, then a normal call
    assert [str(e) for e in seen] == ["a kernel raised"]    # reported, the GIL taken back to do so


def test_a_tracker_step_through_call_entry_is_the_step_through_ctypes_bit_for_bit():
    model = Manipulator.paper()
    X = circle_path(60)
    q = ik(model, X, 1)
    a = Tracker(model, cached_map(model, 1), start_tolerance=(1e-9, 1e-9, 1e-9))
    a.reset(X[0], q[0])
    b = copy.deepcopy(a)                                    # its own arrays, table and entry
    assert b._fn == 0                                       # a copy looks its entry's address up anew
    dt = 1e-3                                               # a time step: the call's t, which a swap would misplace
    flat = b._flat_state()
    b._entry()                                              # its ctypes function
    # (steps 1-3 of ``a`` take the TrackerState path, CMD_PACKED: the encoder-grid watch after a reset
    # with exact joints; the others CMD_ADVANCE: both of call_entry's call sites)
    for k in range(1, len(q)):
        Xa, info = a.step(q[k], dt=dt)
        b._q_in[...] = q[k]
        since = b._call(b._table_address, CMD_ADVANCE, dt, 0.0) - ADVANCE_OFFSET
        b.flat_advanced()
        assert since == info.uncertain_since
        assert np.array_equal(b._out_real[:3], Xa)
        assert info.certain
    assert np.array_equal(a._flat_state(), flat, equal_nan=True)     # the whole state after the stream
