"""A table slave's fast lane: the loader answers the hot calls on arrays the slave shares.

Part of the FMU runtime (bundled): the mixin :class:`TableLane` of the slaves that have one (the DK
FMU, :mod:`fmu_src.dk_lane`; the plant and the controller).  The loader's side and the lane's arrays
are :mod:`fmu_src.fast_lane`.  A slave connects a lane at the end of a successful initialization with
the C address of its compiled step and the step's table (:meth:`TableLane._lane_connect`); the step
reads the inputs from the lane's Real array and writes the outputs there (the slots of the slave's
``LANE_SLOTS``, variable names in the compiled step's order) and keeps its time and step count in a
float64 array ``io`` the slave gives (at ``io_time``, ``io_steps``).  From then on the loader calls:

- :meth:`TableLane._lane_pull` before a call it forwards to Python, when the lane changed values: the
  inputs and outputs into the attributes and, after lane steps, the time and what the slave keeps
  besides (:meth:`_lane_after_steps`);
- :meth:`TableLane._lane_push` after it: the attributes into the arrays, the slave's own state
  (:meth:`_lane_before_steps`) and whether the lane may serve (state stepComplete, initialized, not
  closed, :meth:`_lane_ready`).

``RRR_DK_FAST_LANE=report`` in the host's environment: at fmi2Terminate each instance logs how many
calls its lane answered (also on stderr).  ``0``: no lane.

Nothing here raises into the host: an exception closes the lane (every call then goes to Python), and
one in a pull, which leaves the slave behind the lane's steps, makes the instance refuse further steps
with the reason.
"""
from __future__ import annotations

import os

import numpy as np
from pythonfmu.enums import Fmi2Status

from .fast_lane import LANE_CATEGORY, FastLane, available
from .fmi_states import STEP_COMPLETE

__all__ = ["TableLane"]


