"""Named offsets of the packed arrays the kernels take, the packers, status and mode codes.

A kernel reads its constants from a few flat float64 arrays ("packs") built once per model,
parameter set, gain set or trajectory; every read goes through an offset named here.

========================  ======  ==========================================================
pack                      size    content
========================  ======  ==========================================================
``arm``                   18      the :class:`solver.Manipulator`: motors, ``l1``, ``l2``, platform joints
``bodies``                40      the :class:`dynamics.DynamicParameters` as the kernels use them
``gains``                 6       ``kp`` then ``kd`` of :class:`dynamics.ComputedTorqueGains`
``circle``                7       the :class:`dynamics.CircleTrajectory`
``plant``                 58      ``arm`` then ``bodies``: the plant stepper
``controller``            71      ``arm``, ``bodies``, ``gains``, ``circle``: the controller stepper
========================  ======  ==========================================================
"""
from __future__ import annotations

import numpy as np

# ----------------------------------------------------------------------------- arm (18,)
#: motor axes ``M_i``: x of leg i at ``ARM_MOTORS + 2 i``, y at ``ARM_MOTORS + 2 i + 1``
ARM_MOTORS = 0
#: proximal link lengths ``l1_i`` at ``ARM_L1 + i``
ARM_L1 = 6
#: distal link lengths ``l2_i`` at ``ARM_L2 + i``
ARM_L2 = 9
#: platform joints ``b_i`` in the platform frame: x at ``ARM_PLATFORM + 2 i``, y at ``+ 1``
ARM_PLATFORM = 12
ARM_SIZE = 18

# ----------------------------------------------------------------------------- bodies (40,)
#: distance of the proximal centre of mass from the motor, per leg
BODY_COM_PROXIMAL = 0
#: distance of the distal centre of mass from the elbow, per leg
BODY_COM_DISTAL = 3
#: the 21 velocity-row weights (masses and centroidal inertias), rows below
BODY_WEIGHTS = 6
#: the 9 viscous coefficients: motors, elbows, platform joints
BODY_FRICTION = 27
#: gravity (x, y)
BODY_GRAVITY = 36
#: platform centre of mass (x, y) in the platform frame
BODY_COM_PLATFORM = 38
BODY_SIZE = 40

#: the 21 body velocity rows (of ``V``, ``beta`` and the weights): platform x, y, rotation, then
#: per leg i: proximal x, y, rotation (the rotor rides on it), distal x, y, rotation
ROW_PLATFORM_X, ROW_PLATFORM_Y, ROW_PLATFORM_ROT = 0, 1, 2
ROW_PROXIMAL_X, ROW_PROXIMAL_Y, ROW_PROXIMAL_ROT = 3, 6, 9
ROW_DISTAL_X, ROW_DISTAL_Y, ROW_DISTAL_ROT = 12, 15, 18
N_ROWS = 21
#: the 9 friction-carrying joint rates: motors, elbows (relative), platform joints (relative)
FRICTION_MOTOR, FRICTION_ELBOW, FRICTION_PLATFORM = 0, 3, 6
N_FRICTION = 9

# ----------------------------------------------------------------------------- gains (6,), circle (7,)
GAIN_KP, GAIN_KD = 0, 3
GAINS_SIZE = 6

CIRCLE_CENTER_X, CIRCLE_CENTER_Y, CIRCLE_RADIUS, CIRCLE_PHI = 0, 1, 2, 3
#: cruise rate of the polar angle ``Omega``, ramp time, start angle
CIRCLE_RATE, CIRCLE_RAMP, CIRCLE_START = 4, 5, 6
CIRCLE_SIZE = 7

# ----------------------------------------------------------------------------- slave packs
PLANT_ARM, PLANT_BODIES, PLANT_SIZE = 0, ARM_SIZE, ARM_SIZE + BODY_SIZE
CONTROLLER_ARM, CONTROLLER_BODIES = 0, ARM_SIZE
CONTROLLER_GAINS = ARM_SIZE + BODY_SIZE
CONTROLLER_CIRCLE = CONTROLLER_GAINS + GAINS_SIZE
CONTROLLER_SIZE = CONTROLLER_CIRCLE + CIRCLE_SIZE

# ----------------------------------------------------------------------------- step outputs
#: plant step output (13,): new task-space state (X, dX), then q, dq, total energy
PLANT_OUT_STATE, PLANT_OUT_Q, PLANT_OUT_DQ, PLANT_OUT_ENERGY = 0, 6, 9, 12
PLANT_OUT_SIZE = 13
#: controller step output (9,): torque, reference pose, reference joints
CONTROLLER_OUT_TAU, CONTROLLER_OUT_POSE_REF, CONTROLLER_OUT_Q_REF = 0, 3, 6
CONTROLLER_OUT_SIZE = 9
#: where a controller step was refused (the index of its refusal code)
CONTROLLER_PHASE_REFERENCE, CONTROLLER_PHASE_MEASURED = 0, 1

