"""A tracker's options: one frozen object, checked once against one table.

``Tracker(model, map, options=TrackerOptions(joint_tolerance=1e-4))`` and ``Tracker(model, map,
joint_tolerance=1e-4)`` are the same tracker: the keywords make the options object.  Every scalar
option is checked by :func:`solver.checks.check_number` against its row of :data:`BOUNDS`; the
others (``mode``, the tuples) by :meth:`TrackerOptions.__post_init__`.  What each option means:
:class:`solver.Tracker`.  The robot-dependent ones (``geometry_tolerance``, the default
``start_tolerance``) are resolved by the tracker, which knows the robot.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ._kernels.layout import STRATEGY_SEGMENT
from .checks import Bound, as_array, check_number
from .state_array import TrackerError

__all__ = ["TrackerOptions", "BOUNDS", "MAX_TESTS", "GATE", "REACQUIRE_BOXES", "MODES"]

#: Krawczyk tests one chain of certificates may use (a step runs one chain, or one per real solution
#: while the branch is unknown); beyond it the step is not certified.
MAX_TESTS = 2000

#: With measured joints (``joint_tolerance > 0``): a sample is refused as an outlier when its joint
#: step differs from the one expected (constant joint velocity) by more than the noise allows,
#: ``2 tol (1 + r)``, plus ``GATE`` times the envelope of recent differences, and that difference
#: moves the pose more than noise could (see "Sensors" in :mod:`solver.tracker`).
GATE = 4.0

#: With measured joints: pose boxes one re-acquisition may examine (see "Sensors").
REACQUIRE_BOXES = 10000

#: The tracker's modes (see :mod:`solver.tracker`).
MODES = ("default", "paper")

#: The scalar options and what each may be.
BOUNDS = {
    "r": Bound(none=True, unit="m"),
    "ambiguity_ratio": Bound(),
    "jump_factor": Bound(),
    "singular_tol": Bound(),
    "segment_singular": Bound(open=False),
    "max_tests": Bound(integer=True),
    "joint_tolerance": Bound(open=False, unit="rad"),
    "gate": Bound(open=False),
    "reacquire_boxes": Bound(integer=True, open=False),
    "stuck_after": Bound(integer=True, open=False),
    "step_budget": Bound(none=True, unit="s"),
}


@dataclass(frozen=True)
class TrackerOptions:
    """Everything a :class:`solver.Tracker` is told besides its robot and map (see its parameters).

    Attributes are the tracker's keyword arguments, checked when the object is made
    (:class:`solver.tracker_state.TrackerError`, naming the option, its value and what was expected);
    tuples replace the array-likes (``weights``, ``speed_bound``, ``start_tolerance``), floats and ints
    the numbers.
    """

    mode: str = "default"
    r: float | None = None
    weights: tuple | None = None
    ambiguity_ratio: float = 0.25
    jump_factor: float = 20.0
    singular_tol: float = 1e-4
    use_map: bool = True
    strategy: int = STRATEGY_SEGMENT
    segment_singular: float = 0.05
    posture_certificate: bool = True
    max_tests: int = MAX_TESTS
    joint_tolerance: float = 0.0
    gate: float = GATE
    speed_bound: tuple | None = None
    reacquire_boxes: int = REACQUIRE_BOXES
    stuck_after: int = 0
    start_tolerance: tuple | None = None
    step_budget: float | None = None
    geometry_tolerance: object = 0.0

    def __post_init__(self):
        put = object.__setattr__
        if self.mode not in MODES:
            raise TrackerError(f"mode: expected one of {MODES}, got {self.mode!r}")
        for name, bound in BOUNDS.items():
            put(self, name, check_number(name, getattr(self, name), bound, TrackerError))
        for name in ("use_map", "posture_certificate"):
            put(self, name, bool(getattr(self, name)))
        if self.weights is not None:
            w = as_array("weights", self.weights, (3,))
            if w.shape != (3,) or not np.all(w > 0):
                raise TrackerError(f"weights: expected 3 numbers > 0, got {self.weights!r}")
            put(self, "weights", tuple(w.tolist()))
        if self.speed_bound is not None:
            v = as_array("speed_bound", self.speed_bound, (2,))
            if v.shape != (2,) or not np.all(v > 0):
                raise TrackerError(f"speed_bound: expected (m/s, rad/s), both > 0, or None, got {self.speed_bound!r}")
            put(self, "speed_bound", tuple(v.tolist()))
        if self.start_tolerance is not None:
            r0 = as_array("start_tolerance", self.start_tolerance, (3,))
            if r0.shape != (3,) or not np.all(r0 > 0):
                raise TrackerError(f"start_tolerance: expected 3 half-widths > 0 (m, m, rad), got "
                                   f"{self.start_tolerance!r}")
            put(self, "start_tolerance", tuple(r0.tolist()))
        if self.stuck_after == 1:
            raise TrackerError("stuck_after: expected 0 (off) or at least 2 identical readings, got 1")
        if self.stuck_after and not self.joint_tolerance > 0:
            raise TrackerError(f"stuck_after = {self.stuck_after}: needs joint_tolerance > 0 (measured joints); an "
                               "exact joint at rest repeats its value")

    @classmethod
    def names(cls) -> tuple:
        """The options' names (the tracker's keyword arguments)."""
        return tuple(f.name for f in fields(cls))
