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
``step(t, dt)``        advance the internal state over [t, t+dt]; raise :class:`StepRefused` to
                       refuse the step with a message.
``evaluate()``         direct feedthrough: recompute the outputs whose ``depends_on`` is not empty from
                       the current inputs and state.  Called after every step, at the end of
                       initialization, and lazily by fmi2Get* after an input was set.  Required as
                       soon as an output declares input dependencies (the ModelStructure then tells
                       the truth: such an output changes when its input is set, without doStep).
``get_state()`` / ``set_state(snapshot)``  override only if the default (table values + ``STATE``
                       attributes, deep-copied through pickle) does not fit.

FMU state: pythonfmu 0.7 keeps the object returned by ``_get_fmu_state`` as the fmi2FMUstate
(no copy) and serializes it with the class-level ``_fmu_state_to_bytes``/``_fmu_state_from_bytes``.
Here that object is an immutable pickle of ``get_state()`` plus the base-class bookkeeping, so a
state can be set any number of times and serializes as is.  fmi2Reset makes a new Python instance.
Serialized states are pickles: deserialize only states this project produced.

Rollback snapshots: every doStep (and every lazy ``evaluate`` for fmi2Get*) first takes a snapshot
it restores if the step is refused.  That snapshot never leaves the process, so it is not a pickle
of the whole state but an equally deep in-memory copy (:class:`_Capture`): immutable values
(``float``, ``int``, ``bool``, ``str``, ``bytes``, ``None``, numpy scalars, tuples and frozensets of
them) are kept as they are, plain numpy arrays (no Python objects inside) are copied, lists of
immutable values are copied, and whatever else the state holds is pickled as before (so a state
that does not pickle is still refused at the step, with the same message; and when there is such
a value, or two attributes hold the same array or list, the arrays and lists go into that pickle
too, which keeps any sharing between them).  Restoring gives the same values as restoring the
pickle.  It costs ~2 us instead of ~14 us per step for the plant and controller FMUs (a state
of table values and one array), ~7 us instead of ~13 us for the DK FMU (whose ``get_state``
override alone takes ~4 us).  The finiteness and range checks of each doStep also have a fast
path (one sum over the Real values: finite iff all are; the exact per-variable loop only when it
is not, to name the culprit).

Rules for slave scripts: import only ``fmu_src.table_slave`` from ``fmu_src`` (``fmi_build`` is not
bundled); keep module-level code to imports and the class (pythonfmu's C wrapper re-executes the
module source at every instantiation to find the class); read data files in ``setup()`` from
``Path(self.resources) / <name given to build_fmu>`` and list the attribute in ``CONSTANT``.

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

import keyword
import logging
import math
import operator
import pickle
import re
import sys
import traceback
from dataclasses import dataclass, replace
from typing import Any, ClassVar

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

__all__ = ["Var", "TableSlave", "StepRefused", "TableError", "check_table"]

TYPES = ("Real", "Integer", "Boolean")
CAUSALITIES = ("parameter", "calculatedParameter", "input", "output", "local")
VARIABILITIES = ("constant", "fixed", "tunable", "discrete", "continuous")
INITIALS = ("exact", "approx", "calculated")

# FMI 2.0 (section 2.2.7, table of causality x variability): legal 'initial' values per
# (causality, variability); the first entry is the default.  None means "initial is not allowed".
_LEGAL_INITIAL: dict[tuple[str, str], tuple[str | None, ...]] = {
    ("parameter", "fixed"): ("exact",),
    ("parameter", "tunable"): ("exact",),
    ("calculatedParameter", "fixed"): ("calculated", "approx"),
    ("calculatedParameter", "tunable"): ("calculated", "approx"),
    ("input", "discrete"): (None,),
    ("input", "continuous"): (None,),
    ("output", "constant"): ("exact",),
    ("output", "discrete"): ("calculated", "exact", "approx"),
    ("output", "continuous"): ("calculated", "exact", "approx"),
    ("local", "constant"): ("exact",),
    ("local", "fixed"): ("calculated", "approx"),
    ("local", "tunable"): ("calculated", "approx"),
    ("local", "discrete"): ("calculated", "exact", "approx"),
    ("local", "continuous"): ("calculated", "exact", "approx"),
}

