"""The baselines the tracker must beat, with the tracker's interface.

* :class:`NewtonTracker`: Newton-Raphson on the three constraints from the
  previous pose (the usual practice, paper section 1).
* :class:`PredictorNewtonTracker`: Newton from the eq. 22 predictor.
* :class:`CLDKTracker`: Siciliano's closed-loop direct kinematics: the
  feed-forward ``-J^-1 K dq`` plus the closed-loop correction
  ``-lambda J^-1 F`` (error dynamics ``e' = -lambda e``), run with
  ``lambda h = 0.5`` until the constraint error is at rounding level, so that
  its errors are branch errors and not lag.
* :class:`NearestTracker`: all six DK solutions, the real one nearest the previous pose.
* :class:`NewtonSeparationTracker`: Newton from the previous pose, flagged ``certain``
  when every other real DK solution is more than :data:`SEPARATION` times farther
  from the result than the step it made: a separation margin, the usual heuristic
  a certificate is compared with (it can be wrong and certain).

The other baselines never vouch (``certain`` is False): a benchmark counts all
their errors as silent.

All use the compiled primitives of the tracker (same residual, Jacobian and
DK code), so their times compare like with like.
"""
from __future__ import annotations

import numpy as np

from ._kernels import layout as _lay
from ._kernels.baseline_entry import baseline_entry
from ._kernels.c_entry import CMD_ADVANCE, CMD_PACKED, CMD_TRACK, IO_SIZE, make_table
from .manipulator import Manipulator
from .ordering import DEFAULT_RULE, rule_code
from .tracking import _TrackerBase

__all__ = ["NewtonTracker", "PredictorNewtonTracker", "CLDKTracker", "NearestTracker", "NewtonSeparationTracker",
           "BASELINES", "SEPARATION"]

#: Newton and CLDK stop at this residual max|F_i| (m^2).
NEWTON_TOL = 1e-14
#: NewtonSeparationTracker: certain when the nearest other real solution is this many steps away.
SEPARATION = 3.0


class _Baseline(_TrackerBase):
    kind = -1

    def __init__(self, model: Manipulator, rule: str = DEFAULT_RULE):
        super().__init__(model)
        self._rule = rule_code(rule)
        self._params = _lay.pack_baseline_params(self._w, NEWTON_TOL, SEPARATION)
        self._out_real[_lay.OUT_BOUND:_lay.OUT_BOUND + 3] = np.inf   # a baseline proves no pose bound
        self._entry_table()

    def _entry_table(self) -> None:
        """The table of the baseline's arrays its compiled entry reads (:mod:`._kernels.baseline_entry`):
        a step is one call of four scalars, its joints written into ``io`` first."""
        self._io = np.zeros(IO_SIZE)
        self._q_in = self._io[:3]
        self._table = make_table(self.kind, self._rule, dict(
            a=self._flat, pk=self._state_pack, model=self._model_pack, s2s=self._sample_to_sextic,
            params=self._params, out_real=self._out_real, out_int=self._out_int, io=self._io))
        self._table_address = int(self._table.ctypes.data)

    def _kernel(self, q, deadline):
        self._q_in[...] = q
        baseline_entry(self._table_address, CMD_PACKED, 0.0, 0.0)

    def _advance(self, q, dt, deadline, a):
        self._q_in[...] = q                     # (a is the flat state, which the table holds)
        return baseline_entry(self._table_address, CMD_ADVANCE, dt, 0.0)

    def _loop(self, table):
        return baseline_entry(int(table.ctypes.data), CMD_TRACK, 0.0, 0.0)


class NewtonTracker(_Baseline):
    """Newton-Raphson on F(X, q) = 0 started at the previous pose (at most 50 iterations)."""

    kind = _lay.BASELINE_NEWTON
    name = "newton"


class PredictorNewtonTracker(_Baseline):
    """Newton-Raphson started at the eq. 22 prediction ``X_prev - J^-1 K dq``."""

    kind = _lay.BASELINE_PREDICTOR_NEWTON
    name = "newton-predictor"


class CLDKTracker(_Baseline):
    """Closed-loop direct kinematics (Siciliano): feed-forward + damped closed-loop correction."""

    kind = _lay.BASELINE_CLDK
    name = "cldk"


class NearestTracker(_Baseline):
    """The real DK solution nearest (eq. 19 distance) to the previous pose."""

    kind = _lay.BASELINE_NEAREST
    name = "nearest"


class NewtonSeparationTracker(_Baseline):
    """Newton from the previous pose with a separation flag (see the module docstring)."""

    kind = _lay.BASELINE_NEWTON_SEPARATION
    name = "newton-separation"


#: The baseline classes by name.
BASELINES = {c.name: c for c in (NewtonTracker, PredictorNewtonTracker, CLDKTracker, NearestTracker,
                                 NewtonSeparationTracker)}
