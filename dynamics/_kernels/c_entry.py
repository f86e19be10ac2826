"""The plant's and the controller's communication steps as C entry points: what the FMUs' loader calls.

:func:`plant_entry` and :func:`controller_entry` are numba ``cfunc`` s of C signature ``int64 step(int64
*table, int64 cmd, double t, double h)`` (the signature of :mod:`solver._kernels.c_entry`, which the
loader's fast lane calls; ``cmd`` is :data:`CMD_PUBLISH`).  The table holds the addresses and sizes
of the stepper's arrays (rows ``T_*``, 4 int64 each) and its posture bits; the inputs are read from
the caller's Real value array at ``slots[:n_in]`` and the outputs written at ``slots[n_in:]``.
A step that the compiled step refuses, or whose inputs, times or outputs are not finite, changes
nothing and returns :data:`FALL_BACK`: the caller takes it on its Python path, which refuses it with
the reason; a step taken returns :data:`PUBLISHED`.

- plant: inputs tau1..tau3 (N m); ``n = io[IO_SUBSTEPS]`` RK4 steps of ``h / n`` from the state
  ``x`` (6,), written back into ``x`` when the step is taken; outputs q1..q3, dq1..dq3, x_true, y_true,
  phi_true, energy (the order of :data:`PLANT_SLOTS`).
- controller: inputs q1..q3, dq1..dq3, x, y, phi at time ``t``; outputs tau1..tau3, the reference pose
  and joints (:data:`CONTROLLER_SLOTS`).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import carray, cfunc, njit, types

from solver._kernels.pointers import address_pointer

from .layout import PLANT_OUT_DQ, PLANT_OUT_ENERGY, PLANT_OUT_Q, PLANT_OUT_STATE
from .steps import controller_step, plant_step

__all__ = ["plant_entry", "controller_entry", "make_table", "PLANT_SLOTS", "CONTROLLER_SLOTS", "CMD_PUBLISH",
           "FALL_BACK", "PUBLISHED", "IO_SIZE", "IO_TIME", "IO_STEPS", "IO_SUBSTEPS", "IO_TOL"]

CMD_PUBLISH = 2                      # the loader's LANE_CMD_PUBLISH (solver._kernels.c_entry.CMD_PUBLISH)
FALL_BACK, PUBLISHED = 1, 2          # solver._kernels.c_entry's (the loader's LANE_PUBLISHED)
T_PACK, T_WORK, T_X, T_OUT, T_IO, T_REAL, T_SLOTS = range(7)
T_BITS = 28
TABLE_SIZE = 29
IO_TIME, IO_STEPS, IO_SUBSTEPS, IO_TOL = 0, 1, 2, 3       # out: t + h, steps taken; in: substeps, tolerance
IO_SIZE = 4

PLANT_SLOTS = ("tau1", "tau2", "tau3", "q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true", "energy")
CONTROLLER_SLOTS = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi", "tau1", "tau2", "tau3", "x_ref", "y_ref",
                    "phi_ref_out", "q1_ref", "q2_ref", "q3_ref")
#: where each plant output (after its 3 inputs) is in the compiled step's output array
_PLANT_FROM = (PLANT_OUT_Q, PLANT_OUT_Q + 1, PLANT_OUT_Q + 2, PLANT_OUT_DQ, PLANT_OUT_DQ + 1, PLANT_OUT_DQ + 2,
               PLANT_OUT_STATE, PLANT_OUT_STATE + 1, PLANT_OUT_STATE + 2, PLANT_OUT_ENERGY)
_SIGNATURE = types.int64(types.voidptr, types.int64, types.float64, types.float64)


@njit(cache=False)                  # compiled into the entry points only
def _view(tb, row):
    return carray(address_pointer(tb[4 * row]), (tb[4 * row + 1],), np.float64)


def _plant(table, cmd, t, h):
    tb = carray(table, (TABLE_SIZE,), np.int64)
    pack, work, x, out, io, real = (_view(tb, T_PACK), _view(tb, T_WORK), _view(tb, T_X), _view(tb, T_OUT),
                                    _view(tb, T_IO), _view(tb, T_REAL))
    slots = carray(address_pointer(tb[4 * T_SLOTS]), (tb[4 * T_SLOTS + 1],), np.int64)
    if cmd != CMD_PUBLISH or not (math.isfinite(t) and math.isfinite(h) and h >= 0.0):
        return FALL_BACK
    tau1, tau2, tau3 = real[slots[0]], real[slots[1]], real[slots[2]]
    if not (math.isfinite(tau1) and math.isfinite(tau2) and math.isfinite(tau3)):
        return FALL_BACK
    n = int(io[IO_SUBSTEPS])
    if plant_step(pack, tb[T_BITS], tau1, tau2, tau3, h / n, n, x, out, work) != 0:
        return FALL_BACK
    for i in range(out.size):
        if not math.isfinite(out[i]):
            return FALL_BACK
    for i in range(6):
        x[i] = out[PLANT_OUT_STATE + i]
    for i in range(len(_PLANT_FROM)):
        real[slots[3 + i]] = out[_PLANT_FROM[i]]
    io[IO_TIME] = t + h
    io[IO_STEPS] += 1.0
    return PUBLISHED


def _controller(table, cmd, t, h):
    tb = carray(table, (TABLE_SIZE,), np.int64)
    pack, work, out, io, real = (_view(tb, T_PACK), _view(tb, T_WORK), _view(tb, T_OUT), _view(tb, T_IO),
                                 _view(tb, T_REAL))
    slots = carray(address_pointer(tb[4 * T_SLOTS]), (tb[4 * T_SLOTS + 1],), np.int64)
    if cmd != CMD_PUBLISH or not (math.isfinite(t) and math.isfinite(h) and h >= 0.0):
        return FALL_BACK
    for i in range(9):
        if not math.isfinite(real[slots[i]]):
            return FALL_BACK
    code = controller_step(pack, tb[T_BITS], t, real[slots[0]], real[slots[1]], real[slots[2]], real[slots[3]],
                           real[slots[4]], real[slots[5]], real[slots[6]], real[slots[7]], real[slots[8]],
                           io[IO_TOL], out, work)
    if code != 0:
        return FALL_BACK
    for i in range(9):
        if not math.isfinite(out[i]):
            return FALL_BACK
    for i in range(9):
        real[slots[9 + i]] = out[i]
    io[IO_TIME] = t + h
    io[IO_STEPS] += 1.0
    return PUBLISHED


@lru_cache(maxsize=None)
def plant_entry():
    """The plant's C entry point (numba ``CFunc``, cached on disk; made on first use)."""
    return cfunc(_SIGNATURE, cache=True, error_model="numpy")(_plant)


@lru_cache(maxsize=None)
def controller_entry():
    """The controller's C entry point (numba ``CFunc``, cached on disk; made on first use)."""
    return cfunc(_SIGNATURE, cache=True, error_model="numpy")(_controller)


def make_table(bits: int, pack, work, out, io, real, slots, x=None) -> np.ndarray:
    """The table (TABLE_SIZE,) int64 of an entry point over these arrays (float64, C-contiguous, kept
    alive by the caller; ``slots`` int64; ``x`` the plant's state (6,))."""
    table = np.zeros(TABLE_SIZE, dtype=np.int64)
    rows = ((T_PACK, pack), (T_WORK, work), (T_X, x), (T_OUT, out), (T_IO, io), (T_REAL, real), (T_SLOTS, slots))
    for row, array in rows:
        if array is None:
            continue
        want = np.int64 if row == T_SLOTS else np.float64
        if not (isinstance(array, np.ndarray) and array.dtype == want and array.ndim == 1
                and array.flags.c_contiguous and array.flags.writeable):
            raise ValueError(f"entry table row {row}: expected a writable C-contiguous 1-D {np.dtype(want)} array")
        table[4 * row], table[4 * row + 1] = array.ctypes.data, array.size
    table[T_BITS] = int(bits)
    return table