_ENUM_CAUSALITY = {c: getattr(Fmi2Causality, c) for c in CAUSALITIES}
_ENUM_VARIABILITY = {v: getattr(Fmi2Variability, v) for v in VARIABILITIES}
_ENUM_INITIAL = {i: getattr(Fmi2Initial, i) for i in INITIALS}
_PY_TYPE = {"Real": float, "Integer": int, "Boolean": bool}
_FMI_VAR = {"Real": Real, "Integer": Integer, "Boolean": Boolean}


class TableError(ValueError):
    """The variable table of a slave breaks a rule of FMI 2.0 or of this base class."""


class StepRefused(Exception):
    """Raised by ``step``/``evaluate`` to refuse a step; the message reaches the master's log."""


@dataclass(frozen=True)
class Var:
    """One row of a slave's variable table.

    ``variability`` defaults to ``fixed`` for parameters, ``continuous`` for Real and ``discrete``
    for Integer/Boolean variables; ``initial`` defaults to FMI's default for the combination.
    ``depends_on`` is required for outputs: the names of the inputs the output depends on directly
    (``()`` for none); it becomes ModelStructure/Outputs/Unknown/@dependencies.
    """

    name: str
    type: str
    causality: str
    variability: str | None = None
    initial: str | None = None
    start: float | int | bool | None = None
    unit: str | None = None
    description: str = ""
    depends_on: tuple[str, ...] | None = None
    min: float | int | None = None
    max: float | int | None = None
    attr: str | None = None

    @property
    def is_output(self) -> bool:
        return self.causality == "output"


def _attr_name(name: str) -> str:
    attr = re.sub(r"\W", "_", name)
    if not attr or attr[0].isdigit():
        attr = "v_" + attr
    return attr


def check_table(variables, reserved: set[str] = frozenset()) -> tuple[Var, ...]:
    """Validate a variable table and return it with every default made explicit.

    Raises :class:`TableError` naming the variable and the rule it breaks.
    """
    if not isinstance(variables, (tuple, list)) or not variables:
        raise TableError("VARIABLES must be a non-empty tuple of Var")
    out: list[Var] = []
    names: set[str] = set()
    attrs: set[str] = set()
    for v in variables:
        if not isinstance(v, Var):
            raise TableError(f"VARIABLES entries must be Var, got {v!r}")
        where = f"variable {v.name!r}"
        if not v.name or v.name != v.name.strip() or any(c in v.name for c in "\r\n\t"):
            raise TableError(f"{where}: illegal name")
        if v.name in names:
            raise TableError(f"{where}: duplicate name")
        names.add(v.name)
        if v.type not in TYPES:
            raise TableError(f"{where}: type must be one of {TYPES}, not {v.type!r}")
        if v.causality not in CAUSALITIES:
            raise TableError(f"{where}: causality must be one of {CAUSALITIES}, not {v.causality!r}")
        variability = v.variability
        if variability is None:
            if v.causality in ("parameter", "calculatedParameter"):
                variability = "fixed"
            else:
                variability = "continuous" if v.type == "Real" else "discrete"
        if variability not in VARIABILITIES:
            raise TableError(f"{where}: variability must be one of {VARIABILITIES}, not {variability!r}")
        if variability == "continuous" and v.type != "Real":
            raise TableError(f"{where}: only Real variables may be continuous ({v.type} must be discrete)")
        legal = _LEGAL_INITIAL.get((v.causality, variability))
        if legal is None:
            raise TableError(f"{where}: causality={v.causality!r} with variability={variability!r} "
                             "is not allowed by FMI 2.0")
        initial = v.initial if v.initial is not None else legal[0]
        if initial not in legal:
            allowed = "no initial attribute" if legal == (None,) else f"initial in {legal}"
            raise TableError(f"{where}: {v.causality}/{variability} requires {allowed}, not {v.initial!r}")
        needs_start = v.causality == "input" or initial in ("exact", "approx")
        start = v.start
        if needs_start and start is None:
            raise TableError(f"{where}: a start value is required ({v.causality}, initial={initial})")
        if initial == "calculated" and start is not None:
            raise TableError(f"{where}: initial='calculated' must not have a start value")
        if start is not None:
            if v.type == "Boolean":
                if not isinstance(start, bool):
                    raise TableError(f"{where}: Boolean start must be True or False")
            elif v.type == "Integer":
                if isinstance(start, bool) or int(start) != start:
                    raise TableError(f"{where}: Integer start must be an integer")
                start = int(start)
            else:
                start = float(start)
                if not math.isfinite(start):
                    raise TableError(f"{where}: start must be finite")
        if v.unit is not None and v.type != "Real":
            raise TableError(f"{where}: only Real variables carry a unit")
        if (v.min is not None or v.max is not None) and v.type == "Boolean":
            raise TableError(f"{where}: Boolean variables have no min/max")
        lo = -math.inf if v.min is None else v.min
        hi = math.inf if v.max is None else v.max
        if lo > hi:
            raise TableError(f"{where}: min > max")
        if start is not None and v.type != "Boolean" and not lo <= start <= hi:
            raise TableError(f"{where}: start {start!r} outside [min, max]")
        attr = v.attr or _attr_name(v.name)
        if not attr.isidentifier() or keyword.iskeyword(attr) or attr.startswith("_"):
            raise TableError(f"{where}: attribute name {attr!r} is not a public Python identifier")
        if attr in reserved:
            raise TableError(f"{where}: attribute name {attr!r} collides with a TableSlave attribute; "
                             "pass Var(attr=...)")
        if attr in attrs:
            raise TableError(f"{where}: attribute name {attr!r} used twice")
        attrs.add(attr)
        out.append(replace(v, variability=variability, initial=None if v.causality == "input" else initial,
                           start=start, attr=attr,
                           depends_on=tuple(v.depends_on) if v.depends_on is not None else None))
    inputs = {v.name for v in out if v.causality == "input"}
    for v in out:
        where = f"variable {v.name!r}"
        if v.is_output:
            if v.depends_on is None:
                raise TableError(f"{where}: outputs must declare depends_on (the inputs they depend on "
                                 "directly; () for none)")
            if len(set(v.depends_on)) != len(v.depends_on):
                raise TableError(f"{where}: depends_on lists a name twice")
            bad = [d for d in v.depends_on if d not in inputs]
            if bad:
                raise TableError(f"{where}: depends_on must name inputs of this table, not {bad}")
        elif v.depends_on is not None:
            raise TableError(f"{where}: only outputs have depends_on")
    return tuple(out)


