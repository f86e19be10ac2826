"""fmi2Set* / fmi2Get* of a table slave by value reference: the mixin :class:`ValueAccess`.

Part of the FMU runtime (bundled into every FMU): it imports nothing.  pythonfmu's C wrapper calls
``set_real(vrs, values)``, ``get_real(vrs)``... with lists of value references; pythonfmu answers
them through one ``ScalarVariable`` object and one getter or setter closure per value, with a type
check each.  Here one dictionary lookup per value reference gives the attribute (the tables are
built per class by :class:`fmu_src.table_slave.TableSlave`): the same values set and returned,
the same conversions (``float``, ``int``, ``bool``), the same staleness of direct-feedthrough
outputs (an input set marks them; a get of one refreshes them first, :meth:`TableSlave._refresh`)
and, in Initialization Mode, of every output (any set marks them; :meth:`TableSlave.initial_outputs`).
What the fast path does not take (an unknown reference, one of another type, a value that does
not convert) goes to pythonfmu's own methods, which raise as they always did.

Relies on the class attributes ``_attrs`` ({FMI type: {value reference: attribute}}),
``_real_attrs``, ``_marks_dirty``, ``_refreshing``, ``_feedthrough`` and on ``_dirty``/``_refresh``.
"""
from __future__ import annotations

__all__ = ["ValueAccess"]


class ValueAccess:
    """The fmi2Set*/fmi2Get* methods of :class:`fmu_src.table_slave.TableSlave` (a mixin)."""

    # the Real ones are written out: they are the calls of every step
    def set_real(self, vrs, values):
        attrs = self._real_attrs
        try:
            for vr, value in zip(vrs, values):
                setattr(self, attrs[vr], float(value))
        except (KeyError, TypeError, ValueError, OverflowError):
            return super().set_real(vrs, values)
        if self._init_mode or (self._feedthrough and not self._marks_dirty.isdisjoint(vrs)):
            self._dirty = True

    def get_real(self, vrs):
        if self._dirty and (self._init_mode or not self._refreshing.isdisjoint(vrs)):
            self._refresh()
        attrs = self._real_attrs
        try:
            return [float(getattr(self, attrs[vr])) for vr in vrs]
        except (KeyError, TypeError, ValueError, OverflowError):
            return super().get_real(vrs)

    def set_integer(self, vrs, values):
        self._set(vrs, values, self._attrs["Integer"], int) or super().set_integer(vrs, values)

    def set_boolean(self, vrs, values):
        self._set(vrs, values, self._attrs["Boolean"], bool) or super().set_boolean(vrs, values)

    def get_integer(self, vrs):
        out = self._get(vrs, self._attrs["Integer"], int)
        return super().get_integer(vrs) if out is None else out

    def get_boolean(self, vrs):
        out = self._get(vrs, self._attrs["Boolean"], bool)
        return super().get_boolean(vrs) if out is None else out

    def _set(self, vrs, values, attrs: dict, conv) -> bool:
        """Set ``values`` by reference (what each variable's setter does); False: not taken."""
        try:
            for vr, value in zip(vrs, values):
                setattr(self, attrs[vr], conv(value))
        except (KeyError, TypeError, ValueError, OverflowError):
            return False
        if self._init_mode or (self._feedthrough and not self._marks_dirty.isdisjoint(vrs)):
            self._dirty = True
        return True

    def _get(self, vrs, attrs: dict, conv) -> list | None:
        """The values of ``vrs`` (what each variable's getter returns); None: not taken."""
        if self._dirty and (self._init_mode or not self._refreshing.isdisjoint(vrs)):
            self._refresh()
        try:
            return [conv(getattr(self, attrs[vr])) for vr in vrs]
        except (KeyError, TypeError, ValueError, OverflowError):
            return None
