"""The joint width of the robot as built over a box of poses and joints (:mod:`solver.geometry_tolerance`).

``elbow_margins``: per leg a lower bound of ``l1_i |sin alpha_i|`` over the box (``alpha_i`` the
elbow angle); ``joint_width``: the fixed point ``eps = e / m(joints widened by eps)``, ``inf`` when
an elbow may be straight. Scalars only: a step calls it once (about a microsecond).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _leg_margin(mx, my, l1, bx, by, b_radius, x0, x1, y0, y1, p0, p1, q0, q1):
    """Lower bound of ``l1 |sin alpha|`` (m) of one leg over the box ``[x0, x1] x [y0, y1] x [p0, p1]``
    of poses and ``[q0, q1]`` of its joint, from the box's centre: ``|sin alpha| >= |sin alpha_c| - turn``."""
    xc, yc, pc, qc = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (p0 + p1), 0.5 * (q0 + q1)
    dxy = math.hypot(0.5 * (x1 - x0), 0.5 * (y1 - y0))
    dphi, dq = min(0.5 * (p1 - p0), math.pi), min(0.5 * (q1 - q0), math.pi)
    c, s = math.cos(pc), math.sin(pc)
    ux, uy = math.cos(qc), math.sin(qc)
    vx = xc + c * bx - s * by - mx - l1 * ux
    vy = yc + s * bx + c * by - my - l1 * uy
    nv = math.hypot(vx, vy)
    dv = dxy + b_radius * dphi + l1 * dq                    # how far the rod B - A can move: chord <= arc
    if not (nv > 0.0 and dv < nv):
        return 0.0
    return l1 * max(abs(ux * vy - uy * vx) / nv - dq - math.asin(dv / nv), 0.0)


#: Sub-boxes one leg's margin may split its box into (bisections where the centre's bound is loose).
MAX_PIECES = 256


@njit(cache=True)
def elbow_margins(M, l1, b, b_radius, X_lo, X_hi, q_lo, q_hi, out):
    """``out[i]``: lower bound of ``l1_i |sin alpha_i|`` (m) for poses in ``[X_lo, X_hi]`` and joints
    in ``[q_lo, q_hi]`` (3,); 0 where the box may hold a straight elbow.  A box whose bound is below
    half its centre's value is bisected along its widest side (in m: x, y, phi times the joint's
    radius, the joint times l1), up to :data:`MAX_PIECES` pieces: the least piece's bound."""
    stack = np.empty((MAX_PIECES + 1, 8))
    for i in range(3):
        stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = X_lo[0], X_hi[0], X_lo[1], X_hi[1]
        stack[0, 4], stack[0, 5], stack[0, 6], stack[0, 7] = X_lo[2], X_hi[2], q_lo[i], q_hi[i]
        n, pieces, best = 1, 1, math.inf
        while n > 0:
            n -= 1
            x0, x1, y0, y1, p0, p1, q0, q1 = (stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3], stack[n, 4],
                                              stack[n, 5], stack[n, 6], stack[n, 7])
            m = _leg_margin(M[i, 0], M[i, 1], l1[i], b[i, 0], b[i, 1], b_radius[i], x0, x1, y0, y1, p0, p1, q0, q1)
            if m >= best:
                continue
            mc = _leg_margin(M[i, 0], M[i, 1], l1[i], b[i, 0], b[i, 1], b_radius[i], 0.5 * (x0 + x1), 0.5 * (x0 + x1),
                             0.5 * (y0 + y1), 0.5 * (y0 + y1), 0.5 * (p0 + p1), 0.5 * (p0 + p1),
                             0.5 * (q0 + q1), 0.5 * (q0 + q1))
            if m >= 0.5 * mc or pieces + 1 > MAX_PIECES or n + 2 > MAX_PIECES:
                best = min(best, m)
                continue
            w = (x1 - x0, y1 - y0, b_radius[i] * (p1 - p0), l1[i] * (q1 - q0))
            k = 0
            for j in range(1, 4):
                if w[j] > w[k]:
                    k = j
            for h in range(2):                                  # the two halves along side k
                for j in range(8):
                    stack[n, j] = (x0, x1, y0, y1, p0, p1, q0, q1)[j]
                lo, hi = stack[n, 2 * k], stack[n, 2 * k + 1]
                mid = 0.5 * (lo + hi)
                if h == 0:
                    stack[n, 2 * k + 1] = mid
                else:
                    stack[n, 2 * k] = mid
                n += 1
            pieces += 1
        out[i] = best if math.isfinite(best) else 0.0


