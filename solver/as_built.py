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

from ._kernels import layout as _lay
from .geometry_tolerance import GeometryTolerance, joint_equivalent

__all__ = ["as_built_step", "step_box", "step_width", "inside", "hull"]

#: Runs of a step at most: the box grows to the hull of the proven box each time.
ATTEMPTS = 4

#: A retry's box holds the proven box widened by this factor (its wider joint width widens the bound).
HULL_MARGIN = 1.25

#: The least motion allowance of a step's pose box: a fraction of the robot's reach (m) and an angle (rad).
MOTION_FLOOR = (5e-4, 2e-3)


def step_box(state, q, reach: float, speed_bound, dt, tool_space) -> tuple[np.ndarray, np.ndarray]:
    """The pose box (lo, hi), each (3,) m, m, rad, a step from ``state`` to joints ``q`` is checked over."""
    X = state.X
    bound = np.asarray(state.anchor_bound, float)
    certain_before = state.uncertain_since < 0
    if certain_before and np.all(np.isfinite(bound)):
        floor = np.array([MOTION_FLOOR[0] * reach, MOTION_FLOOR[0] * reach, MOTION_FLOOR[1]])
        if state.X2 is None:
            return X - bound - floor, X + bound + floor
        motion = X - state.X2
        motion[2] = math.remainder(motion[2], 2 * math.pi)
        ahead = X + motion                                   # the pose predicted for this sample
        slack = bound + 0.25 * np.abs(motion) + floor
        return np.minimum(X, ahead) - slack, np.maximum(X, ahead) + slack
    if speed_bound is not None and state.anchor is not None and np.all(np.isfinite(bound)):
        age = state.anchor_age + state.skipped_time + (dt if dt is not None else math.nan)
        if math.isfinite(age):
            v, w = speed_bound
            allow = 1.5 * (bound + np.array([v * age, v * age, w * age]))
            return state.anchor - allow, state.anchor + allow
    return tool_space[:, 0].copy(), tool_space[:, 1].copy()


def step_width(model, tolerance: GeometryTolerance, box, q_prev, q, joint_tolerance: float) -> float:
    """The joint half-width (rad or m) of the robot as built over the pose ``box`` (lo, hi) and the joints
    between ``q_prev`` and ``q`` (3,) widened by ``joint_tolerance``; ``inf`` when none covers it."""
    lo, hi = box
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        return math.inf
    if model.kind == "3-RRR":                        # angles: the joint step the short way round (a wrap at pi)
        q = q_prev + np.remainder(q - q_prev + math.pi, 2 * math.pi) - math.pi
    q_lo = np.minimum(q_prev, q) - joint_tolerance
    q_hi = np.maximum(q_prev, q) + joint_tolerance
    if hi[2] - lo[2] >= 2 * math.pi:
        lo, hi = lo.copy(), hi.copy()
        lo[2], hi[2] = -math.pi, math.pi
    return joint_equivalent(model, tolerance, lo, hi, q_lo, q_hi)


def inside(box, X, bound) -> bool:
    """The pose box ``X +- bound`` (3,) lies in ``box`` (lo, hi); phi unwrapped about the box's centre (a box
    spanning a turn holds every phi)."""
    lo, hi = box
    Xu = _unwrapped(box, X)
    b = np.asarray(bound, float)
    ok = (lo <= Xu - b) & (Xu + b <= hi)
    return bool(ok[0] and ok[1] and (ok[2] or hi[2] - lo[2] >= 2 * math.pi))


def _unwrapped(box, X) -> np.ndarray:
    lo, hi = box
    Xu = np.asarray(X, float).copy()
    c = 0.5 * (lo[2] + hi[2])
    Xu[2] = c + math.remainder(Xu[2] - c, 2 * math.pi)
    return Xu


def hull(box, X, bound) -> tuple[np.ndarray, np.ndarray]:
    """The smallest box holding ``box`` (lo, hi) and ``X +- HULL_MARGIN * bound`` (phi unwrapped about the box)."""
    lo, hi = box
    Xu = _unwrapped(box, X)
    b = HULL_MARGIN * np.asarray(bound, float)        # a margin: the wider width widens the bound a little
    return np.minimum(lo, Xu - b), np.maximum(hi, Xu + b)


def as_built_step(tracker, q, state_pack, deadline) -> None:
    """Run ``tracker``'s compiled step to joints ``q`` (3,) for the robot as built (module docstring):
    its certificates with ``joint_tolerance`` plus the step's joint width; its result packs as the plain
    step leaves them, with ``certain`` withdrawn where no width covers the step's poses."""
    st, model, tol = tracker.state, tracker.model, tracker.geometry_tolerance
    box = step_box(st, q, tracker._reach, tracker.speed_bound, tracker._dt, tracker._tool_space)
    eps = step_width(model, tol, box, st.q, q, tracker.joint_tolerance)
    saved = tracker._anytime.copy()
    params, of, oi = tracker._params, tracker._out_real, tracker._out_int
    for attempt in range(ATTEMPTS):
        params[_lay.PARAM_JOINT_TOL] = tracker.joint_tolerance + (eps if math.isfinite(eps) else 0.0)
        tracker._run(q, state_pack, deadline)
        if not oi[_lay.I_CERTAIN]:
            break
        X, bound = of[_lay.OUT_X:_lay.OUT_X + 3], of[_lay.OUT_BOUND:_lay.OUT_BOUND + 3]
        if math.isfinite(eps) and inside(box, X, bound):
            break
        if attempt < ATTEMPTS - 1 and math.isfinite(eps):   # the pose left the box: again over the hull
            box = hull(box, X, bound)
            wider = step_width(model, tol, box, st.q, q, tracker.joint_tolerance)
            if math.isfinite(wider):
                eps = max(eps, wider)
                tracker._anytime[:] = saved
                continue
        oi[_lay.I_CERTAIN] = oi[_lay.I_INTACT] = 0       # no width covers the robot as built: not vouched for
        oi[_lay.I_TRUST] = min(int(oi[_lay.I_TRUST]), _lay.TRUST_POSSIBLE)
        break
    params[_lay.PARAM_JOINT_TOL] = tracker.joint_tolerance
