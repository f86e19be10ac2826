"""The tracker's step through its compiled C entry point (:mod:`solver._kernels.c_entry`): the mixin
:class:`CEntry` of :class:`solver.Tracker`.

Every step of a tracker is one call of the same machine code: in process through
:func:`solver._kernels.entry_call.call_entry` (the joints written into the tracker's scalars ``io``,
the time step and the deadline passed as the call's two doubles: one numba dispatch of five scalars
instead of a 17-argument one, 0.3 us quicker than ctypes), a whole stream of
:meth:`solver.Tracker.track` in one call through ctypes, and from a C caller (the DK FMU's loader)
directly, on the same flat state.  Both Python calls release the GIL.  The table that the entry
point reads holds the addresses of the tracker's arrays, which live as long as the tracker.
"""
from __future__ import annotations

import numpy as np

from ._kernels.anytime import ANY_DEADLINE, ANY_K_ON, ANY_N, ANY_R_ON
from ._kernels.c_entry import (ADVANCE_OFFSET, CMD_ADVANCE, CMD_PACKED, CMD_TRACK, IO_BUDGET, IO_DEADLINE, IO_DONE,
                               IO_SIZE, entry, make_table, set_rows)
from ._kernels.clock import cycles_per_second
from ._kernels.entry_call import SIGNATURE, call_entry
from .tracker_state import TrackerError
from ._kernels.state_layout import STATE_FLOATS

__all__ = ["CEntry"]


class CEntry:
    """Mixin of :class:`solver.Tracker`: its compiled step through the C entry point (module doc)."""

    def _entry_table(self) -> None:
        """The entry point's table over the tracker's arrays (made once, at construction)."""
        self._io = np.zeros(IO_SIZE)
        self._q_in = self._io[:3]               # the step's joints (``q_in[...] = q``: the quickest copy in)
        self._table = make_table(self._mode, self._rule, dict(
            a=self._flat, pk=self._state_pack, model=self._model_pack, s2s=self._sample_to_sextic, labels=self._labels,
            map=self._map_pack, stencil=self._stencil, params=self._params, out_real=self._out_real,
            out_int=self._out_int, anytime=self._anytime, io=self._io))
        self._table_address = self._table.ctypes.data
        self._call = None                       # entry().ctypes, for a stream, and
        self._fn = 0                            # entry().address, for a step: both made by _entry() when _fn is 0

    def _kernel(self, q, deadline):
        anytime, walk = self._anytime, self.state.walk
        if walk is None:
            anytime[ANY_N] = anytime[ANY_K_ON] = anytime[ANY_R_ON] = 0.0
        else:
            anytime[:len(walk)] = walk
        anytime[ANY_DEADLINE] = deadline
        self._q_in[...] = q
        self._io[IO_DEADLINE] = deadline
        call_entry(self._fn or self._entry(), self._table_address, CMD_PACKED, 0.0, 0.0)
        if self._io[IO_DONE] != 1.0:
            self._failed()

    def _advance(self, q, dt, deadline, a):
        self._q_in[...] = q
        r = call_entry(self._fn or self._entry(), self._table_address, CMD_ADVANCE, dt, deadline)
        if r <= 0:                              # 0: a kernel raised (the cfunc's answer then)
            self._failed()
        return r - ADVANCE_OFFSET

    def _loop(self, table):
        """The stream of ``table`` in one call of the entry point (``CMD_TRACK``), each step with the
        tracker's step budget (none without one).  The call releases the GIL: another thread may run
        meanwhile, but not on this tracker (a tracker is one thread's)."""
        self._io[IO_BUDGET] = 0.0 if self.step_budget is None else self.step_budget * cycles_per_second()
        if not self._fn:
            self._entry()
        steps = self._call(table.ctypes.data, CMD_TRACK, 0.0, 0.0)
        if self._io[IO_DONE] != 1.0:
            self._failed()
        return steps

    def _failed(self):
        """A compiled kernel raised inside the entry point (numba printed it): the step's data is not
        to be trusted; the tracker starts again only from reset()."""
        self._st, self._live, self._held = None, False, None
        raise TrackerError(f"{self.name}: the compiled step failed (its error is printed above); the tracker's "
                           "state is discarded: call reset(X0, q0)")

    def c_step(self, real, integer, boolean, slots):
        """The compiled step for a C caller that publishes steps into value arrays (the DK FMU's loader):
        ``(address, table)`` of :func:`solver._kernels.c_entry.entry` with command ``CMD_PUBLISH``, which
        reads the joints at ``real[slots[0:3]]`` and writes the outputs at the other ``slots``
        (``c_entry.SLOTS``; ``real`` float64, ``integer`` and ``boolean`` int32, by value reference).
        The caller keeps the arrays alive, sets ``io`` (:attr:`c_io`) and steps only when
        :meth:`c_ready` (no stuck-joint detector, encoder-grid watch or joint limits in Python)."""
        self._backup = np.empty(STATE_FLOATS)
        table = self._table.copy()
        set_rows(table, dict(backup=self._backup, real=real, integer=integer, boolean=boolean, slots=slots))
        return self._fn or self._entry(), table

    @property
    def c_io(self) -> np.ndarray:
        """The scalars a C call reads and writes (float64 (IO_SIZE,), ``c_entry.IO_*``)."""
        return self._io

    def c_ready(self) -> bool:
        """Whether a C caller may step now: the live flat state is the whole step (made live here)."""
        if self._watch or self.stuck_after or self._objects or self._limits is not None:
            return False
        self._flat_state()
        return True

    def _entry(self) -> int:
        """Load the C entry point (:func:`solver._kernels.c_entry.entry`) once: its address ``_fn``, which a
        step calls through :func:`solver._kernels.entry_call.call_entry` (one numba dispatch, compiled or
        loaded here, where a DK FMU's lane connects: its build ships it), and its ctypes function
        ``_call``, which a stream calls; returns the address."""
        f = entry()
        call_entry.compile(SIGNATURE.args)      # loaded from the cache (an FMU's shipped kernels) once built
        self._call, self._fn = f.ctypes, f.address
        return self._fn