@njit(cache=True)
def joint_width(M, l1, b, b_radius, e, X_lo, X_hi, q_lo, q_hi, iterations):
    """``max_i eps_i`` (rad) with ``e_i / m_i(joints widened by eps) <= eps_i``: the iteration
    ``eps <- e / m(eps)`` from 0 (increasing, to the least fixed point), a twentieth more, verified;
    ``inf`` when it is not. Continuous in its inputs (no iteration count depends on rounding)."""
    eps = np.zeros(3)
    m = np.empty(3)
    lo, hi = np.empty(3), np.empty(3)
    for _ in range(iterations):
        for i in range(3):
            lo[i], hi[i] = q_lo[i] - eps[i], q_hi[i] + eps[i]
        elbow_margins(M, l1, b, b_radius, X_lo, X_hi, lo, hi, m)
        for i in range(3):
            if m[i] <= 0.0:
                return math.inf
            eps[i] = e[i] / m[i]
    for i in range(3):
        eps[i] *= 1.05
        lo[i], hi[i] = q_lo[i] - eps[i], q_hi[i] + eps[i]
    elbow_margins(M, l1, b, b_radius, X_lo, X_hi, lo, hi, m)
    for i in range(3):
        if not (m[i] > 0.0 and e[i] / m[i] <= eps[i]):
            return math.inf
    return max(eps[0], max(eps[1], eps[2]))


@njit(cache=True)
def step_box(X, X2, bound, certain_before, anchor, age, speed, floor, tool_space, lo, hi):
    """The pose box ``[lo, hi]`` (3,) of a step (:mod:`solver.as_built`): after a certain step the hull
    of the last pose ``X`` and the one predicted (``X2`` the pose before, NaN: none) widened by the
    proven ``bound``, a quarter of the motion and ``floor``; after an uncertain one with a speed bound
    (``speed`` (2,), 0: none) the region reached since the ``anchor`` (widened by half), else the tool
    space (3, 2)."""
    finite = math.isfinite(bound[0]) and math.isfinite(bound[1]) and math.isfinite(bound[2])
    if certain_before and finite:
        for a in range(3):
            d = 0.0
            if math.isfinite(X2[a]):
                d = X[a] - X2[a]
                if a == 2:
                    d = d - 2.0 * math.pi * round(d / (2.0 * math.pi))
            s = bound[a] + 0.25 * abs(d) + floor[a]
            lo[a] = min(X[a], X[a] + d) - s
            hi[a] = max(X[a], X[a] + d) + s
        return
    if speed[0] > 0.0 and finite and math.isfinite(anchor[0]) and math.isfinite(age):
        for a in range(3):
            r = 1.5 * (bound[a] + (speed[0] if a < 2 else speed[1]) * age)
            lo[a], hi[a] = anchor[a] - r, anchor[a] + r
        return
    for a in range(3):
        lo[a], hi[a] = tool_space[a, 0], tool_space[a, 1]


@njit(cache=True)
def step_width(M, l1, b, b_radius, e, lo, hi, q_prev, q, joint_tol, angles, iterations):
    """:func:`joint_width` over the pose box ``[lo, hi]`` and the joints between ``q_prev`` and ``q`` (3,)
    (``angles``: the short way round) widened by ``joint_tol``; ``inf`` for an unbounded box."""
    q_lo, q_hi, X_lo, X_hi = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for a in range(3):
        if not (math.isfinite(lo[a]) and math.isfinite(hi[a])):
            return math.inf
        X_lo[a], X_hi[a] = lo[a], hi[a]
        qa = q[a]
        if angles:
            d = qa - q_prev[a]
            qa = q_prev[a] + d - 2.0 * math.pi * round(d / (2.0 * math.pi))
        q_lo[a], q_hi[a] = min(q_prev[a], qa) - joint_tol, max(q_prev[a], qa) + joint_tol
    if X_hi[2] - X_lo[2] >= 2.0 * math.pi:
        X_lo[2], X_hi[2] = -math.pi, math.pi
    return joint_width(M, l1, b, b_radius, e, X_lo, X_hi, q_lo, q_hi, iterations)


@njit(cache=True)
def box_holds(lo, hi, X, bound, margin):
    """Whether ``[lo, hi]`` holds the pose box ``X +- bound`` (phi unwrapped about the box's centre; a
    box spanning a turn holds every phi); if not, ``[lo, hi]`` grows to hold ``X +- margin * bound``."""
    c = 0.5 * (lo[2] + hi[2])
    d = X[2] - c
    x2 = c + d - 2.0 * math.pi * round(d / (2.0 * math.pi))
    ok = True
    for a in range(3):
        xa = x2 if a == 2 else X[a]
        if not (lo[a] <= xa - bound[a] and xa + bound[a] <= hi[a]) and not (a == 2 and hi[2] - lo[2] >= 2 * math.pi):
            ok = False
    if not ok:
        for a in range(3):
            xa = x2 if a == 2 else X[a]
            lo[a] = min(lo[a], xa - margin * bound[a])
            hi[a] = max(hi[a], xa + margin * bound[a])
    return ok
