"""Compiled building blocks shared by the dynamics kernels: the kinematics core's inverse kinematics
on the ``arm`` pack, finiteness, refusal codes and the work arrays of one configuration.  The angle wrap and
the 3x3 algebra are the solver's (:mod:`solver._kernels.linalg`), the one family of them."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from solver._kernels.kinematics import ik_leg

from .layout import (ARM_L1, ARM_L2, ARM_MOTORS, ARM_PLATFORM, OK, STATUS_SPAN, WS_AUG, WS_BETA, WS_FORCES, WS_JQ,
                     WS_JX, WS_LEG, WS_M, WS_MX, WS_SIZE, WS_U, WS_V, WS_V3, WS_VJ)


# ----------------------------------------------------------------------------- helpers
@njit(cache=True, error_model="numpy")
def ik_arm(arm, x, y, phi, bits, q):
    """The kinematics core's inverse kinematics (:func:`solver._kernels.kinematics.ik_leg`, leg by leg
    as :func:`solver.ik` runs it, so the angles are that function's to the last bit) of one pose on
    the ``arm`` pack, posture elbow bits ``bits``, into ``q`` (3,); False if a leg cannot reach.

    It reads the pack's scalars in place: 2-D views of the pack (what :func:`solver._kernels.kinematics.ik_pose`
    takes) cost more to make than the whole inverse kinematics."""
    c, s = math.cos(phi), math.sin(phi)
    for i in range(3):
        ok, qi = ik_leg(x, y, c, s, arm[ARM_MOTORS + 2 * i], arm[ARM_MOTORS + 2 * i + 1], arm[ARM_L1 + i],
                        arm[ARM_L2 + i], arm[ARM_PLATFORM + 2 * i], arm[ARM_PLATFORM + 2 * i + 1], (bits >> i) & 1)
        if not ok:
            return False
        q[i] = qi
    return True


@njit(cache=True, error_model="numpy")
def finite(v):
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@njit(cache=True)
def code(status, index):
    """The refusal code of ``status`` at ``index`` (``OK`` stays 0)."""
    return status if status == OK else status + STATUS_SPAN * index


@njit(cache=False)
def workspace(buf):
    """The work arrays of one configuration as views of ``buf`` (``WS_SIZE``,): leg table (9, 3),
    J_q, J_x, V (21, 3), beta (21,), M_X, M, forces (6, 3), V J_x (21, 3), a 3x3 scratch (a
    transposed matrix) and two 3-vectors."""
    return (buf[WS_LEG:WS_JQ].reshape(9, 3), buf[WS_JQ:WS_JX].reshape(3, 3), buf[WS_JX:WS_V].reshape(3, 3),
            buf[WS_V:WS_BETA].reshape(21, 3), buf[WS_BETA:WS_MX], buf[WS_MX:WS_M].reshape(3, 3),
            buf[WS_M:WS_FORCES].reshape(3, 3), buf[WS_FORCES:WS_VJ].reshape(6, 3), buf[WS_VJ:WS_AUG].reshape(21, 3),
            buf[WS_AUG:WS_U].reshape(3, 3), buf[WS_U:WS_V3], buf[WS_V3:WS_SIZE])


@njit(cache=True)
def new_workspace():
    """:func:`workspace` of a new buffer."""
    return workspace(np.empty(WS_SIZE))
