"""fmi2Set* / fmi2Get* of a table slave by value reference: the mixin :class:`ValueAccess`.

Part of the FMU runtime (bundled into every FMU): it imports pythonfmu's status enum only.  pythonfmu's C wrapper calls
``set_real(vrs, values)``, ``get_real(vrs)``... with lists of value references; pythonfmu answers
them through one ``ScalarVariable`` object and one getter or setter closure per value, with a type
check each.  Here one dictionary lookup per value reference gives the attribute (the tables are
built per class by :class:`fmu_src.table_slave.TableSlave`): the same values set and returned,
the same conversions (``float``, ``int``, ``bool``), the same staleness of direct-feedthrough
outputs (an input set marks them; a get of one refreshes them first, :meth:`fmu_src.value_checks.ValueChecks._refresh`)
and, in Initialization Mode, of every output (any set marks them; :meth:`TableSlave.initial_outputs`).

Every call keeps the FMI 2.0 state table (:mod:`fmu_src.fmi_states`): a set is refused as a whole
(nothing set, one message) when the state forbids it or when a value reference is not settable now
(unknown, another type, or a variable the state does not let change); a get is refused when the
state forbids it (NaN for each Real, the current value of each Integer/Boolean), and an unknown
reference reads NaN / 0 / False with a message.  Nothing here raises: an exception would be
fmi2Fatal and pythonfmu would release the instance.

Relies on the class attributes ``_attrs`` ({FMI type: {value reference: attribute}}),
``_real_attrs``, ``_marks_dirty``, ``_refreshing``, ``_feedthrough``, on the flags of
:class:`fmu_src.fmi_states.FmiStates` and on ``_dirty``/``_refresh``.
"""
from __future__ import annotations

from pythonfmu.enums import Fmi2Status

__all__ = ["ValueAccess"]

_NAN = float("nan")
_MISSING = {"Real": _NAN, "Integer": 0, "Boolean": False, "String": ""}


class ValueAccess:
    """The fmi2Set*/fmi2Get* methods of :class:`fmu_src.table_slave.TableSlave` (a mixin)."""

    # the Real ones are written out: they are the calls of every step
    def set_real(self, vrs, values):
        if not self._settable_real.issuperset(vrs):
            self._set_refused("Real", vrs)
            return
        attrs = self._real_attrs
        try:
            for vr, value in zip(vrs, values):
                setattr(self, attrs[vr], float(value))
        except (TypeError, ValueError) as exc:     # in process only: the C wrapper passes doubles
            self._refuse_call("fmi2SetReal", f", a value does not convert ({type(exc).__name__}: {exc}; "
                                             "the values before it were set)")
            return
        if self._init_mode or (self._feedthrough and not self._marks_dirty.isdisjoint(vrs)):
            self._dirty = True

    def get_real(self, vrs):
        if not self._can_get and not self._allowed("fmi2GetReal"):
            return [_NAN] * len(vrs)
        if self._dirty and (self._init_mode or not self._refreshing.isdisjoint(vrs)):
            self._refresh()
        attrs = self._real_attrs
        try:
            return [float(getattr(self, attrs[vr])) for vr in vrs]
        except KeyError:
            return self._get_unknown("Real", vrs, attrs, float)

    def set_integer(self, vrs, values):
        self._set("Integer", vrs, values, int)

    def set_boolean(self, vrs, values):
        self._set("Boolean", vrs, values, bool)

    def set_string(self, vrs, values):
        self._set("String", vrs, values, str)

    def get_integer(self, vrs):
        return self._get("Integer", vrs, int)

    def get_boolean(self, vrs):
        return self._get("Boolean", vrs, bool)

    def get_string(self, vrs):
        return self._get("String", vrs, str)

    def _set(self, kind: str, vrs, values, conv) -> None:
        """Set ``values`` by reference (what each variable's setter does), or refuse the call."""
        if self._set_refused(kind, vrs):
            return
        attrs = self._attrs[kind]
        try:
            converted = [conv(value) for value in values]
        except (TypeError, ValueError, OverflowError) as exc:
            self._refuse_call("fmi2Set" + kind, f", a value does not convert ({type(exc).__name__}: {exc})")
            return
        for vr, value in zip(vrs, converted):
            setattr(self, attrs[vr], value)
        if self._init_mode or (self._feedthrough and not self._marks_dirty.isdisjoint(vrs)):
            self._dirty = True

    def _get(self, kind: str, vrs, conv) -> list:
        """The values of ``vrs`` (what each variable's getter returns), or the refusal's values.  An
        empty get reads nothing, in every state (the C loader makes one before fmi2FreeInstance)."""
        if not len(vrs):
            return []
        attrs = self._attrs.get(kind, {})
        if not self._can_get and not self._allowed("fmi2Get" + kind):
            return [conv(getattr(self, attrs[vr])) if vr in attrs else _MISSING[kind] for vr in vrs]
        if self._dirty and (self._init_mode or not self._refreshing.isdisjoint(vrs)):
            self._refresh()
        try:
            return [conv(getattr(self, attrs[vr])) for vr in vrs]
        except KeyError:
            return self._get_unknown(kind, vrs, attrs, conv)

    def _get_unknown(self, kind: str, vrs, attrs: dict, conv) -> list:
        """A get with a reference that is not a variable of ``kind``: log, answer the missing value."""
        bad = [vr for vr in vrs if vr not in attrs]
        msg = (f"{type(self).__name__} instance {self.instance_name!r}: fmi2Get{kind}: no {kind} variable with "
               f"value reference(s) {bad} (valid: {sorted(attrs)}); answered {_MISSING[kind]!r} "
               f"({self._returned(Fmi2Status.ok)})")
        self.refused_calls += 1
        self.last_call_refusal = msg
        self._report(msg, Fmi2Status.error)
        self._hand_off(Fmi2Status.error)
        return [conv(getattr(self, attrs[vr])) if vr in attrs else _MISSING[kind] for vr in vrs]
