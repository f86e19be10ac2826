"""What a slave checks before it trusts its values, and the lazy refresh of its outputs for fmi2Get*.

A mixin of :class:`fmu_src.table_slave.TableSlave` (it relies on its table, ``_checks``, the
rollback of :mod:`fmu_src.slave_state` and ``_report``): the finiteness and range checks of the
inputs and parameters before a step or a refresh, of the outputs after it, and the direct
feedthrough an ``fmi2Get*`` triggers after an ``fmi2Set*`` (in Initialization Mode:
``initial_outputs``).  Neither refresh ever raises (that would be fmi2Fatal).
"""
from __future__ import annotations

import math

from pythonfmu.enums import Fmi2Status

__all__ = ["ValueChecks"]

_IN_PAR = ("input", "parameter")
_OUT = ("output",)


class ValueChecks:
    """Finiteness and range checks of the table's values; the outputs' lazy refresh."""

    def _all_finite(self, check: tuple) -> bool:
        """The fast path of :meth:`_non_finite`: True if every Real value of the group is finite
        and every ranged value in its range (False: ask :meth:`_non_finite` which).

        All Real values are finite iff their sum is (NaN and inf propagate; a finite overflow to
        inf only sends the caller to the exact loop, which then finds nothing).
        """
        reals, ranged = check
        try:
            if not math.isfinite(sum(reals(self))):
                return False
        except TypeError:
            return False
        for attr, lo, hi in ranged:
            value = getattr(self, attr)
            if value < lo or value > hi:
                return False
        return True

    def _non_finite(self, causalities: tuple[str, ...], check_range: bool = True) -> list[str]:
        """Descriptions of the non-finite (and, with ``check_range``, out-of-range) values of the
        variables of ``causalities``; [] if there are none."""
        fast = self._checks.get((causalities, check_range))
        if fast is not None and self._all_finite(fast):
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
        if self._init_mode:
            self._refresh_initial()
            return
        bad = self._non_finite(_IN_PAR)
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

    def _refresh_initial(self) -> None:
        """The outputs in Initialization Mode (:meth:`initial_outputs`); never raises."""
        if not self._has_initial_outputs:
            return
        bad = self._non_finite(_IN_PAR)
        if bad:
            self._report("initial outputs not computed, invalid " + "; ".join(bad), Fmi2Status.warning)
            return
        try:
            self.initial_outputs()
        except Exception as exc:
            self._report(f"initial outputs not computed: {type(exc).__name__}: {exc}", Fmi2Status.warning)
