"""Table-driven base class for the project's pythonfmu slaves (FMI 2.0 Co-Simulation).

A slave is a table of variables plus a ``step``::

    from fmu_src.table_slave import StepRefused, TableSlave, Var

    class Integrator(TableSlave):             # class name == module name == modelIdentifier
        description = "x' = k*u"
        VARIABLES = (
            Var("u", "Real", "input", start=0.0, unit="rad/s", description="rate"),
            Var("k", "Real", "parameter", "tunable", start=1.0, unit="1"),
            Var("x", "Real", "output", unit="rad", depends_on=()),
        )
        STATE = ()                             # extra attributes rolled back with the FMU state

        def step(self, t, dt):
            self.x += self.k * self.u * dt

Each table entry becomes an instance attribute of the same name (``Var.attr`` when the FMI name is
not a Python identifier), set to its start value before ``setup()`` runs.  Value references are the
row numbers of the table (0, 1, 2, ...), so a master looks them up by name once.

Hooks a slave may define
------------------------
``setup()``            build the initial internal state (called at instantiation and by fmi2Reset,
                       which makes a fresh instance); attributes it creates must be listed in
                       ``STATE`` (mutable, rolled back) or ``CONSTANT`` (never changed after setup).
``on_initialized()``   after fmi2ExitInitializationMode, when parameters and inputs are final.
``initial_outputs()``  in Initialization Mode: the outputs of the current parameters and start values
                       (a host reads them to pass them on before exitInitializationMode).  Called on
                       entering it and lazily by fmi2Get* after any fmi2Set* there.
``step(t, dt)``        advance the internal state over [t, t+dt]; raise :class:`StepRefused` to
                       refuse the step with a message.
``evaluate()``         direct feedthrough: recompute the outputs whose ``depends_on`` is not empty from
                       the current inputs and state.  Called after every step, at the end of
                       initialization, and lazily by fmi2Get* after an input was set.  Required as
                       soon as an output declares input dependencies (the ModelStructure then tells
                       the truth: such an output changes when its input is set, without doStep).
``get_state()`` / ``set_state(snapshot)``  override only if the default (table values + ``STATE``
                       attributes, deep-copied through pickle; :mod:`fmu_src.slave_state`) does not fit.

Class attributes a slave may set
--------------------------------
``IMMUTABLE_STATE = True``   ``step``/``evaluate`` never change a ``STATE`` value in place, they
                       only assign new values to the attributes: a doStep's rollback then keeps
                       references (no copy, no pickle; :mod:`fmu_src.slave_state`).
``EVALUATE_AFTER_STEP = False``  ``step`` itself leaves the outputs of the current inputs (no
                       ``evaluate`` after it).
``CHECK_OUTPUTS = False``    do not refuse a step whose Real outputs are not finite.

Speed (the per-step path)
-------------------------
FMU state and rollback snapshots (what a refused step restores): :mod:`fmu_src.slave_state`.
The finiteness and range checks of each doStep cost O(1) per variable (one sum over the Real
values: finite iff all are; the exact per-variable loop only when it is not, to name the
culprit).  ``fmi2Set*``/``fmi2Get*`` take one dictionary lookup per value reference
(:mod:`fmu_src.value_access`).
Compiled kernels of bundled packages are cached on disk per FMU content
(:mod:`fmu_src.kernel_cache`; :mod:`fmu_src.kernel_locator`, installed when this module is imported).

Rules for slave scripts: import only the runtime of ``fmu_src`` (``table_slave``, ``variables``,
``slave_state``, ``dk_variables``; the host side is not bundled); keep module-level code to imports and the class
(pythonfmu's C wrapper re-executes the module source at every instantiation to find the class);
read data files in ``setup()`` from ``Path(self.resources) / <name given to build_fmu>`` and list
the attribute in ``CONSTANT``.

Refused steps
-------------
pythonfmu 0.7 maps ``do_step`` returning False to fmi2Discard (and sets the sticky
fmi2Terminated status flag), and an uncaught exception to fmi2Fatal; there is no path from Python to
fmi2Error in fmi2DoStep.  ``TableSlave.do_step`` therefore never lets an exception out: a
non-finite or out-of-range input or parameter, a :class:`StepRefused`, any other exception from
``step``/``evaluate``, or a non-finite output all restore the state of the start of the step and
return fmi2Discard, with a message naming the cause (variable and value, or exception type and
text).  The message goes to the FMI logger with status fmi2Error (the C wrapper forwards it only
when the instance was created with loggingOn=true) and, always, to the Python logger
``fmu_src.<ModelName>`` (stderr by default), because fmpy.simulate_fmu treats fmi2Discard plus
fmi2Terminated as a normal early end and otherwise returns a silently truncated result.  The
master may continue: with the next valid input at the same communication point, or after
fmi2SetFMUstate.
"""
from __future__ import annotations

