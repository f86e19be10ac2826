"""One communication step of the plant and of the computed-torque controller, compiled.

What :class:`dynamics.PlantStepper` and :class:`dynamics.ControllerStepper` run for the FMU slaves
(``fmu_src/RRRPlant.py``, ``fmu_src/ComputedTorqueController.py``): one compiled call per step,
on the slave's pack (``plant`` or ``controller``, :mod:`.layout`) and a work buffer the stepper
allocated once (``STEP_WORK_SIZE``), so a step allocates nothing.
"""
from __future__ import annotations

from numba import njit

from solver._kernels.linalg import wrap

from .base import code, finite, ik_arm, workspace
from .circle import circle_joint_row
from .control import commanded_acceleration
from .layout import (ARM_L1, ARM_L2, ARM_MOTORS, BAD_INPUT, BAD_SHAPE, CONTROLLER_OUT_SIZE, BODY_COM_DISTAL, BODY_COM_PROXIMAL, BODY_GRAVITY,
                     BODY_WEIGHTS, CONTROL_DDQ_REF, CONTROL_DDX_REF, CONTROL_DQ, CONTROL_DQ_REF, CONTROL_DX_REF,
                     CONTROL_Q, CONTROL_Q_REF, CONTROL_Q_X, CONTROL_TAU, CONTROL_X, CONTROL_X_REF, CONTROL_ACC,
                     CONTROLLER_ARM, CONTROLLER_BODIES, CONTROLLER_CIRCLE, CONTROLLER_GAINS,
                     CONTROLLER_OUT_POSE_REF, CONTROLLER_OUT_Q_REF, CONTROLLER_OUT_TAU, CONTROLLER_PHASE_MEASURED,
                     CONTROLLER_PHASE_REFERENCE, CONTROLLER_SIZE, INVERSE, LEG_COS_Q, LEG_DQ, LEG_LX, LEG_LY,
                     LEG_RBX, LEG_RBY, LEG_SIN_Q, OK, OUTSIDE, PLANT_ARM, PLANT_BODIES, PLANT_OUT_DQ,
                     PLANT_OUT_ENERGY, PLANT_OUT_Q, PLANT_OUT_SIZE, PLANT_OUT_STATE, PLANT_SIZE, ROW_DISTAL_ROT,
                     ROW_DISTAL_X, ROW_DISTAL_Y, ROW_PLATFORM_ROT, ROW_PLATFORM_X, ROW_PLATFORM_Y, ROW_PROXIMAL_ROT,
                     ROW_PROXIMAL_X, ROW_PROXIMAL_Y, SINGULAR, STEP_CONTROL, STEP_Q, STEP_STAGES, STEP_TAU,
                     STEP_WORK_SIZE, STEP_WS)
from .rk4 import rk4_task_step, stages_of
from .rows import geometry_row, joint_row


