"""One tracker step for the robot as built: the joint width of the step's pose box, and its check.

:mod:`solver.geometry_tolerance` turns the robot's geometric tolerance into a joint half-width over a
box of poses and joints. A step of :class:`solver.Tracker` with a non-zero ``geometry_tolerance``
(:func:`step_width`) runs its certificates with ``joint_tolerance + eps``, ``eps`` that width over

* the step's pose box: the hull of the last pose and the one predicted for this sample (the last step's
  motion again), widened by the last proven bound, a quarter of that motion and at least 5e-4 of the
  robot's reach and 2e-3 rad;
  after an uncertain step with a speed bound, the region the platform can have reached since the last
  certain step (the one re-acquisition searches), with half as much again; after an uncertain step
  without one, the whole tool space;
* the joints between the last reading and this one, widened by ``joint_tolerance``.

After the step (:func:`inside`): a certain step's pose box (its pose +- ``pose_bound``) must lie in
the box the width was computed over; else the step runs once more with the width of the hull of both,
and a step that still leaves it, or whose width is infinite (an elbow may be straight in the box),
is not vouched for. The tube between two samples is taken to stay in the hull of their boxes (its
ends are proved there; a step's joint motion is small against the box's allowance).
"""
from __future__ import annotations

import math

import numpy as np

from ._kernels import geometry_width as _gw
from ._kernels import layout as _lay
from .geometry_tolerance import GeometryTolerance, joint_equivalent

__all__ = ["as_built_step", "step_constants", "step_box", "step_width", "inside", "hull"]

#: Iterations of the width's fixed point (:func:`solver._kernels.geometry_width.joint_width`).
WIDTH_ITERATIONS = 5

#: Runs of a step at most: the box grows to the hull of the proven box each time.
ATTEMPTS = 4

#: A retry's box holds the proven box widened by this factor (its wider joint width widens the bound).
HULL_MARGIN = 1.25

#: The least motion allowance of a step's pose box: a fraction of the robot's reach (m) and an angle (rad).
MOTION_FLOOR = (5e-4, 2e-3)


_NAN3 = np.full(3, np.nan)


def step_box(state, reach: float, speed_bound, dt, tool_space) -> tuple[np.ndarray, np.ndarray]:
    """The pose box (lo, hi), each (3,) m, m, rad, of a step from ``state`` (module docstring)."""
    lo, hi = np.empty(3), np.empty(3)
    _gw.step_box(*_box_args(state, reach, speed_bound, dt, tool_space), lo, hi)
    return lo, hi


def _box_args(state, reach, speed_bound, dt, tool_space):
    age = state.anchor_age + state.skipped_time + (dt if dt is not None else math.nan)
    return (state.X, _NAN3 if state.X2 is None else state.X2, np.asarray(state.anchor_bound, float),
            state.uncertain_since < 0, _NAN3 if state.anchor is None else state.anchor, age,
            np.zeros(2) if speed_bound is None else np.asarray(speed_bound, float),
            np.array([MOTION_FLOOR[0] * reach, MOTION_FLOOR[0] * reach, MOTION_FLOOR[1]]), tool_space)


def step_width(model, tolerance: GeometryTolerance, box, q_prev, q, joint_tolerance: float) -> float:
    """The joint half-width (rad or m) of the robot as built over the pose ``box`` (lo, hi) and the joints
    between ``q_prev`` and ``q`` (3,) widened by ``joint_tolerance``; ``inf`` when none covers it."""
    if tolerance.zero:
        return 0.0
    if model.kind == "3-RPR":
        return joint_equivalent(model, tolerance, *box, q_prev, q)
    return float(_gw.step_width(model.motors, model.l1, model.platform, model.platform_radius,
                                tolerance.offset_bound(), np.asarray(box[0], float), np.asarray(box[1], float),
                                np.asarray(q_prev, float), np.asarray(q, float), float(joint_tolerance), True,
                                WIDTH_ITERATIONS))


def inside(box, X, bound) -> bool:
    """The pose box ``X +- bound`` (3,) lies in ``box`` (lo, hi); phi unwrapped about the box's centre (a box
    spanning a turn holds every phi)."""
    lo, hi = np.array(box[0], float), np.array(box[1], float)
    return bool(_gw.box_holds(lo, hi, np.asarray(X, float), np.asarray(bound, float), HULL_MARGIN))


def hull(box, X, bound) -> tuple[np.ndarray, np.ndarray]:
    """The smallest box holding ``box`` (lo, hi) and ``X +- HULL_MARGIN * bound`` (phi unwrapped about the
    box), or ``box`` itself when it holds ``X +- bound``."""
    lo, hi = np.array(box[0], float), np.array(box[1], float)
    _gw.box_holds(lo, hi, np.asarray(X, float), np.asarray(bound, float), HULL_MARGIN)
    return lo, hi


def step_constants(model, tolerance: GeometryTolerance, reach: float, speed_bound) -> tuple:
    """What every step of one tracker passes the kernels unchanged: the legs' offset bounds ``e`` (3,), m,
    the motion floor (3,), the speed bound (2,) (0: none)."""
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
            break
        if attempt < ATTEMPTS - 1 and math.isfinite(eps):   # the pose left the box: again over the hull
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
