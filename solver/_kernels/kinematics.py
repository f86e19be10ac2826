"""The kinematics core of every compiled kernel (the solver's and the dynamics'): one inverse
kinematics, one loop row, one leg row with ``J_q``'s denominator, one Jacobian.

Leg ``i`` is ``M_i - D_i - A_i``: elbow ``D_i = M_i + l1_i (cos q_i, sin q_i)``, platform
joint ``A_i = P + R(phi) b_i``, loop vector ``L_i = A_i - D_i``, loop constraint
``F_i = |L_i|^2 - l2_i^2``.  :func:`loop_row` gives ``L_i`` and row ``i`` of ``J / 2``
(``J = dF/dX``); every J, Newton step and det J sign of the kernels is built from it.
:func:`leg_row` adds the motor side: ``den_i = l1_i L_i . n_i = -K_ii / 2`` (``n_i`` the
normal of the proximal link), so ``J_q = dq/dX = -K^-1 J`` has rows ``(L_x, L_y, L . dR/dphi b) / den``
(what :mod:`dynamics._kernels.rows` uses) and ``K = diag(-2 den)``.
:func:`ik_leg` is the one inverse kinematics formula (:func:`ik_pose` and :func:`solver.ik` loop
over it, and so do the dynamics' plant, controller and reference).  The 3x3 algebra and the angle wrap are in :mod:`.linalg`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .layout import MODEL_L1, MODEL_L2SQ, MODEL_MOTORS, MODEL_OFFSET, MODEL_PLATFORM
from .linalg import cramer3, det3, hadamard, row_ratio, solve3, wrap
from .scratch import floats, scratch2


@njit(cache=True)
def geometry(model_pack):
    """Views of the model pack: motors (3, 2), l1 (3,), the legs (6,): l2^2 (3,) then the offset bounds of
    the robot as built (3,, m; :func:`leg_slack`), platform joints (3, 2).  Every kernel reads ``l2sq[i]``,
    ``i < 3``; a ``l2sq`` of three entries (a model's, from Python) has no offsets."""
    return (model_pack[MODEL_MOTORS:MODEL_MOTORS + 6].reshape((3, 2)), model_pack[MODEL_L1:MODEL_L1 + 3],
            model_pack[MODEL_L2SQ:MODEL_OFFSET + 3], model_pack[MODEL_PLATFORM:MODEL_PLATFORM + 6].reshape((3, 2)))


@njit(cache=False)
def leg_offset(l2sq, i):
    """Leg ``i``'s offset bound ``e_i`` (m) of the robot as built: 0 for the model, and for a prismatic leg
    (whose tolerance the tracker carries as a joint width, exactly ``e_i``)."""
    if l2sq.shape[0] < 6 or l2sq[i] < 0.0:
        return 0.0
    return l2sq[3 + i]


@njit(cache=False)
def leg_slack(l2sq, i):
    """The slack ``sigma_i`` (m^2) of leg ``i``'s circle constraint for the robot as built: at the built
    robot's pose and joints the model's ``F_i = |P + R(phi) b_i - D_i(q_i)|^2 - l2_i^2`` lies in
    ``[-sigma_i, sigma_i]``, ``sigma_i = e_i (2 l2_i + e_i)`` (the model's distance there is within
    ``e_i`` of ``l2_i``: the triangle inequality; :mod:`solver.geometry_tolerance`).  0 without offsets."""
    e = leg_offset(l2sq, i)
    if e == 0.0:
        return 0.0
    return e * (2.0 * math.sqrt(l2sq[i]) + e) * (1.0 + 1e-12)


@njit(cache=False)
def as_built(l2sq):
    """Whether the legs carry an offset (the robot as built): the certificates then bound the pose for
    every geometry within it, and the joints' chains along the readings vouch for nothing."""
    return leg_offset(l2sq, 0) > 0.0 or leg_offset(l2sq, 1) > 0.0 or leg_offset(l2sq, 2) > 0.0


@njit(cache=False)
def radius_sq(l2sq_i, q_i):
    """Squared radius of leg ``i``'s circle: ``l2sq_i`` (3-RRR), or ``q_i^2`` for a prismatic leg,
    which the model pack marks by ``l2sq_i < 0`` (3-RPR: the joint is the leg's length)."""
    return q_i * q_i if l2sq_i < 0.0 else l2sq_i


@njit(cache=False)
def radius_sq_dq(l2sq_i, q_i):
    """d(radius_sq)/dq_i: ``2 q_i`` for a prismatic leg, 0 for a revolute one."""
    return 2.0 * q_i if l2sq_i < 0.0 else 0.0


@njit(cache=True)
def elbows(q, M, l1, D):
    """Elbow positions ``D`` (3, 2) of joints ``q``."""
    for i in range(3):
        D[i, 0] = M[i, 0] + l1[i] * math.cos(q[i])
        D[i, 1] = M[i, 1] + l1[i] * math.sin(q[i])


@njit(cache=False)
def loop_row(x, y, c, s, bx, by, mx, my, ax, ay):
    """Leg loop at pose ``(x, y)``, ``cos/sin phi = c, s``, platform joint ``b = (bx, by)``, motor
    ``M = (mx, my)`` and arm ``D - M = (ax, ay)``.

    Returns ``R b`` (2 values), ``L = P + R b - M - (D - M)`` (2 values) and
    ``L . dR/dphi b``: the row ``(L_x, L_y, L . dR/dphi b)`` is row ``i`` of ``J / 2``.
    Kernels that hold the elbow ``D`` itself pass it as ``M`` with a zero arm.
    """
    rbx = c * bx - s * by
    rby = s * bx + c * by
    lx = x + rbx - mx - ax
    ly = y + rby - my - ay
    return rbx, rby, lx, ly, ly * rbx - lx * rby


@njit(cache=False)
def leg_row(x, y, c, s, q_i, mx, my, l1_i, bx, by):
    """Leg ``i`` at pose ``(x, y)``, ``cos/sin phi = c, s``, motor angle ``q_i``, motor ``(mx, my)``,
    proximal length ``l1_i`` and platform joint ``(bx, by)``.

    Returns ``cos q_i, sin q_i``, ``R b`` (2 values), ``L = A - D`` (2 values), ``L . dR/dphi b``
    (as :func:`loop_row`) and ``den = l1_i L . (-sin q_i, cos q_i)`` (``K_ii = -2 den`` for a
    revolute leg; row ``i`` of ``J_q`` is ``(L_x, L_y, L . dR/dphi b) / den``).
    """
    cq, sq = math.cos(q_i), math.sin(q_i)
    rbx, rby, lx, ly, lr = loop_row(x, y, c, s, bx, by, mx, my, l1_i * cq, l1_i * sq)
    return cq, sq, rbx, rby, lx, ly, lr, l1_i * (ly * cq - lx * sq)


#: rows of :func:`leg_batch`'s output (N, LEG_ROWS, 3): the values :func:`leg_row` returns, per leg
LEG_COS, LEG_SIN, LEG_RBX, LEG_RBY, LEG_LX, LEG_LY, LEG_LR, LEG_DEN = range(8)
LEG_ROWS = 8


@njit(cache=True)
def leg_batch(X, q, M, l1, b, out):
    """:func:`leg_row` of the three legs at poses ``X`` and joints ``q`` (N, 3) into ``out`` (N, 8, 3)."""
    for n in range(X.shape[0]):
        c, s = math.cos(X[n, 2]), math.sin(X[n, 2])
        for i in range(3):
            row = leg_row(X[n, 0], X[n, 1], c, s, q[n, i], M[i, 0], M[i, 1], l1[i], b[i, 0], b[i, 1])
            for r in range(LEG_ROWS):
                out[n, r, i] = row[r]


# ----------------------------------------------------------------------------- inverse kinematics
@njit(cache=False)
def ik_leg(x, y, c, s, mx, my, l1_i, l2_i, bx, by, bit):
    """Inverse kinematics of leg ``i`` at pose ``(x, y)``, ``cos/sin phi = c, s``: motor ``(mx, my)``,
    link lengths ``l1_i, l2_i``, platform joint ``(bx, by)``, elbow bit ``bit`` (1: the elbow sign is
    negative).  Returns ``(True, q_i)`` with ``q_i`` in (-pi, pi], or ``(False, 0.0)`` if the leg
    cannot reach.  The one IK formula: :func:`ik_pose` and the dynamics kernels loop over it."""
    dx = x + c * bx - s * by - mx
    dy = y + s * bx + c * by - my
    rho2 = dx * dx + dy * dy
    rho = math.sqrt(rho2)
    if rho == 0.0:
        return False, 0.0
    ca = (l1_i * l1_i + rho2 - l2_i * l2_i) / (2.0 * l1_i * rho)
    if not abs(ca) <= 1.0 + 1e-12:
        return False, 0.0
    alpha = math.acos(min(1.0, max(-1.0, ca)))
    sign = 1.0 - 2.0 * bit
    return True, wrap(math.atan2(dy, dx) - sign * alpha)


@njit(cache=True)
def ik_pose(x, y, phi, elbow_bits, M, l1, l2, b, q):
    """Inverse kinematics of one pose into ``q`` (3,); False (``q`` partly written) if a leg cannot reach.

    ``elbow_bits`` is ``posture - 1``: bit ``i`` set means leg ``i``'s elbow sign is negative.
    """
    c, s = math.cos(phi), math.sin(phi)
    for i in range(3):
        ok, qi = ik_leg(x, y, c, s, M[i, 0], M[i, 1], l1[i], l2[i], b[i, 0], b[i, 1], (elbow_bits >> i) & 1)
        if not ok:
            return False
        q[i] = qi
    return True


@njit(cache=True)
def ik_batch(X, elbow_bits, M, l1, l2, b, out):
    """:func:`ik_pose` of poses ``X`` (N, 3) with ``elbow_bits`` (N,) into ``out`` (N, 3); NaN rows if unreachable."""
    for n in range(X.shape[0]):
        if not ik_pose(X[n, 0], X[n, 1], X[n, 2], elbow_bits[n], M, l1, l2, b, out[n]):
            for i in range(3):
                out[n, i] = np.nan


# ----------------------------------------------------------------------------- Jacobians
@njit(cache=True)
def jacobian(X, q, M, l1, l2sq, b, J, kd):
    """``J = dF/dX`` (3, 3) and the diagonal ``kd`` (3,) of ``K = dF/dq`` at ``(X, q)``, written in place
    (a revolute leg's joint moves its circle's centre, a prismatic leg's its radius)."""
    c, s = math.cos(X[2]), math.sin(X[2])
    for i in range(3):
        _cq, _sq, _rbx, _rby, lx, ly, lr, den = leg_row(X[0], X[1], c, s, q[i], M[i, 0], M[i, 1], l1[i], b[i, 0],
                                                        b[i, 1])
        J[i, 0] = 2.0 * lx
        J[i, 1] = 2.0 * ly
        J[i, 2] = 2.0 * lr
        kd[i] = -2.0 * den - radius_sq_dq(l2sq[i], q[i])


@njit(cache=True)
def jacobian_batch(X, q, M, l1, l2sq, b, J, kd):
    """:func:`jacobian` of ``X``, ``q`` (N, 3) into ``J`` (N, 3, 3) and ``kd`` (N, 3)."""
    for n in range(X.shape[0]):
        jacobian(X[n], q[n], M, l1, l2sq, b, J[n], kd[n])


@njit(cache=True)
def velocity(X, q, dq, M, l1, l2sq, b, out):
    """dX = -J^-1 K dq at (X, q) (the velocity model, eq. 20); returns the Hadamard ratio of J."""
    J = scratch2(3, 3, np.float64)
    kd = floats(3)
    jacobian(X, q, M, l1, l2sq, b, J, kd)
    r = floats(3)
    for i in range(3):
        r[i] = -kd[i] * dq[i]
    if not solve3(J, r, out):
        out[:] = 0.0
        return 0.0
    return hadamard(J)


@njit(cache=True)
def newton_step(x, y, phi, D, b, l2sq):
    """At a real pose with elbows ``D``: max|F_i|, the Newton step (dx, dy, dphi) on F(X) = 0,
    whether the step is finite, and the Hadamard ratio of J (0 when singular)."""
    c, s = math.cos(phi), math.sin(phi)
    A = scratch2(3, 3, np.float64)           # J / 2
    g = floats(3)                            # -F / 2
    step = floats(3)
    res = 0.0
    for i in range(3):
        _rbx, _rby, lx, ly, lr = loop_row(x, y, c, s, b[i, 0], b[i, 1], D[i, 0], D[i, 1], 0.0, 0.0)
        F = lx * lx + ly * ly - l2sq[i]
        res = max(res, abs(F))
        A[i, 0], A[i, 1], A[i, 2], g[i] = lx, ly, lr, -0.5 * F
    det = det3(A)
    if det == 0.0 or not math.isfinite(det):
        return res, 0.0, 0.0, 0.0, False, 0.0
    ok = cramer3(A, g, det, step)
    return res, step[0], step[1], step[2], ok, row_ratio(A, det)


@njit(cache=True)
def det_sign(x, y, phi, D, b):
    """Sign of det J at a real pose with elbows ``D`` (+1 or -1; 0 exactly singular)."""
    c, s = math.cos(phi), math.sin(phi)
    A = scratch2(3, 3, np.float64)
    for i in range(3):
        _rbx, _rby, lx, ly, lr = loop_row(x, y, c, s, b[i, 0], b[i, 1], D[i, 0], D[i, 1], 0.0, 0.0)
        A[i, 0], A[i, 1], A[i, 2] = lx, ly, lr
    det = det3(A)
    return 1 if det > 0 else (-1 if det < 0 else 0)