@njit(cache=True, error_model="numpy")
def _energy(arm, bodies, x, y, phi, dx, dy, dphi, rcx, rcy, leg):
    """Kinetic (body by body, ``1/2 sum w v^2``) plus gravitational potential energy of a
    configuration whose per-leg table ``leg`` holds the rates ``dq`` (after ``geometry_row``)."""
    gx, gy = bodies[BODY_GRAVITY], bodies[BODY_GRAVITY + 1]
    w = bodies[BODY_WEIGHTS:BODY_WEIGHTS + ROW_DISTAL_ROT + 3]
    v0, v1 = dx - dphi * rcy, dy + dphi * rcx
    ke = w[ROW_PLATFORM_X] * v0 * v0 + w[ROW_PLATFORM_Y] * v1 * v1 + w[ROW_PLATFORM_ROT] * dphi * dphi
    pe = w[ROW_PLATFORM_X] * ((x + rcx) * gx + (y + rcy) * gy)
    for i in range(3):
        l1, l2 = arm[ARM_L1 + i], arm[ARM_L2 + i]
        rp, sd = bodies[BODY_COM_PROXIMAL + i], bodies[BODY_COM_DISTAL + i] / l2
        cq, sq, rbx, rby = leg[LEG_COS_Q, i], leg[LEG_SIN_Q, i], leg[LEG_RBX, i], leg[LEG_RBY, i]
        lx, ly, dq = leg[LEG_LX, i], leg[LEG_LY, i], leg[LEG_DQ, i]
        vdx, vdy = -l1 * sq * dq, l1 * cq * dq
        dlx, dly = (dx - dphi * rby) - vdx, (dy + dphi * rbx) - vdy
        px, py = -rp * sq * dq, rp * cq * dq
        ux, uy = vdx + sd * dlx, vdy + sd * dly
        om = (lx * dly - ly * dlx) / l2 ** 2
        ke += (w[ROW_PROXIMAL_X + i] * px * px + w[ROW_PROXIMAL_Y + i] * py * py
               + w[ROW_PROXIMAL_ROT + i] * dq * dq + w[ROW_DISTAL_X + i] * ux * ux
               + w[ROW_DISTAL_Y + i] * uy * uy + w[ROW_DISTAL_ROT + i] * om * om)
        mx, my = arm[ARM_MOTORS + 2 * i], arm[ARM_MOTORS + 2 * i + 1]
        dxp, dyp = mx + l1 * cq, my + l1 * sq                      # elbow D_i
        pe += w[ROW_PROXIMAL_X + i] * ((mx + rp * cq) * gx + (my + rp * sq) * gy)
        pe += w[ROW_DISTAL_X + i] * ((dxp + sd * lx) * gx + (dyp + sd * ly) * gy)
    return 0.5 * ke - pe


@njit(cache=True, error_model="numpy")
def plant_outputs(arm, bodies, bits, out, ws):
    """Sensor outputs of the task-space state ``out[PLANT_OUT_STATE:+6]``: ``q`` (the core's IK, :func:`solver.ik`'s),
    ``dq = J_q dX`` and the total energy, into ``out``.  Returns :data:`OUTSIDE` if the pose has
    no inverse kinematics in the posture, :data:`SINGULAR` for a non-finite output, else :data:`OK`."""
    leg, Jq = ws[0], ws[1]
    x = out[PLANT_OUT_STATE:PLANT_OUT_STATE + 6]
    q = out[PLANT_OUT_Q:PLANT_OUT_Q + 3]
    if not finite(x):
        return OUTSIDE
    if not ik_arm(arm, x[0], x[1], x[2], bits, q):
        return OUTSIDE
    rcx, rcy, res = geometry_row(arm, bodies, x[0], x[1], x[2], q, leg, Jq)
    for i in range(3):
        d = Jq[i, 0] * x[3] + Jq[i, 1] * x[4] + Jq[i, 2] * x[5]
        leg[LEG_DQ, i] = d
        out[PLANT_OUT_DQ + i] = d
    out[PLANT_OUT_ENERGY] = _energy(arm, bodies, x[0], x[1], x[2], x[3], x[4], x[5], rcx, rcy, leg)
    return OK if finite(out[:PLANT_OUT_SIZE]) else SINGULAR


@njit(cache=True, error_model="numpy")
def plant_step(plant, bits, tau1, tau2, tau3, h, n, x, out, work):
    """The plant's doStep: ``n`` RK4 steps of ``h`` of the task-space dynamics from ``x`` (6,) with
    the torques held, then :func:`plant_outputs`, into ``out`` (``PLANT_OUT_SIZE``,); ``x`` is not
    modified (``n = 0``: the outputs of ``x``).

    Returns :data:`OK` or a refusal code whose index is the RK4 step refused (``< n``; the refused
    stage state is then in ``out[:6]``) or ``n`` (the outputs of the final state were refused).
    """
    if x.shape[0] != 6 or out.shape[0] != PLANT_OUT_SIZE:
        return BAD_SHAPE
    arm, bodies = plant[PLANT_ARM:PLANT_BODIES], plant[PLANT_BODIES:PLANT_SIZE]
    ws = workspace(work[STEP_WS:STEP_STAGES])
    stages = stages_of(work[STEP_STAGES:STEP_TAU])
    tau = work[STEP_TAU:STEP_Q]
    tau[0], tau[1], tau[2] = tau1, tau2, tau3
    ctx = (arm, bodies, bits, tau, work[STEP_Q:STEP_CONTROL], ws)
    state = out[PLANT_OUT_STATE:PLANT_OUT_STATE + 6]
    for j in range(6):
        state[j] = x[j]
    for k in range(n):
        st, _ = rk4_task_step(ctx, 0.0, state, h, state, stages)
        if st != OK:
            return code(st, k)
    return code(plant_outputs(arm, bodies, bits, out, ws), n)


