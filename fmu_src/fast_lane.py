"""The slave's side of the C loader's fast lane: its variables as arrays the loader reads and writes.

Part of the FMU runtime (bundled into every FMU): numpy and ctypes only.  The loader
(``fmu_src/loader/fast_lane.h``, which this module's :class:`LaneStruct` mirrors) answers the hot
calls of a step on these arrays without entering the interpreter: ``fmi2SetReal`` of the inputs,
``fmi2Get*`` of any variable, and ``fmi2DoStep`` through a compiled step (a numba ``cfunc`` whose
address and table the slave gives, :mod:`solver._kernels.c_entry`).  Every other call still goes to
Python, and the two sides meet at its border: before it, the loader calls :meth:`FastLane.pull`'s
owner (the slave reads what the lane changed), after it the owner's push (the slave writes its
attributes and says whether the lane may serve, ``enabled``).

A slave uses it in three steps (``fmu_src/RRRDirectKinematics.py``)::

    lane = FastLane(type(self)._table, pull=self._lane_pull, push=self._lane_push)
    lane.connect(step_address, table)         # the compiled step and its table
    self.log(lane.hand_over(), category=LANE_CATEGORY)   # the loader takes the lane from the logger

The FMI 3.0 loader serves the same arrays by FMI 3.0 value reference: an FMI 3.0 variable made of
consecutive core variables (an array, ``fmu_src/fmi3_adapter.py``) is read and set there in one
piece (:meth:`FastLane.map3`).

Set ``RRR_DK_FAST_LANE=0`` in the host's environment to keep every call on the Python path (the
reference the lane is tested against).
"""
from __future__ import annotations

import ctypes
import os

import numpy as np

from .fmi_states import behind_loader

__all__ = ["FastLane", "LaneStruct", "LANE_CATEGORY", "VERSION", "available"]

#: the logger category of the hand-over (the loader's LANE_CATEGORY)
LANE_CATEGORY = "rrrdkFastLane"
#: the layout version of :class:`LaneStruct` (the loader's LANE_VERSION)
VERSION = 2
REAL, INTEGER, BOOLEAN, SET, OUTPUT, DIRTIES = 1, 2, 4, 8, 16, 32
_TYPE_BIT = {"Real": REAL, "Integer": INTEGER, "Boolean": BOOLEAN}


class LaneStruct(ctypes.Structure):
    """The loader's ``Lane`` (fast_lane.h), field for field."""

    _fields_ = [("version", ctypes.c_int64), ("enabled", ctypes.c_int64), ("py_stale", ctypes.c_int64),
                ("dirty", ctypes.c_int64), ("n_vr", ctypes.c_int64), ("real", ctypes.c_void_p),
                ("integer", ctypes.c_void_p), ("boolean", ctypes.c_void_p), ("flags", ctypes.c_void_p),
                ("step", ctypes.c_void_p), ("table", ctypes.c_void_p), ("pull", ctypes.c_void_p),
                ("push", ctypes.c_void_p), ("fast_steps", ctypes.c_int64), ("fast_calls", ctypes.c_int64),
                ("n_vr3", ctypes.c_int64), ("first3", ctypes.c_void_p), ("count3", ctypes.c_void_p)]


def available(resources) -> bool:
    """Whether an instance of the FMU whose ``resources`` folder this is can have a lane: behind the
    project's FMI 2.0 or FMI 3.0 loader (:func:`fmu_src.fmi_states.behind_loader`), and
    ``RRR_DK_FAST_LANE`` is not ``0``."""
    if os.environ.get("RRR_DK_FAST_LANE", "1").strip() == "0":
        return False
    return behind_loader(resources)


