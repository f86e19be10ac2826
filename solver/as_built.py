"""One tracker step for the robot as built: the joint width of the step's pose box, and its check.

:mod:`solver.geometry_tolerance` turns the robot's geometric tolerance into a joint half-width over a
box of poses and joints. A step of :class:`solver.Tracker` with a non-zero ``geometry_tolerance``
(:func:`as_built_step`) runs its certificates with ``joint_tolerance + eps``, ``eps`` that width
(:func:`solver._kernels.geometry_width.step_width`) over

* the step's pose box (:func:`solver._kernels.geometry_width.step_box`): the hull of the last pose and
  the one predicted for this sample (the last step's motion again), widened by the last proven bound,
  a quarter of that motion and at least :data:`MOTION_FLOOR` (5e-4 of the robot's reach, 2e-3 rad);
  after an uncertain step with a speed bound, the region the platform can have reached since the last
  certain step (the one re-acquisition searches), with half as much again; after an uncertain step
  without one, the whole tool space;
* the joints between the last reading and this one (the short way round), widened by
  ``joint_tolerance``.

After the step (:func:`solver._kernels.geometry_width.box_holds`): a certain step's pose box (its pose
+- ``pose_bound``) must lie in the box the width was computed over; else the box grows to hold it
(with :data:`HULL_MARGIN`) and the step runs again with the width of that box (at most
:data:`ATTEMPTS` runs); a step that still leaves it, or whose width is infinite (an elbow may be
straight in the box), is not vouched for. The tube between two samples is taken to stay in the hull
of their boxes (its ends are proved there; a step's joint motion is small against the box's allowance).
"""
from __future__ import annotations

import math

import numpy as np

from ._kernels import geometry_width as _gw
from ._kernels import layout as _lay
from .geometry_tolerance import GeometryTolerance, joint_equivalent

__all__ = ["as_built_step", "step_constants", "step_width", "WIDTH_ITERATIONS", "ATTEMPTS", "HULL_MARGIN",
           "MOTION_FLOOR"]

#: Iterations of the width's fixed point (:func:`solver._kernels.geometry_width.joint_width`).
WIDTH_ITERATIONS = 5

#: Runs of a step at most: the box grows to hold the proven box each time.
ATTEMPTS = 4

#: A retry's box holds the proven box widened by this factor (its wider joint width widens the bound).
HULL_MARGIN = 1.25

#: The least motion allowance of a step's pose box: a fraction of the robot's reach (m) and an angle (rad).
MOTION_FLOOR = (5e-4, 2e-3)

_NAN3 = np.full(3, np.nan)


def step_width(model, tolerance: GeometryTolerance, box, q_prev, q, joint_tolerance: float) -> float:
    """The joint half-width (rad or m) of the robot as built over the pose ``box`` (lo, hi), each (3,) m,
    m, rad, and the joints between ``q_prev`` and ``q`` (3,) widened by ``joint_tolerance``; ``inf`` when
    none covers it (what :meth:`solver.Tracker.reset` adds over its start region)."""
    if tolerance.zero:
        return 0.0
    if model.kind == "3-RPR":
        return joint_equivalent(model, tolerance, *box, q_prev, q)
    return float(_gw.step_width(model.motors, model.l1, model.platform, model.platform_radius,
                                tolerance.offset_bound(), np.asarray(box[0], float), np.asarray(box[1], float),
                                np.asarray(q_prev, float), np.asarray(q, float), float(joint_tolerance), True,
                                WIDTH_ITERATIONS))


def step_constants(model, tolerance: GeometryTolerance, reach: float, speed_bound) -> tuple:
    """What every step of one tracker passes the kernels unchanged: the legs' offset bounds ``e`` (3,), m,
    the motion floor (3,) (m, m, rad; ``reach`` in m), the speed bound (2,) (m/s, rad/s; 0: none)."""
    return (np.ascontiguousarray(tolerance.offset_bound()),
            np.array([MOTION_FLOOR[0] * reach, MOTION_FLOOR[0] * reach, MOTION_FLOOR[1]]),
            np.zeros(2) if speed_bound is None else np.asarray(speed_bound, float))


def as_built_step(tracker, q, state_pack, deadline) -> None:
    """Run ``tracker``'s compiled step to joints ``q`` (3,) for the robot as built (module docstring):
    its certificates with ``joint_tolerance`` plus the step's joint width; its result packs as the plain
    step leaves them, with ``certain`` withdrawn where no width covers the step's poses."""
    st, model = tracker.state, tracker.model
    e, floor, speed = tracker._as_built
    jt = tracker.joint_tolerance
    lo, hi = np.empty(3), np.empty(3)
    dt = tracker._dt
    age = st.anchor_age + st.skipped_time + (dt if dt is not None else math.nan)
    _gw.step_box(st.X, _NAN3 if st.X2 is None else st.X2, st.anchor_bound, st.uncertain_since < 0,
                 _NAN3 if st.anchor is None else st.anchor, age, speed, floor, tracker._tool_space, lo, hi)
    rpr = model.kind == "3-RPR"
    width = ((lambda: float(np.max(e))) if rpr else
             (lambda: _gw.step_width(model.motors, model.l1, model.platform, model.platform_radius, e, lo, hi,
                                     st.q, q, jt, True, WIDTH_ITERATIONS)))
    eps = width()
    saved = tracker._anytime.copy() if deadline else None
    params, of, oi = tracker._params, tracker._out_real, tracker._out_int
    for attempt in range(ATTEMPTS):
        params[_lay.PARAM_JOINT_TOL] = jt + (eps if math.isfinite(eps) else 0.0)
        tracker._run(q, state_pack, deadline)
        if not oi[_lay.I_CERTAIN]:
            break
        X, bound = of[_lay.OUT_X:_lay.OUT_X + 3], of[_lay.OUT_BOUND:_lay.OUT_BOUND + 3]
        if math.isfinite(eps) and _gw.box_holds(lo, hi, X, bound, HULL_MARGIN):
            break                                        # (box_holds grew [lo, hi] when it did not hold)
        if attempt < ATTEMPTS - 1 and math.isfinite(eps):   # the pose left the box: again over the grown box
            wider = width()
            if math.isfinite(wider):
                eps = max(eps, wider)
                if saved is not None:
                    tracker._anytime[:] = saved
                continue
        oi[_lay.I_CERTAIN] = oi[_lay.I_INTACT] = 0       # no width covers the robot as built: not vouched for
        oi[_lay.I_TRUST] = min(int(oi[_lay.I_TRUST]), _lay.TRUST_POSSIBLE)
        break
    params[_lay.PARAM_JOINT_TOL] = jt