def _values_getter(attrs: tuple):
    """``f(obj) -> tuple`` of the attributes ``attrs`` of ``obj`` (operator.attrgetter, always a tuple)."""
    if not attrs:
        return lambda obj: ()
    if len(attrs) == 1:
        get = operator.attrgetter(attrs[0])
        return lambda obj: (get(obj),)
    return operator.attrgetter(*attrs)


#: types whose values never change in place (kept as they are in a rollback snapshot); numpy's scalar
#: types are added when first met
_IMMUTABLE = {float, int, bool, str, bytes, type(None), complex}
_IN_PAR = ("input", "parameter")
_BOOKKEEPING = ("_time", "_dirty", "_initialized", "_init_error", "_broken")
_book_values = operator.attrgetter(*_BOOKKEEPING)
_OUT = ("output",)


def _immutable(value) -> bool:
    """True if ``value`` can be kept by reference in a snapshot (it cannot change in place)."""
    t = type(value)
    if t in _IMMUTABLE:
        return True
    if t is tuple or t is frozenset:
        return _IMMUTABLE.issuperset(map(type, value)) or all(map(_immutable, value))
    np = sys.modules.get("numpy")          # numpy scalars (never imported here: FMUs bundle this module)
    if np is not None and isinstance(value, (np.number, np.bool_)):
        _IMMUTABLE.add(t)
        return True
    return False


