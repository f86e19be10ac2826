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

All use the compiled primitives of the tracker (same residual, Jacobian and
DK code), so their times compare like with like.
"""
from __future__ import annotations

import numpy as np

from . import _track_kernel as _tk
from .kinematics import _RULE_CODES, DEFAULT_RULE
from .manipulator import Manipulator
from .tracker import _TrackerBase

__all__ = ["NewtonTracker", "PredictorNewtonTracker", "CLDKTracker", "NearestTracker", "BASELINES"]

#: Newton and CLDK stop at this residual max|F_i| (m^2).
NEWTON_TOL = 1e-14


class _Baseline(_TrackerBase):
    kind = -1

    def __init__(self, model: Manipulator, rule: str = DEFAULT_RULE):
        super().__init__(model)
        self._rule = _RULE_CODES[rule]
        self._bpar = np.concatenate([self._w, [NEWTON_TOL]])

    def _kernel(self, q, st):
        _tk.baseline_step_packed(self.kind, self._rule, q, st, self._geo, self._T, self._bpar, self._out_f,
                                 self._ii)


class NewtonTracker(_Baseline):
    """Newton-Raphson on F(X, q) = 0 started at the previous pose (at most 50 iterations)."""

    kind = 0
    name = "newton"


class PredictorNewtonTracker(_Baseline):
    """Newton-Raphson started at the eq. 22 prediction ``X_prev - J^-1 K dq``."""

    kind = 1
    name = "newton-predictor"


class CLDKTracker(_Baseline):
    """Closed-loop direct kinematics (Siciliano): feed-forward + damped closed-loop correction."""

    kind = 2
    name = "cldk"


class NearestTracker(_Baseline):
    """The real DK solution nearest (eq. 19 distance) to the previous pose."""

    kind = 3
    name = "nearest"


#: The baseline classes by name.
BASELINES = {c.name: c for c in (NewtonTracker, PredictorNewtonTracker, CLDKTracker, NearestTracker)}
