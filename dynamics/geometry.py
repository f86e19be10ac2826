r"""Kinematics the dynamics needs: loop geometry, velocity and acceleration of every body (numpy).

Bodies
------
* proximal link ``i``: rotates about the motor ``M_i`` with the motor angle ``q_i``; centre of
  mass at ``M_i + r_p,i (cos q_i, sin q_i)``;
* motor rotor ``i``: rotates with ``q_i`` (inertia reflected to the link side);
* distal link ``i``: planar motion from the elbow ``D_i`` to the platform joint ``A_i``; centre
  of mass at ``D_i + (r_d,i / l2_i) (A_i - D_i)``, angle ``psi_i = atan2(A_i - D_i)``;
* platform: centre of mass at ``P + R(phi) c`` with ``c`` in the platform frame.

Velocities and accelerations (minimal coordinates ``X = (x, y, phi)``)
--------------------------------------------------------------------
Write ``L_i = A_i - D_i``, ``e_i = (cos q_i, sin q_i)``, ``n_i = (-sin q_i, cos q_i)``,
``A_i = P + R(phi) b_i`` and ``v_A = dP + dphi E R b_i`` (``E`` the +90 deg rotation).
Differentiating ``|L_i|^2 = l2_i^2`` once and twice:

.. math::

   \dot q_i = \frac{L_i\cdot v_{A_i}}{l_{1i}\, L_i\cdot n_i}, \qquad
   \ddot q_i = \frac{L_i\cdot a_{A_i} + l_{1i}\dot q_i^2\, L_i\cdot e_i + |\dot L_i|^2}
                    {l_{1i}\, L_i\cdot n_i}

(the first is ``dq = -K^{-1} J dX`` of eq. 3; ``J_q = -K^{-1} J`` below).  The distal link
turns at ``omega_i = (L_i x dL_i) / l2_i^2`` and accelerates at ``alpha_i = (L_i x ddL_i) /
l2_i^2``; its centre of mass, an affine combination of ``D_i`` and ``A_i``, moves at
``(1 - s) v_D + s v_A``.  So every body velocity is linear in ``dX`` and every body acceleration
is affine in ``ddX``:

.. math::  v_b = V_b(X)\,\dot X, \qquad a_b = V_b(X)\,\ddot X + \beta_b(X, \dot X),

where ``beta_b`` (the velocity-product acceleration) follows from the formulas above with
``ddX = 0``: no numerical differentiation anywhere.  :func:`geometry` takes the loop geometry
from the kinematics core (:mod:`solver._kernels.kinematics`, compiled) and :func:`motion`
evaluates the body motion with numpy for the kinematic helpers below and the energies
(:mod:`dynamics.energy`); the dynamics terms evaluate both compiled (:mod:`dynamics._kernels.rows`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from solver import Manipulator, as_array, wrap_angle
from solver._kernels.kinematics import LEG_ROWS, leg_batch

from ._checks import broadcast, check_model
from .parameters import DynamicParameters

__all__ = ["ASSEMBLY_TOL", "joint_velocity_jacobian", "pose_velocity_jacobian", "joint_accelerations",
           "passive_joint_angles", "passive_joint_rates"]

#: A joint-space call refuses ``(q, X)`` whose loop residual max_i |F_i| / l2_i^2
#: exceeds this (the pose does not belong to the joints).
ASSEMBLY_TOL = 1e-6


class Geom(NamedTuple):
    """Configuration-dependent quantities of ``(X, q)``; per-leg arrays are (..., 3)."""

    cq: np.ndarray      # cos q_i
    sq: np.ndarray      # sin q_i
    Lx: np.ndarray      # L_i = A_i - D_i
    Ly: np.ndarray
    Rbx: np.ndarray     # R(phi) b_i
    Rby: np.ndarray
    Rcx: np.ndarray     # R(phi) c, platform centre of mass offset, (...)
    Rcy: np.ndarray
    den: np.ndarray     # l1_i L_i . n_i  (= -K_ii / 2)
    Jq: np.ndarray      # dq/dX = -K^-1 J, (..., 3, 3)


def geometry(model, com_platform, X, q) -> Geom:
    """The loop geometry of configurations ``(X, q)`` (..., 3) broadcast together, by the kinematics
    core (:func:`solver._kernels.kinematics.leg_row`, the one the compiled dynamics and the solver run)."""
    X, q = np.broadcast_arrays(X, q)
    lead = X.shape[:-1]
    legs = np.empty((math.prod(lead), LEG_ROWS, 3))
    leg_batch(np.ascontiguousarray(X, dtype=np.float64).reshape(-1, 3),
              np.ascontiguousarray(q, dtype=np.float64).reshape(-1, 3), model.motors, model.l1, model.platform, legs)
    legs = legs.reshape(lead + (LEG_ROWS, 3))
    cq, sq, Rbx, Rby, Lx, Ly, Lr, den = (legs[..., r, :] for r in range(LEG_ROWS))
    Jq = np.stack([Lx, Ly, Lr], axis=-1) / den[..., None]
    c, s = np.cos(X[..., 2]), np.sin(X[..., 2])
    Rcx = c * com_platform[0] - s * com_platform[1]
    Rcy = s * com_platform[0] + c * com_platform[1]
    return Geom(cq, sq, Lx, Ly, Rbx, Rby, Rcx, Rcy, den, Jq)


def assembly_residual(model, X, q) -> float:
    """The largest loop residual ``max_i |F_i| / l2_i^2`` over the configurations ``(X, q)``."""
    g = geometry(model, (0.0, 0.0), X, q)
    return float(np.max(np.abs(g.Lx ** 2 + g.Ly ** 2 - model.l2 ** 2) / model.l2 ** 2))


class Motion(NamedTuple):
    """Velocities and velocity-product accelerations (ddX = 0) for a given dX."""

    v: np.ndarray        # (..., 21) body velocity rows
    beta: np.ndarray     # (..., 21) body accelerations at ddX = 0
    dq: np.ndarray       # (..., 3) motor rates
    ddq0: np.ndarray     # (..., 3) motor accelerations at ddX = 0
    omega: np.ndarray    # (..., 3) distal link angular rates


def motion(params, model, g: Geom, dX) -> Motion:
    # dq, ddq0 and omega are pure kinematics; only the centre-of-mass rows read params.
    dx, dy, dphi = dX[..., 0:1], dX[..., 1:2], dX[..., 2:3]
    dq = np.einsum("...ij,...j->...i", g.Jq, dX)
    l1, l2sq = model.l1, model.l2 ** 2
    vAx, vAy = dx - dphi * g.Rby, dy + dphi * g.Rbx
    vDx, vDy = -l1 * g.sq * dq, l1 * g.cq * dq
    dLx, dLy = vAx - vDx, vAy - vDy
    w2 = dphi * dphi
    aAx, aAy = -w2 * g.Rbx, -w2 * g.Rby
    dq2 = dq * dq
    ddq0 = (g.Lx * aAx + g.Ly * aAy + l1 * dq2 * (g.Lx * g.cq + g.Ly * g.sq) + dLx * dLx + dLy * dLy) / g.den
    aDx = l1 * (-g.sq * ddq0 - g.cq * dq2)
    aDy = l1 * (g.cq * ddq0 - g.sq * dq2)
    ddLx, ddLy = aAx - aDx, aAy - aDy
    omega = (g.Lx * dLy - g.Ly * dLx) / l2sq
    alpha = (g.Lx * ddLy - g.Ly * ddLx) / l2sq
    rp, sd = params.com_proximal, params.com_distal / model.l2
    w = dphi[..., 0]
    v = np.concatenate([
        np.stack([dx[..., 0] - w * g.Rcy, dy[..., 0] + w * g.Rcx, w], -1),
        -rp * g.sq * dq, rp * g.cq * dq, dq,
        vDx + sd * dLx, vDy + sd * dLy, omega], axis=-1)
    w2 = w2[..., 0]
    beta = np.concatenate([
        np.stack([-w2 * g.Rcx, -w2 * g.Rcy, np.zeros_like(w2)], -1),
        rp * (-g.sq * ddq0 - g.cq * dq2), rp * (g.cq * ddq0 - g.sq * dq2), ddq0,
        aDx + sd * ddLx, aDy + sd * ddLy, alpha], axis=-1)
    return Motion(v, beta, dq, ddq0, omega)



def mat_vec(A, v):
    return np.einsum("...ij,...j->...i", A, v)


def joint_velocity_jacobian(model: Manipulator, X, q) -> np.ndarray:
    """``J_q = dq/dX = -K^{-1} J`` (eq. 3 solved for the motor rates).

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles of the same configurations, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``dq = J_q dX``; columns x, y in rad/m, column phi dimensionless.
    """
    check_model(model)
    X, q = broadcast(X=as_array("X", X), q=as_array("q", q))
    return geometry(model, (0.0, 0.0), X, q).Jq


def pose_velocity_jacobian(model: Manipulator, X, q) -> np.ndarray:
    """``J_x = dX/dq = -J^{-1} K``, the inverse of :func:`joint_velocity_jacobian`.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``dX = J_x dq``; rows x, y in m/rad, row phi dimensionless.  Unbounded
        at a type-1 singularity (``det J = 0``).
    """
    return np.linalg.inv(joint_velocity_jacobian(model, X, q))


def joint_accelerations(model: Manipulator, X, q, dX, ddX) -> np.ndarray:
    """Motor accelerations of a platform motion (exact second-order velocity model).

    ``ddq = J_q ddX + ddq_0(X, dX)`` with ``ddq_0`` from differentiating the
    loop constraints twice (module docstring).

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Configuration (pose m, m, rad; motor angles rad).
    dX : array_like, shape (..., 3)
        Pose rates, m/s, m/s, rad/s.
    ddX : array_like, shape (..., 3)
        Pose accelerations, m/s^2, m/s^2, rad/s^2.

    Returns
    -------
    ndarray, shape (..., 3)
        ``ddq`` in rad/s^2.
    """
    check_model(model)
    X, q, dX, ddX = broadcast(X=as_array("X", X), q=as_array("q", q), dX=as_array("dX", dX),
                               ddX=as_array("ddX", ddX))
    params = KINEMATIC_ONLY
    g = geometry(model, params.com_platform, X, q)
    mo = motion(params, model, g, dX)
    return mat_vec(g.Jq, ddX) + mo.ddq0


def passive_joint_angles(model: Manipulator, X, q) -> np.ndarray:
    """Angles of the six passive joints (the ``q^u`` of eq. 6).

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Pose (m, m, rad) and motor angles (rad) of assembled configurations.

    Returns
    -------
    ndarray, shape (..., 6)
        ``(psi_i - q_i)`` for the elbows ``D_i`` (i = 1..3), then ``(phi - psi_i)``
        for the platform joints ``A_i``, with ``psi_i`` the direction of
        ``A_i - D_i``; rad, wrapped to (-pi, pi].
    """
    check_model(model)
    X, q = broadcast(X=as_array("X", X), q=as_array("q", q))
    g = geometry(model, (0.0, 0.0), X, q)
    psi = np.arctan2(g.Ly, g.Lx)
    return wrap_angle(np.concatenate([psi - q, X[..., 2:3] - psi], axis=-1))


def passive_joint_rates(model: Manipulator, X, q, dX) -> np.ndarray:
    """Rates of the six passive joints of :func:`passive_joint_angles`, rad/s.

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Configuration.
    dX : array_like, shape (..., 3)
        Pose rates, m/s, m/s, rad/s.

    Returns
    -------
    ndarray, shape (..., 6)
        ``(omega_i - dq_i)`` then ``(dphi - omega_i)``, ``omega_i`` the distal link rates.
    """
    check_model(model)
    X, q, dX = broadcast(X=as_array("X", X), q=as_array("q", q), dX=as_array("dX", dX))
    params = KINEMATIC_ONLY
    mo = motion(params, model, geometry(model, params.com_platform, X, q), dX)
    return np.concatenate([mo.omega - mo.dq, dX[..., 2:3] - mo.omega], axis=-1)


#: parameters for the kinematics-only uses of :func:`motion` (only its geometric rows are read)
KINEMATIC_ONLY = DynamicParameters()