class _Capture:
    """In-memory rollback snapshot of a :class:`TableSlave` (see the module docstring).

    ``book``: the bookkeeping values; ``keys``: the snapshot's keys in order; ``kept``: immutable
    values by key; ``arrays``: copies of numpy arrays; ``lists``: tuples of the items of lists;
    ``blob``: pickle of the other values (None if there are none).  ``table``: the table values in
    table order when they were all immutable and ``get_state`` is the default (then ``keys`` etc.
    hold only the ``STATE`` attributes).
    """

    __slots__ = ("book", "table", "keys", "kept", "arrays", "lists", "blob")

    def __init__(self, book, table, state: dict):
        self.book, self.table, self.keys = book, table, tuple(state)
        kept = dict(state)                  # a copy: get_state() may hand out a dict it keeps
        arrays, lists, other = {}, {}, {}
        odd = [key for key, value in kept.items() if type(value) not in _IMMUTABLE]
        if odd:
            np = sys.modules.get("numpy")
            ndarray = np.ndarray if np is not None else None
            for key in odd:
                value = kept[key]
                t = type(value)
                if t is ndarray and not value.dtype.hasobject:
                    arrays[key] = value.copy(order="K")
                elif _immutable(value):
                    continue
                elif t is list and (_IMMUTABLE.issuperset(map(type, value)) or all(map(_immutable, value))):
                    lists[key] = tuple(value)
                else:
                    other[key] = value
                del kept[key]
            if other or len({id(state[key]) for key in (*arrays, *lists)}) < len(arrays) + len(lists):
                # an object that may refer to an array or list of the state, or two attributes holding
                # the same array or list: one pickle of all of them keeps the sharing, as before
                for key in (*arrays, *lists):
                    other[key] = state[key]
                arrays, lists = {}, {}
        self.kept, self.arrays, self.lists = kept, arrays, lists
        self.blob = pickle.dumps(other, protocol=pickle.HIGHEST_PROTOCOL) if other else None

    def state(self) -> dict:
        """The captured values as fresh objects (a snapshot can be restored more than once)."""
        kept = self.kept
        if len(kept) == len(self.keys):
            return dict(kept)
        other = pickle.loads(self.blob) if self.blob is not None else {}
        out = {}
        for key in self.keys:
            if key in kept:
                out[key] = kept[key]
            elif key in self.arrays:
                out[key] = self.arrays[key].copy(order="K")
            elif key in self.lists:
                out[key] = list(self.lists[key])
            else:
                out[key] = other[key]
        return out