class FastLane:
    """A slave's variables as three arrays by value reference, and the :class:`LaneStruct` that points at them.

    Parameters
    ----------
    table : sequence of fmu_src.variables.Var
        The slave's variable table (value reference = row).
    pull, push : callable
        The slave's methods the loader calls before and after a call it forwards to Python (kept
        alive here: the loader holds their addresses).
    marks_dirty : set of int
        Value references whose set makes the outputs of direct feedthrough stale.
    """

    def __init__(self, table, pull, push, marks_dirty=frozenset()):
        n = len(table)
        self.real = np.zeros(n)
        self.integer = np.zeros(n, dtype=np.int32)
        self.boolean = np.zeros(n, dtype=np.int32)
        self.flags = np.zeros(n, dtype=np.uint8)
        for vr, v in enumerate(table):
            bits = _TYPE_BIT.get(v.type, 0)
            if v.causality == "input" and v.type == "Real":
                bits |= SET
            if v.is_output and v.depends_on:      # direct feedthrough: stale once an input is set
                bits |= OUTPUT
            if vr in marks_dirty:                 # its set makes them stale (the slave's _marks_dirty)
                bits |= DIRTIES
            self.flags[vr] = bits
        self._attrs = [(vr, v.attr, v.type) for vr, v in enumerate(table) if v.type in _TYPE_BIT]
        self._read = [(vr, v.attr, v.type) for vr, v in enumerate(table)
                      if v.type in _TYPE_BIT and (v.is_output or v.causality == "input")]
        self._methods = (pull, push)
        self._table = None
        self.closed = False                   # the slave closed it after an error: never enabled again
        self.handed = False                   # handed to the loader (once per instance)
        self.struct = LaneStruct(version=VERSION, n_vr=n, real=self.real.ctypes.data,
                                 integer=self.integer.ctypes.data, boolean=self.boolean.ctypes.data,
                                 flags=self.flags.ctypes.data, pull=id(pull), push=id(push))

    @property
    def address(self) -> int:
        """The address of :attr:`struct` (what the loader is handed)."""
        return ctypes.addressof(self.struct)

    def hand_over(self) -> str:
        """The hand-over message (the lane's address) for the logger category :data:`LANE_CATEGORY`."""
        return hex(self.address)

    def connect(self, step: int, table: np.ndarray) -> None:
        """The compiled step (C address) and its table (int64 array, kept alive here)."""
        self._table = table
        self.struct.step = step
        self.struct.table = table.ctypes.data

    def map3(self, first: np.ndarray, count: np.ndarray) -> None:
        """The FMI 3.0 value references over the lane's: FMI 3.0 value reference k is the lane's
        ``first[k] .. first[k] + count[k] - 1`` (``first[k]`` < 0: not served by the lane).

        Parameters
        ----------
        first, count : array_like of int, shape (n_vr3,)
        """
        first, count = np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(count, dtype=np.int64)
        n = len(self.flags)
        if first.shape != count.shape or first.ndim != 1 or np.any((first >= 0) & ((count <= 0) | (first + count > n))):
            raise ValueError(f"map3: expected first and count (n,) int within the lane's {n} value references, got "
                             f"{first.tolist()} and {count.tolist()}")
        self._map3 = (first, count)            # kept alive: the loader reads them
        self.struct.n_vr3 = len(first)
        self.struct.first3 = first.ctypes.data
        self.struct.count3 = count.ctypes.data

    def write(self, slave) -> None:
        """The slave's variables into the arrays (a push)."""
        real, integer, boolean = self.real, self.integer, self.boolean
        for vr, attr, kind in self._attrs:
            value = getattr(slave, attr)
            if kind == "Real":
                real[vr] = value
            elif kind == "Integer":
                integer[vr] = value
            else:
                boolean[vr] = 1 if value else 0

    def read(self, slave) -> None:
        """The inputs and outputs from the arrays into the slave's attributes (a pull)."""
        real, integer, boolean = self.real.tolist(), self.integer.tolist(), self.boolean.tolist()
        for vr, attr, kind in self._read:
            if kind == "Real":
                setattr(slave, attr, real[vr])
            elif kind == "Integer":
                setattr(slave, attr, integer[vr])
            else:
                setattr(slave, attr, boolean[vr] != 0)
