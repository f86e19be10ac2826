"""An FMI 3.0 Co-Simulation face for a table slave: the mixin :class:`Fmi3Adapter` (pythonfmu3).

Part of the runtime of the FMI 3.0 FMUs (bundled into them, never into an FMI 2.0 FMU): it imports
the standard library, pythonfmu3 and the table slave it wraps.  The FMI 3.0 slave holds one instance
of an FMI 2.0 :class:`fmu_src.table_slave.TableSlave` class, its *core*, made in process (no FMI 2.0
host): every FMI 3.0 call becomes the core's call of the same meaning, so the two FMUs share the
slave logic, its state and its state table, not a copy::

    class RRRDirectKinematics3(Fmi3Adapter, Fmi3Slave):
        CORE = RRRDirectKinematics
        ROWS = (Row3("time", "Float64", "independent"),
                Row3("q", "Float64", "input", core=("q1", "q2", "q3"), unit="rad"), ...)

A :class:`Row3` is one FMI 3.0 variable, made of one core variable (a scalar) or several (an array
of dimension ``len(core)``, in that order); ``time`` (causality independent, which fmpy's
validation asks for) reads the core's time.  Value references are the row numbers.

What maps to what.  ``fmi3SetFloat64/Int32/Boolean`` set the core's values of the rows' core
variables in one ``set_real``/``set_integer``/``set_boolean`` of the core (its checks, its
staleness of direct-feedthrough outputs, its refusals); ``fmi3Get*`` likewise.  The array values
are taken from the flat list the C wrapper passes: pythonfmu3's own array setter
(``np.reshape(v, newshape=...)``, a keyword numpy 2.4 removed) is never called.  Enter/exit
initialization, doStep, terminate and the FMU state go to the core; the core's log messages are
handed on to pythonfmu3's log queue with their status after every call.  ``do_step`` answers
fmi3OK, fmi3Discard (the core refused the step and rolled it back) or fmi3Error (a doStep the FMI
state table forbids): pythonfmu3's wrapper returns the status it is given.

Where FMI 3.0's state machine differs from the core's FMI 2.0 one, the adapter answers as FMI 3.0
says: a get in Instantiated reads the start values (or the values set), without computing; after a
doStep that returned fmi3Discard the FMU is in the state before the call (StepMode, FMI 3.0 has no
stepFailed), so the core goes back from stepFailed to stepComplete (its state was rolled back).

Statuses.  pythonfmu3's wrapper returns fmi3OK after every other call that does not raise (an
exception is fmi3Fatal).  Behind the project's FMI 3.0 loader (``fmu_src/loader/fmi3_loader.c``, what
the build puts in the FMU's binary on Linux) the core hands its state and the status of each call
over in log category :data:`fmu_src.fmi_states.HAND_OFF_CATEGORY` (passed through here, consumed by
the loader, never shown to the host): a set or get the core refuses, an unknown value reference and
a refused exitInitializationMode return fmi3Error.  Without the loader (no C compiler at build time)
such a call changes nothing and is logged with status fmi3Error, but returns fmi3OK.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pythonfmu3 import Boolean, Float64, Int32
from pythonfmu3.enums import Fmi3Causality, Fmi3Initial, Fmi3Status, Fmi3Variability
from pythonfmu3.fmi3slave import Fmi3StepResult
from pythonfmu3.variables import Dimension

from .fast_lane import LANE_CATEGORY
from .fmi_states import (ERROR, HAND_OFF_CATEGORY, INITIALIZATION_MODE, INSTANTIATED, STEP_COMPLETE, STEP_FAILED,
                         TERMINATED)

__all__ = ["Row3", "Fmi3Adapter", "Fmi3TableError"]

_CORE_TYPE = {"Float64": "Real", "Int32": "Integer", "Boolean": "Boolean"}
_CLASS = {"Float64": Float64, "Int32": Int32, "Boolean": Boolean}
#: FMI 3.0's names of the core's states, and what FMI 3.0 sets in them (the state table's footnotes)
_STATE3 = {INSTANTIATED: "Instantiated", INITIALIZATION_MODE: "InitializationMode", STEP_COMPLETE: "StepMode",
           TERMINATED: "Terminated", ERROR: "Terminated"}
_SETTABLE3 = {"Instantiated": "the variables with initial exact or approx",
              "InitializationMode": "the variables with initial exact and the inputs",
              "StepMode": "the inputs and the tunable parameters"}
#: the core's words for a discarded step (fmu_src.table_slave.TableSlave._refuse), and FMI 3.0's
_DISCARD2 = ("(fmi2Discard,", "now in state stepFailed: fmi2SetFMUstate, fmi2Reset or fmi2Terminate)")
_DISCARD3 = ("(fmi3Discard,", "still in StepMode: set valid inputs and step again, fmi3SetFMUState, fmi3Reset "
             "or fmi3Terminate)")
_OK, _DISCARD, _ERROR = (Fmi3StepResult(status=s) for s in (Fmi3Status.ok, Fmi3Status.discard, Fmi3Status.error))


class Fmi3TableError(ValueError):
    """A row of an FMI 3.0 adapter names no core variable of its type, or breaks a rule of this module."""


@dataclass(frozen=True)
class Row3:
    """One FMI 3.0 variable of an adapter.

    ``core``: the names of the core's variables it is made of (one: a scalar; n > 1: an array of
    dimension n); ``()`` only for ``time`` (causality ``independent``).  Causality, variability,
    initial and start are those of the core variables (``initial``: that of the first; a start
    value in the adapter's ``START`` replaces the core's).  ``unit``:
    the FMI 3.0 unit (an array has one unit; leave it None when its elements differ).
    """

    name: str
    type: str
    causality: str
    core: tuple[str, ...] = ()
    unit: str | None = None
    description: str = ""

    @property
    def size(self) -> int:
        return max(len(self.core), 1)


class Fmi3Adapter:
    """The FMI 3.0 methods of pythonfmu3's ``Fmi3Slave`` answered by a table slave (the module doc)."""

    CORE: ClassVar[type] = None
    ROWS: ClassVar[tuple[Row3, ...]] = ()
    #: start values that differ from the core's, by core variable name
    START: ClassVar[dict] = {}
    #: the host lacks packages the core needs (fmu_src.requirements): the constructor raises it
    MISSING: ClassVar[Exception | None] = None
    # filled by __init_subclass__: FMI 3.0 value reference -> the core's value references
    _core_vrs: ClassVar[dict[int, tuple[int, ...]]] = {}
    _kind_of: ClassVar[dict[int, str]] = {}
    _time_vr: ClassVar[int] = -1
    _lane_map3: ClassVar[tuple] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.CORE is None or not cls.__dict__.get("ROWS"):
            return
        table = {v.name: v for v in cls.CORE._table}
        cls._core_vrs, cls._kind_of = {}, {}
        for vr, row in enumerate(cls.ROWS):
            where = f"{cls.__name__}: row {row.name!r}"
            if row.type not in _CORE_TYPE:
                raise Fmi3TableError(f"{where}: type {row.type!r}; expected one of {sorted(_CORE_TYPE)}")
            if row.causality == "independent":
                if row.type != "Float64" or row.core:
                    raise Fmi3TableError(f"{where}: the independent variable is a Float64 of no core variable")
                cls._time_vr = vr
                continue
            if not row.core:
                raise Fmi3TableError(f"{where}: names no core variable")
            rows = [table.get(name) for name in row.core]
            bad = [n for n, v in zip(row.core, rows) if v is None or v.type != _CORE_TYPE[row.type]]
            bad += [n for n in row.core if n in cls.START and n in table
                    and table[n].causality not in ("input", "parameter")]
            if bad:
                raise Fmi3TableError(f"{where}: {bad} are not {_CORE_TYPE[row.type]} variables of {cls.CORE.__name__}")
            if {(v.causality, v.variability) for v in rows} != {(rows[0].causality, rows[0].variability)}:
                raise Fmi3TableError(f"{where}: its core variables differ in causality or variability")
            cls._core_vrs[vr] = tuple(cls.CORE.VR[name] for name in row.core)
            cls._kind_of[vr] = row.type
        # the core's fast lane, if any, serves an FMI 3.0 variable whose core variables are consecutive
        # (one piece of the lane's arrays): (first core value reference or -1, count) by FMI 3.0 one
        first, count = [-1] * len(cls.ROWS), [0] * len(cls.ROWS)
        for vr, core in cls._core_vrs.items():
            if list(core) == list(range(core[0], core[0] + len(core))):
                first[vr], count[vr] = core[0], len(core)
        cls._lane_map3 = (first, count)

    # ------------------------------------------------------------------ construction
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        if self.MISSING is not None:
            raise self.MISSING
        core_kwargs = {k: kwargs[k] for k in ("instance_name", "resources") if k in kwargs}
        # an instance made by an FMI host (the C wrapper passes a logger) keeps the FMI state table strictly
        self.core = self.CORE(fmi_strict="logger" in kwargs, **core_kwargs)
        for name, value in self.START.items():
            setattr(self.core, name, value)
        self.core._lane_map3 = self._lane_map3    # the core's fast lane, if any, serves the FMI 3.0 calls
        self.modelName = type(self).__name__
        for attr in ("description", "author", "version", "license", "default_experiment"):
            setattr(self, attr, getattr(self.CORE, attr, None))
        table = {v.name: v for v in self.CORE._table}
        for vr, row in enumerate(self.ROWS):
            self.register_variable(self._variable(vr, row, table.get(row.core[0]) if row.core else None),
                                   nested=False)
        self._relay()

    def to_xml(self, *args, **kwargs):
        """pythonfmu3's model description (in process, not an FMI call: it reads the start values with
        get calls in state instantiated, which the core's state table would log)."""
        saved = self.core._can_get
        self.core._can_get = True
        try:
            return super().to_xml(*args, **kwargs)
        finally:
            self.core._can_get = saved

    def _variable(self, vr: int, row: Row3, first):
        """The pythonfmu3 variable of ``row`` (its getter and setter go through the core)."""
        kwargs = dict(description=row.description or None, getter=lambda: self._get(row.type, [vr]),
                      setter=lambda values: self._set(row.type, [vr], values if row.core[1:] else [values]))
        if first is None:
            kwargs.update(causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous)
        else:
            kwargs.update(causality=getattr(Fmi3Causality, first.causality),
                          variability=getattr(Fmi3Variability, first.variability))
            if first.initial is not None:
                kwargs["initial"] = getattr(Fmi3Initial, first.initial)
        if row.size > 1:
            kwargs["dimensions"] = [Dimension(start=str(row.size))]
        if row.type == "Float64" and row.unit is not None:
            kwargs["unit"] = row.unit
        return _CLASS[row.type](row.name, **kwargs)

    # ------------------------------------------------------------------ values
    def _flat(self, kind: str, vrs) -> list[int] | None:
        """The core's value references of ``vrs`` in order, or None (one is not a ``kind`` variable)."""
        out = []
        get = self._core_vrs.get
        for vr in vrs:
            core = get(vr)
            if core is None or self._kind_of[vr] != kind:
                return None
            out.extend(core)
        return out

    def _refuse_vrs(self, call: str, kind: str, vrs) -> None:
        valid = sorted(vr for vr, k in self._kind_of.items() if k == kind)
        self._refuse(f"{type(self).__name__} instance {self.core.instance_name!r}: {call}: value references "
                     f"{list(vrs)} are not all {kind} variables (valid: {valid}); nothing done")

    def _refuse_set(self, kind: str, vrs, settable) -> None:
        """fmi3Set<kind> of variables not settable in the state, refused in FMI 3.0's terms (the core's
        check, its FMI 2.0 message not sent)."""
        core = self.core
        names = ", ".join(repr(self.ROWS[vr].name) for vr in vrs if not settable.issuperset(self._core_vrs[vr]))
        state = _STATE3.get(core._fmi_state, core._fmi_state)
        status = "fmi3Error" if core._loader else "fmi3Error by the standard; pythonfmu3 returns fmi3OK"
        self._refuse(f"{type(self).__name__} instance {core.instance_name!r}: fmi3Set{kind} refused in state {state}: "
                     f"variable(s) {names} not settable in this state (FMI 3.0 sets in {state} "
                     f"{_SETTABLE3.get(state, 'no variable')}); nothing changed ({status})")

    def _refuse(self, msg: str) -> None:
        self.core.refused_calls += 1
        self.core.last_call_refusal = msg
        self.log(msg, Fmi3Status.error)
        self.core._pylog.error("%s", msg)
        self.core._hand_off(Fmi3Status.error)        # behind the C loader: the call returns fmi3Error
        self._relay()

    def _set(self, kind: str, vrs, values) -> None:
        flat = self._flat(kind, vrs)
        if flat is None or len(flat) != len(values):
            self._refuse_vrs(f"fmi3Set{kind}", kind, vrs)
            return
        core = self.core
        settable = core._settable_now[_CORE_TYPE[kind]]
        if not settable.issuperset(flat) and core._fmi_strict:
            self._refuse_set(kind, vrs, settable)
            return
        (core.set_real if kind == "Float64" else core.set_integer if kind == "Int32" else core.set_boolean)(
            flat, list(values))
        self._relay()

    def _get(self, kind: str, vrs) -> list:
        flat = self._flat(kind, vrs)
        if flat is None:
            if kind == "Float64" and self._time_vr in vrs and self._flat(kind, [v for v in vrs if v != self._time_vr]) \
                    is not None:                 # time, and Float64 variables of the core
                return [x for vr in vrs for x in ([float(self.core._time)] if vr == self._time_vr
                                                  else self._get(kind, [vr]))]
            self._refuse_vrs(f"fmi3Get{kind}", kind, vrs)
            return []
        core = self.core
        get = core.get_real if kind == "Float64" else core.get_integer if kind == "Int32" else core.get_boolean
        if not core._can_get and core._fmi_state == INSTANTIATED:
            # FMI 3.0 reads the start values (or the values set) in Instantiated, FMI 2.0 does not: the
            # core answers with its current values, nothing computed
            saved = core._can_get, core._dirty
            core._can_get, core._dirty = True, False
            try:
                out = get(flat)
            finally:
                core._can_get, core._dirty = saved
        else:
            out = get(flat)
        if core.log_queue:
            self._relay()
        return out

    def set_float64(self, vrs, values):
        self._set("Float64", vrs, values)

    def get_float64(self, vrs):
        return self._get("Float64", vrs)

    def set_int32(self, vrs, values):
        self._set("Int32", vrs, values)

    def get_int32(self, vrs):
        return self._get("Int32", vrs)

    def set_boolean(self, vrs, values):
        self._set("Boolean", vrs, values)

    def get_boolean(self, vrs):
        return self._get("Boolean", vrs)

    # ------------------------------------------------------------------ the calls of the state machine
    def enter_initialization_mode(self):
        self.core.enter_initialization_mode()
        self._relay()

    def exit_initialization_mode(self):
        self.core.exit_initialization_mode()
        self._relay()

    def do_step(self, current_time: float, step_size: float):
        core = self.core
        forbidden, stepping = core.refused_calls, core._fmi_state == STEP_COMPLETE
        done = core.do_step(current_time, step_size)
        if not done and stepping and core._fmi_state == STEP_FAILED:
            # FMI 3.0: a doStep that returns fmi3Discard leaves the FMU in the state before the call
            # (StepMode: set inputs, step again, get, set the FMU state, terminate); FMI 2.0's core went
            # to stepFailed after rolling the step back, and its message says so: FMI 3.0's words
            core._enter_state(STEP_COMPLETE)
            for m in core.log_queue:
                m.msg = m.msg.replace(_DISCARD2[0], _DISCARD3[0]).replace(_DISCARD2[1], _DISCARD3[1])
        if core.log_queue:
            self._relay()
        if done:
            return _OK
        return _ERROR if core.refused_calls != forbidden else _DISCARD

    def terminate(self):
        self.core.terminate()
        self._relay()

    # ------------------------------------------------------------------ FMU state (the core's: a pickle)
    def _get_fmu_state(self):
        state = self.core._get_fmu_state()
        self._relay()
        return state

    def _set_fmu_state(self, state):
        self.core._set_fmu_state(state)
        self._relay()

    @staticmethod
    def _fmu_state_to_bytes(state) -> bytes:
        return bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(state) -> bytes:
        return bytes(state)

    # ------------------------------------------------------------------ log
    def _relay(self) -> None:
        """Hand the core's log messages on to pythonfmu3's queue (same status numbers in FMI 2.0 and 3.0;
        the core escapes '%' for FMI 2.0's printf-style logger, FMI 3.0's takes the text as it is)."""
        queue = self.core.log_queue
        for m in queue:
            # the core's hand-offs (for the C loader only) keep their category, as a host's log category does
            kept = m.category in (HAND_OFF_CATEGORY, LANE_CATEGORY) or m.category in self.log_categories
            self.log(m.msg.replace("%%", "%"), Fmi3Status(int(m.status)), m.category if kept else None)
        queue.clear()