class TableSlave(Fmi2Slave):
    """pythonfmu slave whose interface is the class attribute ``VARIABLES`` (see the module doc)."""

    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    STATE: ClassVar[tuple[str, ...]] = ()
    CONSTANT: ClassVar[tuple[str, ...]] = ()
    UNITS: ClassVar[dict[str, dict[str, float]]] = {}
    CHECK_OUTPUTS: ClassVar[bool] = True

    # filled by __init_subclass__
    _table: ClassVar[tuple[Var, ...]] = ()
    VR: ClassVar[dict[str, int]] = {}
    _feedthrough: ClassVar[bool] = False
    _table_values: ClassVar[Any] = None
    _state_values: ClassVar[Any] = None
    _default_state: ClassVar[bool] = False
    _checks: ClassVar[dict] = {}

    _BOOKKEEPING = _BOOKKEEPING

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        # rollback snapshots bypass get_state/set_state where they are the defaults (see _capture)
        cls._default_state = cls.get_state is TableSlave.get_state and cls.set_state is TableSlave.set_state
        names = cls.STATE
        valid = isinstance(names, tuple) and all(isinstance(n, str) and n.isidentifier() for n in names)
        cls._state_values = staticmethod(_values_getter(names)) if valid else None   # invalid: TableError below
        if not cls.__dict__.get("VARIABLES"):
            return  # an intermediate abstract base
        reserved = {n for n in dir(TableSlave) if not n.startswith("_")} | {
            "vars", "instance_name", "resources", "visible", "log_queue", "guid", "author", "license",
            "version", "copyright", "modelName", "description", "default_experiment", "refused_steps",
            "last_refusal"}
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
        cls._feedthrough = has_evaluate
        # per-step fast paths: all table values at once, the finiteness and range checks of each group
        cls._table_values = staticmethod(_values_getter(tuple(v.attr for v in table)))
        cls._checks = {}
        for causalities, check_range in ((_IN_PAR, True), (_OUT, False)):
            rows = [v for v in table if v.causality in causalities and v.type != "Boolean"]
            reals = _values_getter(tuple(v.attr for v in rows if v.type == "Real"))
            ranged = tuple((v.attr, -math.inf if v.min is None else v.min, math.inf if v.max is None else v.max)
                           for v in rows if check_range and (v.min is not None or v.max is not None))
            cls._checks[causalities, check_range] = (reals, ranged)

    # ------------------------------------------------------------------ construction
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        cls = type(self)
        if not cls._table:
            raise TableError(f"{cls.__name__} has no VARIABLES table")
        self.modelName = cls.__name__
        self._time = 0.0
        self._dirty = False
        self._initialized = False
        self._init_error: str | None = None
        self._broken: str | None = None
        self.refused_steps = 0          # diagnostics only, not part of the FMU state
        self.last_refusal: str | None = None
        self._pylog = logging.getLogger(f"fmu_src.{cls.__name__}")
        self._base_attrs = set(self.__dict__) | {"_base_attrs"}
        for v in cls._table:
            setattr(self, v.attr, _PY_TYPE[v.type](v.start) if v.start is not None else _PY_TYPE[v.type]())
            self.register_variable(self._make_variable(v), nested=False)
        self.setup()

    def _make_variable(self, v: Var):
        attr, conv = v.attr, _PY_TYPE[v.type]
        marks_dirty = self._feedthrough and (v.causality == "input" or v.variability == "tunable")
        if v.is_output and self._feedthrough:
            def getter():
                if self._dirty:
                    self._refresh()
                return getattr(self, attr)
        else:
            def getter():
                return getattr(self, attr)
        if marks_dirty:
            def setter(value):
                setattr(self, attr, conv(value))
                self._dirty = True
        else:
            def setter(value):
                setattr(self, attr, conv(value))
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

    def get_state(self) -> Any:
        """A picklable snapshot of the whole internal state."""
        snap = {v.attr: getattr(self, v.attr) for v in self._table}
        snap.update({a: getattr(self, a) for a in self.STATE})
        return snap

    def set_state(self, snapshot: Any) -> None:
        for key, value in snapshot.items():
            setattr(self, key, value)

    # ------------------------------------------------------------------ pythonfmu interface
    def setup_experiment(self, start_time: float, stop_time=None, tolerance=None):
        self._time = float(start_time)

    def exit_initialization_mode(self):
        self._initialized = True
        try:
            self.on_initialized()
            if self._feedthrough and not self._non_finite(("input", "parameter")):
                self.evaluate()
            self._dirty = False
        except Exception as exc:  # never let an exception reach the C wrapper (it would be fmi2Fatal)
            self._init_error = f"{type(exc).__name__}: {exc}"
            self._report(f"initialization failed: {self._init_error}", Fmi2Status.error)

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self._broken:
            return self._refuse(current_time, step_size, f"instance unusable: {self._broken}")
        if self._init_error:
            return self._refuse(current_time, step_size, f"initialization failed: {self._init_error}")
        if not (math.isfinite(current_time) and math.isfinite(step_size) and step_size >= 0.0):
            return self._refuse(current_time, step_size, f"invalid communication step size {step_size!r}")
        bad = self._non_finite(("input", "parameter"))
        if bad:
            return self._refuse(current_time, step_size, "invalid " + "; ".join(bad))
        try:
            snapshot = self._capture()
        except Exception as exc:
            return self._refuse(current_time, step_size, f"the state does not pickle: {type(exc).__name__}: {exc}")
        try:
            self.step(current_time, step_size)
            if self._feedthrough:
                self.evaluate()
            if self.CHECK_OUTPUTS:
                bad = self._non_finite(("output",), check_range=False)
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

    # An exception in these two would reach the C wrapper as fmi2Fatal: report and degrade instead
    # (an unusable snapshot makes every later step refuse with the reason).
    def _get_fmu_state(self) -> bytes:
        self._warn_undeclared()
        try:
            return self._snapshot()
        except Exception as exc:
            reason = f"fmi2GetFMUstate failed: {type(exc).__name__}: {exc}"
            self._report(reason, Fmi2Status.error)
            return pickle.dumps(("unusable", reason))

    def _set_fmu_state(self, state: bytes) -> None:
        try:
            self._restore(state)
        except Exception as exc:
            self._broken = f"fmi2SetFMUstate failed: {type(exc).__name__}: {exc}"
            self._report(self._broken, Fmi2Status.error)

    @staticmethod
    def _fmu_state_to_bytes(state: bytes) -> bytes:
        return state

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> bytes:
        return bytes(state)

    # ------------------------------------------------------------------ internals
    def _snapshot(self) -> bytes:
        book = {k: getattr(self, k) for k in self._BOOKKEEPING}
        return pickle.dumps((book, self.get_state()), protocol=pickle.HIGHEST_PROTOCOL)

    def _capture(self) -> _Capture:
        """Rollback snapshot (in memory, as deep as the pickle of :meth:`_snapshot`; module docstring)."""
        book = _book_values(self)
        if self._default_state:
            table = self._table_values(self)
            if _IMMUTABLE.issuperset(map(type, table)) or all(map(_immutable, table)):
                return _Capture(book, table, dict(zip(self.STATE, self._state_values(self))))
        return _Capture(book, None, self.get_state())

    def _restore(self, blob) -> None:
        if type(blob) is _Capture:
            if blob.table is not None:
                for v, value in zip(self._table, blob.table):
                    setattr(self, v.attr, value)
                for key, value in blob.state().items():
                    setattr(self, key, value)
            else:
                self.set_state(blob.state())
            for key, value in zip(_BOOKKEEPING, blob.book):
                setattr(self, key, value)
            return
        book, snap = pickle.loads(blob)
        if book == "unusable":
            raise RuntimeError(snap)
        self.set_state(snap)
        for key, value in book.items():
            setattr(self, key, value)

    def _rollback_and_refuse(self, snapshot, t: float, dt: float, msg: str) -> bool:
        try:
            self._restore(snapshot)
        except Exception as exc:  # the state is no longer trustworthy: refuse everything from now on
            self._broken = f"rollback failed ({type(exc).__name__}: {exc}) after: {msg}"
            msg = self._broken
        return self._refuse(t, dt, msg)

    def _non_finite(self, causalities: tuple[str, ...], check_range: bool = True) -> list[str]:
        fast = self._checks.get((causalities, check_range))
        if fast is not None:
            # all Real values finite <=> their sum is (NaN and inf propagate; a finite overflow to inf
            # only sends us to the exact loop below), then the declared ranges
            reals, ranged = fast
            try:
                ok = math.isfinite(sum(reals(self)))
            except TypeError:
                ok = False
            if ok:
                for attr, lo, hi in ranged:
                    value = getattr(self, attr)
                    if value < lo or value > hi:
                        break
                else:
                    return []
        bad = []
        for v in self._table:
            if v.causality not in causalities or v.type == "Boolean":
                continue
            value = getattr(self, v.attr)
            if v.type == "Real" and not math.isfinite(value):
                bad.append(f"{v.causality} {v.name!r} = {value!r}")
            elif check_range and ((v.min is not None and value < v.min) or (v.max is not None and value > v.max)):
                bad.append(f"{v.causality} {v.name!r} = {value!r} outside [{v.min}, {v.max}]")
        return bad

    def _refresh(self) -> None:
        """Lazy direct feedthrough for fmi2Get*: never raises (that would be fmi2Fatal)."""
        self._dirty = False
        bad = self._non_finite(("input", "parameter"))
        if bad:
            self._report("outputs not updated, invalid " + "; ".join(bad), Fmi2Status.warning)
            return
        snapshot = None
        try:
            snapshot = self._capture()
            self.evaluate()
        except Exception as exc:
            if snapshot is not None:
                self._rollback_quietly(snapshot)
            self._report(f"outputs not updated, evaluate() failed: {type(exc).__name__}: {exc}",
                         Fmi2Status.warning)

    def _rollback_quietly(self, snapshot) -> None:
        try:
            self._restore(snapshot)
        except Exception as exc:
            self._broken = f"rollback failed ({type(exc).__name__}: {exc})"
        self._dirty = False

    def _refuse(self, t: float, dt: float, msg: str) -> bool:
        full = (f"{type(self).__name__} instance {self.instance_name!r}: step [{t!r}, {t + dt!r}] refused "
                f"(fmi2Discard, state kept at t={self._time!r}): {msg}")
        self.refused_steps += 1
        self.last_refusal = full
        self._report(full, Fmi2Status.error)
        return False

    def _report(self, msg: str, status: Fmi2Status) -> None:
        # the C wrapper hands the text to the host logger as its printf *format* argument (FMI 2.0
        # defines the message that way): escape '%' or a '%s' in an exception text reads garbage
        self.log(msg.replace("%", "%%"), status)
        self._pylog.log(logging.ERROR if status >= Fmi2Status.discard else logging.WARNING, "%s", msg)

    def _warn_undeclared(self) -> None:
        extra = self.undeclared_attributes()
        if extra:
            self._report(f"attributes not covered by the FMU state (declare them in STATE or CONSTANT): "
                         f"{sorted(extra)}", Fmi2Status.warning)

    def undeclared_attributes(self) -> set[str]:
        """Instance attributes that are neither table variables, STATE, CONSTANT nor bookkeeping."""
        known = self._base_attrs | {v.attr for v in self._table} | set(self.STATE) | set(self.CONSTANT)
        return set(self.__dict__) - known
