"""The computed-torque law, compiled: the commanded acceleration and the inverse dynamics at it.

``v = ddq_d + K_d (dq_d - dq) + K_p wrap(q_d - q)`` (the wrap is the kinematics core's,
:func:`solver._kernels.linalg.wrap`) and ``tau = M v + C dq + G + F`` (:func:`.rows.joint_row`,
mode ``INVERSE``).  :func:`computed_torque_batch` runs :func:`dynamics.computed_torque`; the
controller's step (:mod:`.steps`) calls :func:`commanded_acceleration` itself.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from solver._kernels.linalg import wrap

from .base import code, finite, new_workspace
from .layout import BAD_INPUT, INVERSE, OK
from .rows import joint_row


@njit(cache=True, error_model="numpy")
def commanded_acceleration(gains, q, dq, q_d, dq_d, ddq_d, v):
    """``v = ddq_d + K_d (dq_d - dq) + K_p wrap(q_d - q)`` into ``v`` (3,); ``gains`` is ``(kp, kd)``."""
    for i in range(3):
        v[i] = ddq_d[i] + gains[3 + i] * (dq_d[i] - dq[i]) + gains[i] * wrap(q_d[i] - q[i])


@njit(cache=True, error_model="numpy")
def computed_torque_batch(arm, bodies, gains, q, dq, X, q_d, dq_d, ddq_d, tol, out):
    """Computed torque, the inverse dynamics at the commanded acceleration,
    ``tau = M v + C dq + G + F`` (:func:`commanded_acceleration`, :func:`.rows.joint_row` INVERSE),
    over the rows of the (n, 3) arrays; returns :data:`OK` or the refusal code of the first row refused."""
    ws = new_workspace()
    v = np.empty(3)
    for k in range(q.shape[0]):
        if not (finite(q_d[k]) and finite(dq_d[k]) and finite(ddq_d[k])):
            return code(BAD_INPUT, k)
        commanded_acceleration(gains, q[k], dq[k], q_d[k], dq_d[k], ddq_d[k], v)
        st = joint_row(arm, bodies, q[k], dq[k], X[k], v, tol, INVERSE, out[k], ws)
        if st != OK:
            return code(st, k)
    return OK
