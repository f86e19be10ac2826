"""The DK slave's fast lane: its step and outputs served by the C loader without the interpreter.

Part of the FMU runtime (bundled): the mixin :class:`DKLane` of ``RRRDirectKinematics`` (and its
subclasses), on :class:`fmu_src.table_lane.TableLane`.  At the end of a successful initialization the slave builds a
:class:`fmu_src.fast_lane.FastLane` over its variables, connects it to its tracker's compiled step
(:meth:`solver.Tracker.c_step`: the joints read from the lane's arrays, the outputs written there,
the tracker's flat state advanced in place) and hands it to the loader.  From then on a routine
``fmi2SetReal(q)`` / ``fmi2DoStep`` / ``fmi2Get*`` never enters Python; anything else does, and
sees the same state:

- in a pull (before a call the loader forwards, if the lane changed anything), after lane steps:
  the tracker's snapshot (``_track``), the uncertain episode (``_since``) and the committed outputs,
  as ``step`` leaves them;
- in a push (after it): the tracker's flat state made the committed one (a tentative ``evaluate``
  moved it), the scalars of the compiled step (episode, budget) and whether the lane may serve: a
  tracker without the Python-only watches (stuck-joint detector, encoder-grid watch, joint limits).

A lane step that is not routine (its status differs from the logged episode's: unreachable,
singular, rejected, or back to ok; an output not finite; joints not finite) undoes itself and the
loader forwards the doStep to Python, which takes the same step and logs or refuses it.
"""
from __future__ import annotations

import math

import numpy as np

from . import kernel_locator

kernel_locator.install()    # before the first import of solver: its kernels find the FMU's shipped cache

from solver._kernels.c_entry import (IO_DONE, IO_EPISODE, IO_LAST_H, IO_LAST_Q, IO_NO_BOUND, IO_RATE,  # noqa: E402
                                     IO_SHARE, IO_SINCE_STEP, IO_SINCE_TIME, IO_STEPS, IO_TIME, SLOTS)
from solver._kernels.clock import cycles_per_second  # noqa: E402

from .dk_variables import NO_BOUND  # noqa: E402
from .table_lane import TableLane  # noqa: E402

__all__ = ["DKLane"]


class DKLane(TableLane):
    """Mixin: the fast lane of a DK slave (module doc).  Needs ``_tracker``, ``_track``, ``_since``,
    ``_episode``, ``_committed``, ``_cache``, ``JOINTS`` and the table slave's attributes."""


    def _dk_lane_connect(self) -> None:
        """Give the loader (if the slave runs behind it) a lane on the current tracker; reconnect it
        when the tracker was rebuilt (set_state of other parameters)."""
        if not self._lane_wanted() or self._tracker is None:
            return
        try:
            lane = self._lane_made()
            slots = self._lane_slots()
            step, table = self._tracker.c_step(lane.real, lane.integer, lane.boolean, slots)
            self._lane_connect(step, table, self._tracker.c_io, IO_TIME, IO_STEPS, slots)
        except Exception as exc:  # noqa: BLE001 - no lane: every call on the Python path, as before
            self._lane_failed(exc)

    def _lane_slots(self) -> np.ndarray:
        # the compiled step's slots: this slave's joint inputs (a subclass may rename them), then the outputs
        return np.array([self.VR[name] for name in (*self.JOINTS, *SLOTS[3:])], dtype=np.int64)

    def _lane_ready(self) -> bool:
        tracker = self._tracker
        if tracker is None or self._track is None:
            return False
        tracker.restore(self._track)               # the committed state (free when it still is)
        return tracker.c_ready()

    def _lane_after_steps(self) -> None:
        tracker = self._tracker
        io = tracker.c_io
        tracker.flat_advanced()
        self._track = tracker.snapshot()
        since = io[IO_SINCE_STEP]
        self._since = None if math.isnan(since) else (int(since), float(io[IO_SINCE_TIME]))
        # the joints of the last lane step (the compiled step kept them; the inputs may already hold
        # the next sample) and its outputs, which the arrays still hold
        self._committed = (tuple(io[IO_LAST_Q:IO_LAST_Q + 3].tolist()), self._outputs())
        self._cache = None
        # the budget of that step, as step() leaves it (what a tentative evaluate() then has)
        share, h = float(self.step_budget_share), float(io[IO_LAST_H])
        tracker.step_budget = share * h if share > 0.0 and h > 0.0 else None

    def _lane_checked(self, io) -> None:
        if io[IO_DONE] != 1.0:              # a compiled kernel raised: the flat state is not the committed one
            self._tracker.flat_advanced()    # (restore(_track) copies it back before any step)
            io[IO_DONE] = 1.0

    def _lane_before_steps(self) -> None:
        io = self._tracker.c_io
        share = float(self.step_budget_share)
        io[IO_SHARE] = share
        io[IO_RATE] = cycles_per_second() if share > 0.0 else 0.0
        io[IO_EPISODE] = self._episode
        io[IO_SINCE_STEP], io[IO_SINCE_TIME] = (math.nan, math.nan) if self._since is None else self._since
        io[IO_NO_BOUND] = NO_BOUND
