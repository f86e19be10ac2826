"""The joint width of the robot as built over a box of poses and joints (:mod:`solver.geometry_tolerance`).

``elbow_margins``: per leg a lower bound of ``l1_i |sin alpha_i|`` over the box (``alpha_i`` the
elbow angle); ``joint_width``: the fixed point ``eps = e / m(joints widened by eps)``, ``inf`` when
an elbow may be straight. Scalars only.  The tracker carries a 3-RRR's tolerance as a constraint slack
(:mod:`solver.as_built`), not as this width; the width is the reduction's own measure (the benchmarks'
fold floor with the geometry box, and the tests of the reduction).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .scratch import floats


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
    eps = floats(3)
    eps[:] = 0.0
    m = floats(3)
    lo, hi = floats(3), floats(3)
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
