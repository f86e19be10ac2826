"""State handling of a table slave: the FMU state (get/set/serialize) and the rollback snapshots.

Part of the FMU runtime (bundled into every FMU): it imports the standard library and pythonfmu
only (numpy is looked up in ``sys.modules``, never imported).  :class:`StateHandling` is a mixin
of :class:`fmu_src.table_slave.TableSlave`; it relies on the attributes that class sets up
(``_table``, ``STATE``, ``CONSTANT``, ``_report``...).

FMU state: pythonfmu 0.7 keeps the object returned by ``_get_fmu_state`` as the fmi2FMUstate
(no copy) and serializes it with the class-level ``_fmu_state_to_bytes``/``_fmu_state_from_bytes``.
Here that object is an immutable pickle of ``get_state()`` plus the base-class bookkeeping, so a
state can be set any number of times and serializes as is.  fmi2Reset makes a new Python instance.
Serialized states are pickles: deserialize only states this project produced.

Rollback snapshots: every doStep (and every lazy ``evaluate`` for fmi2Get*) first takes a snapshot
it restores if the step is refused.  That snapshot never leaves the process, so it is never a pickle.

* A slave that declares ``IMMUTABLE_STATE = True`` promises that ``step``/``evaluate`` never change
  a ``STATE`` value in place (they assign new values to the attributes, e.g. a new
  ``solver.TrackerState`` or a result array other than the one the attribute holds).  Its snapshot
  is a tuple of references: the bookkeeping, the table values (Python scalars) and the ``STATE``
  values -- one ``operator.attrgetter`` call, no copy, whatever the state holds (< 1 us).
* Otherwise the snapshot is an in-memory copy as deep as the pickle of the FMU state
  (:class:`Capture`): immutable values
(``float``, ``int``, ``bool``, ``str``, ``bytes``, ``None``, numpy scalars, tuples and frozensets of
them) are kept as they are, plain numpy arrays (no Python objects inside) are copied, lists of
immutable values are copied, and whatever else the state holds is pickled as before (so a state
that does not pickle is still refused at the step, with the same message; and when there is such
a value, or two attributes hold the same array or list, the arrays and lists go into that pickle
too, which keeps any sharing between them).  Restoring gives the same values as restoring the
pickle (~2 us for a state of table values and one array).
"""
from __future__ import annotations

import operator
import pickle
import sys
from typing import Any

from pythonfmu.enums import Fmi2Status

__all__ = ["StateHandling", "Capture", "is_immutable", "values_getter", "BOOKKEEPING"]

#: types whose values never change in place (kept as they are in a rollback snapshot); numpy's scalar
#: types are added when first met
IMMUTABLE = {float, int, bool, str, bytes, type(None), complex}
#: the base class's own attributes that an FMU state and a rollback carry with the slave's state
#: (``_fmi_state``: the FMI state machine's state, :mod:`fmu_src.fmi_states`; a set FMU state restores it)
BOOKKEEPING = ("_time", "_dirty", "_fmi_state", "_init_error", "_broken")
_book_values = operator.attrgetter(*BOOKKEEPING)


def values_getter(attrs: tuple):
    """``f(obj) -> tuple`` of the attributes ``attrs`` of ``obj`` (operator.attrgetter, always a tuple)."""
    if not attrs:
        return lambda obj: ()
    if len(attrs) == 1:
        get = operator.attrgetter(attrs[0])
        return lambda obj: (get(obj),)
    return operator.attrgetter(*attrs)


def is_immutable(value) -> bool:
    """True if ``value`` can be kept by reference in a snapshot (it cannot change in place)."""
    t = type(value)
    if t in IMMUTABLE:
        return True
    if t is tuple or t is frozenset:
        return IMMUTABLE.issuperset(map(type, value)) or all(map(is_immutable, value))
    np = sys.modules.get("numpy")          # numpy scalars (never imported here: FMUs bundle this module)
    if np is not None and isinstance(value, (np.number, np.bool_)):
        IMMUTABLE.add(t)
        return True
    return False


class Capture:
    """In-memory rollback snapshot of a table slave (see the module docstring).

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
        odd = [key for key, value in kept.items() if type(value) not in IMMUTABLE]
        if odd:
            np = sys.modules.get("numpy")
            ndarray = np.ndarray if np is not None else None
            for key in odd:
                value = kept[key]
                t = type(value)
                if t is ndarray and not value.dtype.hasobject:
                    arrays[key] = value.copy(order="K")
                elif is_immutable(value):
                    continue
                elif t is list and (IMMUTABLE.issuperset(map(type, value)) or all(map(is_immutable, value))):
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


class StateHandling:
    """The FMU state and rollback methods of :class:`fmu_src.table_slave.TableSlave` (a mixin)."""

    _BOOKKEEPING = BOOKKEEPING

    def get_state(self) -> Any:
        """A picklable snapshot of the whole internal state."""
        snap = {v.attr: getattr(self, v.attr) for v in self._table}
        snap.update({a: getattr(self, a) for a in self.STATE})
        return snap

    def set_state(self, snapshot: Any) -> None:
        for key, value in snapshot.items():
            setattr(self, key, value)

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
            self._enter_state(self._fmi_state)      # the flags of the restored FMI state
        except Exception as exc:
            self._broken = f"fmi2SetFMUstate failed: {type(exc).__name__}: {exc}"
            self._report(self._broken, Fmi2Status.error)

    @staticmethod
    def _fmu_state_to_bytes(state: bytes) -> bytes:
        return state

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> bytes:
        return bytes(state)

    def _snapshot(self) -> bytes:
        book = {k: getattr(self, k) for k in self._BOOKKEEPING}
        return pickle.dumps((book, self.get_state()), protocol=pickle.HIGHEST_PROTOCOL)

    def _capture(self) -> tuple | Capture:
        """Rollback snapshot (in memory; references or as deep as the pickle of :meth:`_snapshot`,
        see the module docstring)."""
        if self.IMMUTABLE_STATE:
            return self._rollback_values(self)
        book = _book_values(self)
        if self._default_state:
            table = self._table_values(self)
            if IMMUTABLE.issuperset(map(type, table)) or all(map(is_immutable, table)):
                return Capture(book, table, dict(zip(self.STATE, self._state_values(self))))
        return Capture(book, None, self.get_state())

    def _restore(self, blob) -> None:
        if type(blob) is tuple:                      # references (IMMUTABLE_STATE)
            for key, value in zip(self._rollback_attrs, blob):
                setattr(self, key, value)
            return
        if type(blob) is Capture:
            if blob.table is not None:
                for v, value in zip(self._table, blob.table):
                    setattr(self, v.attr, value)
                for key, value in blob.state().items():
                    setattr(self, key, value)
            else:
                self.set_state(blob.state())
            for key, value in zip(BOOKKEEPING, blob.book):
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

    def _rollback_quietly(self, snapshot) -> None:
        try:
            self._restore(snapshot)
        except Exception as exc:
            self._broken = f"rollback failed ({type(exc).__name__}: {exc})"
        self._dirty = False

    def _warn_undeclared(self) -> None:
        extra = self.undeclared_attributes()
        if extra:
            self._report(f"attributes not covered by the FMU state (declare them in STATE or CONSTANT): "
                         f"{sorted(extra)}", Fmi2Status.warning)

    def undeclared_attributes(self) -> set[str]:
        """Instance attributes that are neither table variables, STATE, CONSTANT nor bookkeeping."""
        known = self._base_attrs | {v.attr for v in self._table} | set(self.STATE) | set(self.CONSTANT)
        return set(self.__dict__) - known