# ----------------------------------------------------------------------------- work arrays
#: one configuration's work arrays (:func:`dynamics._kernels.base.workspace`), in one buffer:
#: per-leg table (9, 3), J_q, J_x, V (21, 3), beta (21,), M_X, M, forces (6, 3), V J_x (21, 3),
#: a 3x3 scratch (a transposed matrix) and two 3-vectors
WS_LEG, WS_JQ, WS_JX, WS_V, WS_BETA, WS_MX, WS_M = 0, 27, 36, 45, 108, 129, 138
WS_FORCES, WS_VJ, WS_AUG, WS_U, WS_V3 = 147, 165, 228, 237, 240
WS_SIZE = 243
#: the controller step's 3-vectors (in its work buffer at STEP_CONTROL): the reference (X, dX,
#: ddX, q, dq, ddq), the measured q, dq and pose, the commanded acceleration, q_X, the torque
CONTROL_X_REF, CONTROL_DX_REF, CONTROL_DDX_REF, CONTROL_Q_REF, CONTROL_DQ_REF, CONTROL_DDQ_REF = 0, 3, 6, 9, 12, 15
CONTROL_Q, CONTROL_DQ, CONTROL_X, CONTROL_ACC, CONTROL_Q_X, CONTROL_TAU = 18, 21, 24, 27, 30, 33
CONTROL_SIZE = 36
#: rows of the RK4 ``stages`` array: the four derivatives, the three stage states, two temporaries
RK4_K1, RK4_K2, RK4_K3, RK4_K4, RK4_X2, RK4_X3, RK4_X4, RK4_ACC, RK4_TMP = range(9)
RK4_STAGES = 9
#: a stepper's work buffer: the workspace, then the RK4 stages (9, 6), the held torque (3), the
#: motor angles of the inverse kinematics (3) and the controller's 3-vectors
STEP_WS, STEP_STAGES = 0, WS_SIZE
STEP_TAU = STEP_STAGES + 6 * RK4_STAGES
STEP_Q = STEP_TAU + 3
STEP_CONTROL = STEP_Q + 3
STEP_WORK_SIZE = STEP_CONTROL + CONTROL_SIZE

#: rows of the per-leg table ``leg`` (9, 3)
LEG_COS_Q, LEG_SIN_Q, LEG_RBX, LEG_RBY, LEG_LX, LEG_LY, LEG_DEN, LEG_DQ, LEG_DDQ0 = range(9)
#: rows of the force table (6, 3): task space C_X dX, G_X, F_X; joint space C dq, G, F
FORCE_CX, FORCE_GX, FORCE_FX, FORCE_CJ, FORCE_GJ, FORCE_FJ = range(6)

# ----------------------------------------------------------------------------- codes
#: what a task- or joint-space evaluation returns
MASS, CORIOLIS, GRAVITY, FRICTION, FORWARD, INVERSE, GENERALIZED = range(7)
#: statuses: accepted; a non-finite input; no inverse-kinematics solution; loop residual above
#: the tolerance; an exactly singular matrix or a non-finite result; an array of the wrong length
OK, BAD_INPUT, OUTSIDE, NOT_ASSEMBLED, SINGULAR, BAD_SHAPE = range(6)
#: a refusal code is ``status + STATUS_SPAN * index`` (index of the refused row, step or phase)
STATUS_SPAN = 8


def refusal(code: int) -> tuple[int, int]:
    """``(status, index)`` of a kernel's return value (``(OK, 0)`` if it accepted)."""
    return code % STATUS_SPAN, code // STATUS_SPAN


# ----------------------------------------------------------------------------- packers
def pack_arm(motors, l1, l2, platform) -> np.ndarray:
    """The ``arm`` pack (18,) of a :class:`solver.Manipulator`'s arrays."""
    return np.concatenate([np.ravel(motors), l1, l2, np.ravel(platform)]).astype(np.float64)


def pack_bodies(com_proximal, com_distal, weights, friction, gravity, com_platform) -> np.ndarray:
    """The ``bodies`` pack (40,): centres of mass, the 21 row weights, the 9 viscous
    coefficients, gravity and the platform centre of mass."""
    return np.concatenate([com_proximal, com_distal, weights, friction, gravity,
                           com_platform]).astype(np.float64)


def pack_gains(kp, kd) -> np.ndarray:
    """The ``gains`` pack (6,)."""
    return np.concatenate([kp, kd]).astype(np.float64)


def pack_circle(center, radius, phi, rate, ramp_time, start) -> np.ndarray:
    """The ``circle`` pack (7,): centre (x, y), radius, orientation, cruise rate, ramp time, start."""
    return np.array([center[0], center[1], radius, phi, rate, ramp_time, start], dtype=np.float64)
