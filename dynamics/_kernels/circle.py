"""The circle reference of :class:`dynamics.trajectory.CircleTrajectory`, compiled.

The time law and the geometry are derived in :mod:`dynamics.trajectory`; here they run with
scalar code, one time at a time, on the ``circle`` pack (:mod:`.layout`).  The joint-space part
runs the kinematics core's inverse kinematics (:func:`.base.ik_arm`: the core's ``ik_leg``, what
:func:`solver.ik` runs), so the reference angles are that function's to the last bit.
"""
from __future__ import annotations

import math

from numba import njit

from .base import code, ik_arm, new_workspace
from .layout import (BAD_INPUT, CIRCLE_CENTER_X, CIRCLE_CENTER_Y, CIRCLE_PHI, CIRCLE_RADIUS, CIRCLE_RAMP,
                     CIRCLE_RATE, CIRCLE_START, LEG_DDQ0, LEG_DQ, OK, OUTSIDE, SINGULAR)
from .rows import geometry_row, motion_row


@njit(cache=True, error_model="numpy")
def polar_row(circle, t):
    """The time law: polar angle ``theta``, its rate and its acceleration at time ``t`` (finite)."""
    rate, ramp, start = circle[CIRCLE_RATE], circle[CIRCLE_RAMP], circle[CIRCLE_START]
    if ramp == 0.0:
        return start + rate * max(t, 0.0), (rate if t >= 0 else 0.0), 0.0
    u = min(max(t / ramp, 0.0), 1.0)
    if t < ramp:
        S = u ** 4.0 * (2.5 - 3.0 * u + u * u)           # integral of s
        s = u ** 3.0 * (10.0 - 15.0 * u + 6.0 * u * u)
        ds = 30.0 * u * u * (1.0 - u) ** 2.0
        return start + rate * ramp * S, rate * s, rate * ds / ramp
    return start + rate * (t - 0.5 * ramp), rate, 0.0


@njit(cache=True, error_model="numpy")
def polar_batch(circle, t, out):
    """:func:`polar_row` at the times ``t`` (n,) (finite) into ``out`` (n, 3)."""
    for k in range(t.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = polar_row(circle, t[k])


@njit(cache=True, error_model="numpy")
def circle_task_row(circle, t, X, dX, ddX):
    """Pose, rate and acceleration of the circle at time ``t`` (finite) into ``X, dX, ddX`` (3,)."""
    theta, dth, ddth = polar_row(circle, t)
    c, s_ = math.cos(theta), math.sin(theta)
    r = circle[CIRCLE_RADIUS]
    X[0] = circle[CIRCLE_CENTER_X] + r * c
    X[1] = circle[CIRCLE_CENTER_Y] + r * s_
    X[2] = circle[CIRCLE_PHI]
    dX[0] = -r * s_ * dth
    dX[1] = r * c * dth
    dX[2] = 0.0
    dth2 = dth ** 2.0
    ddX[0] = -r * s_ * ddth - r * c * dth2
    ddX[1] = r * c * ddth - r * s_ * dth2
    ddX[2] = 0.0


@njit(cache=True, error_model="numpy")
def circle_joint_row(arm, bodies, circle, bits, t, X, dX, ddX, q, dq, ddq, leg, Jq, beta):
    """Task- and joint-space reference at ``t``: ``X, dX, ddX`` as :func:`circle_task_row`,
    ``q = g_j(X)`` (solver's IK), ``dq = J_q dX``, ``ddq = J_q ddX + ddq_0(X, dX)``.

    ``bodies`` only fills the unused centre-of-mass rows of ``beta``; ``leg, Jq, beta`` are work
    arrays.  Returns :data:`OK`, :data:`BAD_INPUT` (``t`` not finite), :data:`OUTSIDE` (no IK
    solution) or :data:`SINGULAR`.
    """
    if not math.isfinite(t):
        return BAD_INPUT
    circle_task_row(circle, t, X, dX, ddX)
    if not ik_arm(arm, X[0], X[1], X[2], bits, q):
        return OUTSIDE
    rcx, rcy, res = geometry_row(arm, bodies, X[0], X[1], X[2], q, leg, Jq)
    motion_row(arm, bodies, dX[0], dX[1], dX[2], rcx, rcy, leg, Jq, beta)
    for i in range(3):
        dq[i] = leg[LEG_DQ, i]
        ddq[i] = (Jq[i, 0] * ddX[0] + Jq[i, 1] * ddX[1] + Jq[i, 2] * ddX[2]) + leg[LEG_DDQ0, i]
    for i in range(3):
        if not (math.isfinite(dq[i]) and math.isfinite(ddq[i])):
            return SINGULAR
    return OK


@njit(cache=True, error_model="numpy")
def circle_batch(arm, bodies, circle, bits, t, joint, X, dX, ddX, q, dq, ddq):
    """The circle reference at the times ``t`` (n,) into the (n, 3) arrays; the joint-space part
    only when ``joint``.  Returns :data:`OK` or the refusal code of the first time refused."""
    ws = new_workspace()
    leg, Jq, beta = ws[0], ws[1], ws[4]
    for k in range(t.shape[0]):
        if not math.isfinite(t[k]):
            return code(BAD_INPUT, k)
        if joint:
            st = circle_joint_row(arm, bodies, circle, bits, t[k], X[k], dX[k], ddX[k], q[k], dq[k], ddq[k],
                                  leg, Jq, beta)
            if st != OK:
                return code(st, k)
        else:
            circle_task_row(circle, t[k], X[k], dX[k], ddX[k])
    return OK