import logging
import math
import traceback
from typing import Any, ClassVar

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from . import kernel_cache, kernel_locator, kernel_warmup
from .fmi_states import (ERROR, INITIALIZATION_MODE, INSTANTIATED, STEP_COMPLETE, STEP_FAILED, TERMINATED, FmiStates,
                         behind_loader)
from .slave_state import StateHandling, values_getter
from .value_access import ValueAccess
from .value_checks import _IN_PAR, _OUT, ValueChecks
from .variables import CAUSALITIES, INITIALS, VARIABILITIES, TableError, Var, check_table

kernel_locator.install()

__all__ = ["Var", "TableSlave", "StepRefused", "TableError", "check_table"]

_ENUM_CAUSALITY = {c: getattr(Fmi2Causality, c) for c in CAUSALITIES}
_ENUM_VARIABILITY = {v: getattr(Fmi2Variability, v) for v in VARIABILITIES}
_ENUM_INITIAL = {i: getattr(Fmi2Initial, i) for i in INITIALS}
_PY_TYPE = {"Real": float, "Integer": int, "Boolean": bool}
_FMI_VAR = {"Real": Real, "Integer": Integer, "Boolean": Boolean}


class StepRefused(Exception):
    """Raised by ``step``/``evaluate`` to refuse a step; the message reaches the master's log."""