class TableLane:
    """Mixin of a :class:`fmu_src.table_slave.TableSlave` with a fast lane (module doc)."""

    #: the slave's variables in the order of its compiled step's slots
    LANE_SLOTS: tuple = ()
    _lane = None
    #: (first, count): the FMI 3.0 value references over this slave's (an FMI 3.0 adapter sets it,
    #: :meth:`fmu_src.fast_lane.FastLane.map3`); None behind the FMI 2.0 loader
    _lane_map3 = None

    def _lane_made(self) -> FastLane:
        """The slave's lane: its value arrays (made on first use, kept for the instance's life)."""
        if self._lane is None:
            cls = type(self)
            lane = FastLane(cls._table, self._lane_pull, self._lane_push, cls._marks_dirty)
            if self._lane_map3 is not None:
                lane.map3(*self._lane_map3)
            self._lane = lane
        return self._lane

    def _lane_connect(self, step: int, table: np.ndarray, io: np.ndarray, io_time: int, io_steps: int,
                      slots: np.ndarray) -> None:
        """Connect the lane to the compiled step ``step`` (C address) and its ``table`` (the arrays it
        points at, ``slots`` and ``io``, are kept alive here) and hand it to the loader the first time;
        a later call reconnects it (a new tracker after set_state)."""
        lane = self._lane_made()
        self._lane_io = (io, io_time, io_steps, slots)
        lane.connect(step, table)
        if not lane.handed:
            lane.handed = True
            self.log(lane.hand_over(), Fmi2Status.ok, category=LANE_CATEGORY)

    def _lane_wanted(self) -> bool:
        """Whether this instance runs behind the project's loader and may have a lane; also in the kernel
        warm-up's child (``RRR_DK_FAST_LANE=warm-up``, :func:`fmu_src.kernel_warmup.replay`), which makes
        the lane without a loader so that the compiled steps it calls are compiled there, never on a
        host's thread."""
        if os.environ.get("RRR_DK_FAST_LANE", "").strip() == "warm-up":
            return True
        return bool(self._loader) and available(self.resources)

    def _lane_slots(self) -> np.ndarray:
        """The value references of :attr:`LANE_SLOTS` (int64)."""
        return np.array([self.VR[name] for name in self.LANE_SLOTS], dtype=np.int64)

    def _lane_failed(self, exc: Exception) -> None:
        """The lane could not be made: every call stays on the Python path (logged)."""
        if self._lane is not None:                   # the loader may hold it: closed, never freed
            self._lane.closed = True
            self._lane.struct.enabled = 0
        self._pylog.warning("instance %r: no fast lane (%s: %s)", self.instance_name, type(exc).__name__, exc)

    # ---------------------------------------------------------------- the loader's calls
    def _lane_pull(self) -> None:
        """What the lane changed, into the slave (the loader calls it before a forwarded call)."""
        try:
            lane = self._lane
            lane.read(self)
            io, io_time, io_steps, _ = self._lane_io
            self._lane_checked(io)
            if io[io_steps]:
                io[io_steps] = 0.0
                self._time = float(io[io_time])
                self._lane_after_steps()
            self._dirty = bool(lane.struct.dirty)
            lane.struct.py_stale = 0
        except BaseException as exc:  # noqa: BLE001 - never into the host: the lane closes
            self._lane_close(exc)

    def _lane_push(self) -> None:
        """The slave's state into the lane, and whether it may serve (after a forwarded call)."""
        try:
            lane = self._lane
            s = lane.struct
            ok = (self._fmi_state == STEP_COMPLETE and not self._broken and not self._init_error
                  and not lane.closed and self._lane_ready())
            if ok:
                lane.write(self)
                io, _, io_steps, _ = self._lane_io
                io[io_steps] = 0.0
                self._lane_before_steps()
                s.dirty = int(bool(self._dirty))
            s.enabled = int(ok)
            s.py_stale = 0
        except BaseException as exc:  # noqa: BLE001 - never into the host: the lane closes
            self._lane_close(exc)

    def _lane_close(self, exc: Exception) -> None:
        """A pull or push raised: the lane closes for good, said in the FMU's log (a warning; an error when
        the slave could not read the lane's steps, which makes the instance unusable)."""
        lane = self._lane
        lane.closed = True
        lane.struct.enabled = 0
        broken = bool(lane.struct.py_stale)
        if broken:
            self._broken = f"fast lane: the slave could not read the lane's state ({type(exc).__name__}: {exc})"
        self._report(f"instance {self.instance_name!r}: fast lane closed ({type(exc).__name__}: {exc}); every "
                     "call goes through Python", Fmi2Status.error if broken else Fmi2Status.warning)

    # ---------------------------------------------------------------- hooks (a slave overrides them)
    def _lane_checked(self, io) -> None:
        """In a pull, before anything else: a compiled step that raised (its state unspecified)."""

    def _lane_ready(self) -> bool:
        """Whether the compiled step is the whole step now (besides the state and the flags)."""
        return True

    def _lane_after_steps(self) -> None:
        """After lane steps: the slave's own state from the step's arrays (in a pull)."""

    def _lane_before_steps(self) -> None:
        """Before lane steps: the slave's own state into the step's arrays (in a push)."""

    def terminate(self):
        super().terminate()
        if self._lane is not None and os.environ.get("RRR_DK_FAST_LANE", "").strip() == "report":
            steps, calls = self.lane_counts
            msg = f"instance {self.instance_name!r}: the fast lane answered {steps} doSteps and {calls} get/set calls"
            self.log(msg.replace("%", "%%"), Fmi2Status.ok)     # the wrapper's text is a printf format
            self._pylog.warning("%s", msg)              # stderr: a host without a logger shows it too

    @property
    def lane_counts(self) -> tuple[int, int]:
        """(doSteps, get/set calls) the loader's fast lane answered ((0, 0) without a lane)."""
        s = None if self._lane is None else self._lane.struct
        return (0, 0) if s is None else (int(s.fast_steps), int(s.fast_calls))
