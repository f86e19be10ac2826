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
def elbow_margins(M, l1, b, b_radius, X_lo, X_hi, q_lo, q_hi, out):
    """``out[i]``: lower bound of ``l1_i |sin alpha_i|`` (m) for poses in ``[X_lo, X_hi]`` and joints
    in ``[q_lo, q_hi]`` (3,); 0 where the box may hold a straight elbow."""
    xc, yc, pc = 0.5 * (X_lo[0] + X_hi[0]), 0.5 * (X_lo[1] + X_hi[1]), 0.5 * (X_lo[2] + X_hi[2])
    dxy = math.hypot(0.5 * (X_hi[0] - X_lo[0]), 0.5 * (X_hi[1] - X_lo[1]))
    dphi = min(0.5 * (X_hi[2] - X_lo[2]), math.pi)
    c, s = math.cos(pc), math.sin(pc)
    for i in range(3):
        qc, dq = 0.5 * (q_lo[i] + q_hi[i]), min(0.5 * (q_hi[i] - q_lo[i]), math.pi)
        ux, uy = math.cos(qc), math.sin(qc)
        vx = xc + c * b[i, 0] - s * b[i, 1] - M[i, 0] - l1[i] * ux
        vy = yc + s * b[i, 0] + c * b[i, 1] - M[i, 1] - l1[i] * uy
        nv = math.hypot(vx, vy)
        dv = dxy + b_radius[i] * dphi + l1[i] * dq            # how far the rod B - A can move: chord <= arc
        if not (nv > 0.0 and dv < nv):
            out[i] = 0.0
            continue
        turn = dq + math.asin(dv / nv)
        out[i] = l1[i] * max(abs(ux * vy - uy * vx) / nv - turn, 0.0)


@njit(cache=True)
def joint_width(M, l1, b, b_radius, e, X_lo, X_hi, q_lo, q_hi, iterations):
    """``max_i eps_i`` (rad) with ``e_i / m_i(joints widened by eps) <= eps_i``; ``inf`` when none is found."""
    eps = np.zeros(3)
    m = np.empty(3)
    lo, hi = np.empty(3), np.empty(3)
    for _ in range(iterations + 1):
        for i in range(3):
            lo[i], hi[i] = q_lo[i] - eps[i], q_hi[i] + eps[i]
        elbow_margins(M, l1, b, b_radius, X_lo, X_hi, lo, hi, m)
        done = True
        for i in range(3):
            if m[i] <= 0.0:
                return math.inf
            if e[i] / m[i] > eps[i]:
                done = False
        if done:
            return max(eps[0], max(eps[1], eps[2]))
        for i in range(3):                                     # a quarter more: the fixed point in a step or two
            eps[i] = max(eps[i], 1.25 * e[i] / m[i])
    return math.inf