class TableSlave(FmiStates, StateHandling, ValueAccess, ValueChecks, Fmi2Slave):
    """pythonfmu slave whose interface is the class attribute ``VARIABLES`` (see the module doc)."""

    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    STATE: ClassVar[tuple[str, ...]] = ()
    CONSTANT: ClassVar[tuple[str, ...]] = ()
    UNITS: ClassVar[dict[str, dict[str, float]]] = {}
    CHECK_OUTPUTS: ClassVar[bool] = True
    IMMUTABLE_STATE: ClassVar[bool] = False
    EVALUATE_AFTER_STEP: ClassVar[bool] = True

    # filled by __init_subclass__
    _table: ClassVar[tuple[Var, ...]] = ()
    VR: ClassVar[dict[str, int]] = {}
    _feedthrough: ClassVar[bool] = False
    _has_initial_outputs: ClassVar[bool] = False
    _evaluate_after_step: ClassVar[bool] = False
    _table_values: ClassVar[Any] = None
    _rollback_attrs: ClassVar[tuple[str, ...]] = ()
    _rollback_values: ClassVar[Any] = None
    _output_attrs: ClassVar[tuple[str, ...]] = ()
    _output_values: ClassVar[Any] = None
    _state_values: ClassVar[Any] = None
    _default_state: ClassVar[bool] = False
    _checks: ClassVar[dict] = {}
    _in_check: ClassVar[tuple] = (None, ())
    _out_check: ClassVar[tuple] = (None, ())
    # value reference -> attribute, per FMI type; value references whose set marks the outputs stale;
    # value references of outputs that a get refreshes first (direct feedthrough)
    _attrs: ClassVar[dict[str, dict[int, str]]] = {}
    _real_attrs: ClassVar[dict[int, str]] = {}
    _marks_dirty: ClassVar[frozenset] = frozenset()
    _refreshing: ClassVar[frozenset] = frozenset()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls._has_initial_outputs = cls.initial_outputs is not TableSlave.initial_outputs
        # rollback snapshots bypass get_state/set_state where they are the defaults (see _capture)
        cls._default_state = cls.get_state is TableSlave.get_state and cls.set_state is TableSlave.set_state
        names = cls.STATE
        valid = isinstance(names, tuple) and all(isinstance(n, str) and n.isidentifier() for n in names)
        cls._state_values = staticmethod(values_getter(names)) if valid else None   # invalid: TableError below
        if not cls.__dict__.get("VARIABLES"):
            return  # an intermediate abstract base
        reserved = {n for n in dir(TableSlave) if not n.startswith("_")} | {
            "vars", "instance_name", "resources", "visible", "log_queue", "guid", "author", "license",
            "version", "copyright", "modelName", "description", "default_experiment", "refused_steps",
            "last_refusal", "refused_calls", "last_call_refusal"}
        table = check_table(cls.VARIABLES, reserved)
        for group in ("STATE", "CONSTANT"):
            names = getattr(cls, group)
            if not isinstance(names, tuple) or not all(isinstance(n, str) and n.isidentifier() for n in names):
                raise TableError(f"{cls.__name__}.{group} must be a tuple of attribute names")
            clash = set(names) & {v.attr for v in table}
            if clash:
                raise TableError(f"{cls.__name__}.{group} repeats table variables {sorted(clash)}")
        if set(cls.STATE) & set(cls.CONSTANT):
            raise TableError(f"{cls.__name__}: an attribute cannot be both STATE and CONSTANT")
        feedthrough = any(v.is_output and v.depends_on for v in table)
        has_evaluate = cls.evaluate is not TableSlave.evaluate
        if feedthrough and not has_evaluate:
            raise TableError(f"{cls.__name__}: outputs declare input dependencies (direct feedthrough) "
                             "but the class defines no evaluate()")
        cls._table = table
        cls.VR = {v.name: i for i, v in enumerate(table)}
        cls._build_settable(table)
        cls._feedthrough = has_evaluate
        cls._evaluate_after_step = has_evaluate and bool(cls.EVALUATE_AFTER_STEP)
        cls._attrs = {kind: {i: v.attr for i, v in enumerate(table) if v.type == kind} for kind in _PY_TYPE}
        cls._real_attrs = cls._attrs["Real"]
        cls._marks_dirty = frozenset(i for i, v in enumerate(table) if has_evaluate
                                     and (v.causality == "input" or v.variability == "tunable"))
        cls._refreshing = frozenset(i for i, v in enumerate(table) if has_evaluate and v.is_output)
        # per-step fast paths: all table values at once, the finiteness and range checks of each group
        cls._table_values = staticmethod(values_getter(tuple(v.attr for v in table)))
        cls._rollback_attrs = (*cls._BOOKKEEPING, *(v.attr for v in table), *cls.STATE)
        cls._rollback_values = staticmethod(values_getter(cls._rollback_attrs))
        cls._output_attrs = tuple(v.attr for v in table if v.is_output)
        cls._output_values = staticmethod(values_getter(cls._output_attrs))
        cls._checks = {}
        for causalities, check_range in ((_IN_PAR, True), (_OUT, False)):
            rows = [v for v in table if v.causality in causalities and v.type != "Boolean"]
            reals = values_getter(tuple(v.attr for v in rows if v.type == "Real"))
            ranged = tuple((v.attr, -math.inf if v.min is None else v.min, math.inf if v.max is None else v.max)
                           for v in rows if check_range and (v.min is not None or v.max is not None))
            cls._checks[causalities, check_range] = (reals, ranged)
        cls._in_check, cls._out_check = cls._checks[_IN_PAR, True], cls._checks[_OUT, False]

    # ------------------------------------------------------------------ construction
    def __init__(self, **kwargs):
        # strict FMI state table only for an instance made by an FMI host (fmu_src.fmi_states)
        self._fmi_strict = bool(kwargs.pop("fmi_strict", "logger" in kwargs))
        super().__init__(**kwargs)
        cls = type(self)
        if not cls._table:
            raise TableError(f"{cls.__name__} has no VARIABLES table")
        self.modelName = cls.__name__
        self._time = 0.0
        self._dirty = False
        self._init_error: str | None = None
        self._broken: str | None = None
        self._enter_state(INSTANTIATED)  # the FMI state machine (fmu_src.fmi_states): _fmi_state and flags
        # behind the C loader, hand the FMI state and refusals over to it (fmu_src.fmi_states); not the
        # state instantiated: the loader knows it (a message logged in the constructor waits in
        # pythonfmu's queue until the next call)
        self._loader = self._fmi_strict and behind_loader(self.resources)
        self.refused_steps = 0          # diagnostics only, not part of the FMU state
        self.refused_calls = 0          # calls the FMI state table forbids (diagnostics)
        self.last_call_refusal: str | None = None
        self.last_refusal: str | None = None
        self._pylog = logging.getLogger(f"fmu_src.{cls.__name__}")
        self._base_attrs = set(self.__dict__) | {"_base_attrs"}
        for v in cls._table:
            setattr(self, v.attr, _PY_TYPE[v.type](v.start) if v.start is not None else _PY_TYPE[v.type]())
            self.register_variable(self._make_variable(v), nested=False)
        problem = kernel_cache.attach(self)     # a kernel compiled now is announced in this instance's log
        if problem:                             # the shipped kernels cannot serve: compiled in a child process
            kernel_warmup.ensure(self, self.resources, problem)
        self.setup()

    def _make_variable(self, v: Var):
        attr, conv = v.attr, _PY_TYPE[v.type]
        marks_dirty = self._feedthrough and (v.causality == "input" or v.variability == "tunable")
        refreshing = v.is_output and self._feedthrough
        if v.is_output:
            def getter():
                if self._dirty and (refreshing or self._init_mode):
                    self._refresh()
                return getattr(self, attr)
        else:
            def getter():
                return getattr(self, attr)

        def setter(value):
            setattr(self, attr, conv(value))
            if marks_dirty or self._init_mode:
                self._dirty = True
        kwargs = dict(causality=_ENUM_CAUSALITY[v.causality], variability=_ENUM_VARIABILITY[v.variability],
                      description=v.description or None, getter=getter, setter=setter)
        if v.initial is not None:
            kwargs["initial"] = _ENUM_INITIAL[v.initial]
        return _FMI_VAR[v.type](v.name, **kwargs)

    # ------------------------------------------------------------------ hooks (override)
    def setup(self) -> None:
        """Create the initial internal state (attributes listed in STATE / CONSTANT)."""

    def on_initialized(self) -> None:
        """Called once parameters and inputs of the initialization are final."""

    def step(self, t: float, dt: float) -> None:
        raise NotImplementedError

    def evaluate(self) -> None:
        """Recompute the direct-feedthrough outputs from inputs and state (optional)."""

    def initial_outputs(self) -> None:
        """The outputs of the parameters and start values, in Initialization Mode (optional)."""

    # ------------------------------------------------------------------ pythonfmu interface
    def to_xml(self, *args, **kwargs):
        """pythonfmu's model description (in process, not an FMI call: it reads the start values with
        fmi2Get* methods in state instantiated, which the state table would refuse)."""
        saved = self._can_get
        self._can_get = True
        try:
            return super().to_xml(*args, **kwargs)
        finally:
            self._can_get = saved

    # Every method below first checks the FMI state table (fmu_src.fmi_states): a forbidden call is
    # logged and changes nothing.  None of them lets an exception out (it would be fmi2Fatal).
    def setup_experiment(self, start_time: float, stop_time=None, tolerance=None):
        if not self._allowed("fmi2SetupExperiment"):
            return
        if not math.isfinite(start_time):
            self._refuse_call("fmi2SetupExperiment", f", startTime {start_time!r} is not finite")
            return
        self._time = float(start_time)

    def enter_initialization_mode(self):
        if not self._allowed("fmi2EnterInitializationMode"):
            return
        self._enter_state(INITIALIZATION_MODE)
        self._dirty = True                     # the first fmi2Get* computes the initial outputs

    def exit_initialization_mode(self):
        """Check the parameters and start values and initialize; on a refusal the state is ``error``
        (the reason is logged; the C loader returns fmi2Error, pythonfmu 0.7 alone fmi2OK)."""
        if not self._allowed("fmi2ExitInitializationMode"):
            return
        self._init_error = None
        bad = self._non_finite(_IN_PAR)
        if bad:
            self._init_failed("invalid " + "; ".join(bad))
            return
        self._enter_state(STEP_COMPLETE)
        try:
            self.on_initialized()
            if self._feedthrough:
                self.evaluate()
            self._dirty = False
        except Exception as exc:  # never let an exception reach the C wrapper (it would be fmi2Fatal)
            self._init_failed(f"{type(exc).__name__}: {exc}")

    def _init_failed(self, reason: str) -> None:
        """fmi2ExitInitializationMode refused: state ``error``, the reason logged (a slave may extend it)."""
        self._init_error = reason
        self._enter_state(ERROR)
        self._dirty = False
        self._report(f"{type(self).__name__} instance {self.instance_name!r}: fmi2ExitInitializationMode: "
                     f"initialization failed: {reason}; the instance is in state error "
                     f"({self._returned(Fmi2Status.ok)}): fmi2Reset it, or free it and instantiate again, "
                     "and initialize with valid values", Fmi2Status.error)
        self._hand_off(Fmi2Status.error)

    def terminate(self):
        if self._allowed("fmi2Terminate"):
            self._enter_state(TERMINATED)

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self._can_step and not self._allowed("fmi2DoStep"):
            return False
        if (self._broken or self._init_error or not self._all_finite(self._in_check)
                or not (math.isfinite(current_time) and math.isfinite(step_size) and step_size >= 0.0)):
            reason = self._step_refusal(current_time, step_size)
            if reason:
                return self._refuse(current_time, step_size, reason)
        if self.IMMUTABLE_STATE:
            snapshot = self._rollback_values(self)           # references (fmu_src.slave_state)
        else:
            try:
                snapshot = self._capture()
            except Exception as exc:
                return self._refuse(current_time, step_size,
                                    f"the state does not pickle: {type(exc).__name__}: {exc}")
        try:
            self.step(current_time, step_size)
            if self._evaluate_after_step:
                self.evaluate()
            if self.CHECK_OUTPUTS and not self._all_finite(self._out_check):
                bad = self._non_finite(_OUT, check_range=False)
                if bad:
                    raise StepRefused("step produced non-finite " + "; ".join(bad))
        except StepRefused as exc:
            return self._rollback_and_refuse(snapshot, current_time, step_size, str(exc))
        except Exception as exc:
            tb = traceback.format_exc(limit=-3)
            return self._rollback_and_refuse(snapshot, current_time, step_size,
                                             f"internal error {type(exc).__name__}: {exc}\n{tb}")
        self._time = current_time + step_size
        self._dirty = False
        return True

    def _step_refusal(self, t: float, dt: float) -> str:
        """Why a doStep cannot start (in this order: the instance, the step size, the inputs and
        parameters); "" if it can."""
        if self._broken:
            return f"instance unusable: {self._broken}"
        if self._init_error:
            return f"initialization failed: {self._init_error}"
        if not (math.isfinite(t) and math.isfinite(dt) and dt >= 0.0):
            return f"invalid communication step size {dt!r}"
        bad = self._non_finite(_IN_PAR)
        return "invalid " + "; ".join(bad) if bad else ""

    # ------------------------------------------------------------------ internals
    def _refuse(self, t: float, dt: float, msg: str) -> bool:
        """Refuse a doStep (after its rollback, if any): count, log, return False (fmi2Discard).
        Every refusal ends here; a slave may extend it (the DK FMU sets its status output)."""
        full = (f"{type(self).__name__} instance {self.instance_name!r}: step [{t!r}, {t + dt!r}] refused "
                f"(fmi2Discard, state kept at t={self._time!r}; now in state stepFailed: fmi2SetFMUstate, "
                f"fmi2Reset or fmi2Terminate): {msg}")
        self._enter_state(STEP_FAILED)
        self.refused_steps += 1
        self.last_refusal = full
        self._report(full, Fmi2Status.error)
        return False

    def _report(self, msg: str, status: Fmi2Status) -> None:
        # the C wrapper hands the text to the host logger as its printf *format* argument (FMI 2.0
        # defines the message that way): escape '%' or a '%s' in an exception text reads garbage
        self.log(msg.replace("%", "%%"), status)
        self._pylog.log(logging.ERROR if status >= Fmi2Status.discard else logging.WARNING, "%s", msg)
