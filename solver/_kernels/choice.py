"""The tracker's predictor and choice rules, compiled: the joint step, the continuation along it,
and the eq. 19 distance with the nearest solution to a prediction (shared with the baselines).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kinematics import velocity
from .linalg import wrap


@njit(cache=True)
def joint_step(q, qp, dq):
    """The joint step ``dq = q - qp`` (3,) with wrapped angles, written in place; returns max|dq_i|."""
    dqn = 0.0
    for i in range(3):
        dq[i] = wrap(q[i] - qp[i])
        dqn = max(dqn, abs(dq[i]))
    return dqn


@njit(cache=True)
def continuation(X0, q0, dq, nsub, M, l1, l2sq, b, out):
    """Integrate J dX = -K dq along the joint segment q0 + s dq, s in [0, 1] (RK4, ``nsub`` steps).

    Writes the end pose to ``out``; returns the smallest Hadamard ratio of J met.
    """
    h = 1.0 / nsub
    X = X0.copy()
    k1, k2, k3, k4 = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    Xs, qs = np.empty(3), np.empty(3)
    worst = 1.0
    for n in range(nsub):
        s0 = n * h
        for i in range(3):
            qs[i] = q0[i] + s0 * dq[i]
        worst = min(worst, velocity(X, qs, dq, M, l1, l2sq, b, k1))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k1[i]
            qs[i] = q0[i] + (s0 + 0.5 * h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k2))
        for i in range(3):
            Xs[i] = X[i] + 0.5 * h * k2[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k3))
        for i in range(3):
            Xs[i] = X[i] + h * k3[i]
            qs[i] = q0[i] + (s0 + h) * dq[i]
        worst = min(worst, velocity(Xs, qs, dq, M, l1, l2sq, b, k4))
        for i in range(3):
            X[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    out[:] = X
    return worst


@njit(cache=True)
def wdist(a, b, w):
    """Weighted pose distance of eq. 19 with the phi difference wrapped."""
    dp = wrap(a[2] - b[2])
    return math.sqrt(w[0] * (a[0] - b[0]) ** 2 + w[1] * (a[1] - b[1]) ** 2 + w[2] * dp * dp)


@njit(cache=True)
def nearest(poses, real, Xref, w, m1, m2, m3, use_map):
    """The real solution nearest to ``Xref`` among those whose label is in one of the masks
    (all real ones if ``use_map`` is off or none qualifies), and its decisiveness
    ``d_best / d_second`` (0 = certain, 1 = a tie)."""
    Xr = np.empty(3)
    best, second, k_best = np.inf, np.inf, -1
    best_any, second_any, k_any = np.inf, np.inf, -1
    for k in range(6):
        if real[k]:
            for i in range(3):
                Xr[i] = poses[k, i].real
            d = wdist(Xr, Xref, w)
            if d < best_any:
                best_any, second_any, k_any = d, best_any, k
            elif d < second_any:
                second_any = d
            if m1[k + 1] or m2[k + 1] or m3[k + 1]:
                if d < best:
                    best, second, k_best = d, best, k
                elif d < second:
                    second = d
    if not use_map or k_best < 0:
        return k_any, best_any / second_any if second_any > 0 else 1.0
    return k_best, best / second if second > 0 else 1.0