@njit(cache=True, error_model="numpy")
def controller_step(controller, bits, t, q1, q2, q3, dq1, dq2, dq3, x, y, phi, tol, out, work):
    """The computed-torque controller's doStep at ``t`` into ``out`` (``CONTROLLER_OUT_SIZE``,):
    the circle reference at ``t``, ``q_X = g_j(X)`` unwrapped next to ``q``, and the inverse
    dynamics at the commanded acceleration, ``tau = M(q_X, X) v + C dq + G + F``.

    Returns :data:`OK` or a refusal code whose index is ``CONTROLLER_PHASE_REFERENCE`` (the
    reference at ``t``) or ``CONTROLLER_PHASE_MEASURED`` (the measured joints and the DK pose).
    """
    if out.shape[0] != CONTROLLER_OUT_SIZE:
        return BAD_SHAPE
    arm = controller[CONTROLLER_ARM:CONTROLLER_BODIES]
    bodies = controller[CONTROLLER_BODIES:CONTROLLER_GAINS]
    gains = controller[CONTROLLER_GAINS:CONTROLLER_CIRCLE]
    circle = controller[CONTROLLER_CIRCLE:CONTROLLER_SIZE]
    ws = workspace(work[STEP_WS:STEP_STAGES])
    c = work[STEP_CONTROL:STEP_WORK_SIZE]
    Xd, dXd, ddXd = c[CONTROL_X_REF:CONTROL_DX_REF], c[CONTROL_DX_REF:CONTROL_DDX_REF], c[CONTROL_DDX_REF:CONTROL_Q_REF]
    qd, dqd, ddqd = c[CONTROL_Q_REF:CONTROL_DQ_REF], c[CONTROL_DQ_REF:CONTROL_DDQ_REF], c[CONTROL_DDQ_REF:CONTROL_Q]
    q, dq, X = c[CONTROL_Q:CONTROL_DQ], c[CONTROL_DQ:CONTROL_X], c[CONTROL_X:CONTROL_ACC]
    v, qx, tau = c[CONTROL_ACC:CONTROL_Q_X], c[CONTROL_Q_X:CONTROL_TAU], c[CONTROL_TAU:CONTROL_TAU + 3]
    st = circle_joint_row(arm, bodies, circle, bits, t, Xd, dXd, ddXd, qd, dqd, ddqd, ws[0], ws[1], ws[4])
    if st != OK:
        return code(st, CONTROLLER_PHASE_REFERENCE)
    q[0], q[1], q[2] = q1, q2, q3
    dq[0], dq[1], dq[2] = dq1, dq2, dq3
    X[0], X[1], X[2] = x, y, phi
    if not (finite(q) and finite(dq) and finite(X)):
        return code(BAD_INPUT, CONTROLLER_PHASE_MEASURED)
    if not ik_arm(arm, x, y, phi, bits, qx):
        return code(OUTSIDE, CONTROLLER_PHASE_MEASURED)
    for i in range(3):
        qx[i] = q[i] + wrap(qx[i] - q[i])          # q_X next to q (2 pi turns)
    commanded_acceleration(gains, q, dq, qd, dqd, ddqd, v)
    st = joint_row(arm, bodies, qx, dq, X, v, tol, INVERSE, tau, ws)
    if st != OK:
        return code(st, CONTROLLER_PHASE_MEASURED)
    for i in range(3):
        out[CONTROLLER_OUT_TAU + i] = tau[i]
        out[CONTROLLER_OUT_POSE_REF + i] = Xd[i]
        out[CONTROLLER_OUT_Q_REF + i] = qd[i]
    return OK
