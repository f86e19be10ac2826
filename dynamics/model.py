r"""The model terms of the 3-RRR dynamics (paper eqs. 5-7), in task and in joint space.

One function per term: inertia, Coriolis and centrifugal, gravity, friction, forward and inverse
dynamics.  Each evaluates its formula with one compiled kernel (:mod:`dynamics._kernels.rows`);
what a kernel refuses raises :class:`dynamics.DynamicsError`.

Task space (minimal coordinates ``X = (x, y, phi)``)
--------------------------------------------------
Every body velocity is linear in ``dX`` and every body acceleration affine in ``ddX``
(:mod:`dynamics.geometry`).  Stacking the 21 scalar rows (2 translations and 1 rotation of the
platform and of each of the six links; the rotor rides on the proximal rotation row) with weights
``w`` (masses and centroidal inertias), the principle of virtual power (Kane) gives

.. math::

   M_X \ddot X + C_X \dot X + G_X + F_X = J_q^T \tau, \quad
   M_X = V^T W V, \quad C_X\dot X = V^T W \beta, \quad
   G_X = -V^T W \gamma, \quad F_X = V_f^T B V_f \dot X,

``gamma`` the gravity acceleration of each translation row (zero for rotations), ``V_f`` the
Jacobian of the 9 joint rates that carry viscous friction (3 motors, 3 elbows, 3 platform
joints), ``B`` their coefficients.  This is exact for planar rigid bodies (there is no gyroscopic
term in the plane).  The motor angles come from the inverse kinematics in a posture.

Joint space (eq. 5)
-------------------
With ``J_x = dX/dq = J_q^{-1}`` and, at ``ddq = 0``, ``ddX_0 = -J_x ddq_0(X, dX)`` (``ddq_0``
the velocity-product part of the joint acceleration), multiplying the task-space equation by
``J_x^T`` (``J_x^T J_q^T = I``) gives

.. math::

   \tau = M(q)\ddot q + C(q, \dot q)\dot q + G(q) + F(q, \dot q), \quad
   M = J_x^T M_X J_x, \quad C\dot q = J_x^T (M_X \ddot X_0 + C_X \dot X),
   \quad G = J_x^T G_X, \quad F = J_x^T F_X.

``M``, ``C``, ``G`` are functions of the active joints only in principle; in practice they need
the pose ``X`` that the direct kinematics delivers (paper Figs 2 and 3), so every joint-space
function takes ``(q, X)`` and refuses a pose that does not close the loops of ``q``
(:data:`dynamics.ASSEMBLY_TOL`).

Shapes and units
----------------
Poses ``X`` (..., 3) in m, m, rad; motor angles ``q`` (..., 3) in rad; rates per second,
accelerations per second squared; torques ``tau`` (..., 3) in N m.  Task-space generalised forces
are ``(F_x, F_y, torque)`` in N, N, N m.  Every function takes ``(params, model, ...)``
(:class:`dynamics.DynamicParameters`, :class:`solver.Manipulator`) and broadcasts over leading
batch dimensions; task-space functions take a ``posture`` 1..8 (default 1).  Near a type-2
singularity (``det K = 0``, a leg stretched or folded) ``J_q`` is unbounded and near a type-1
singularity (``det J = 0``) ``J_x`` is; neither is guarded.

Raises
------
SolverInputError
    Wrong shapes or types, arrays that do not broadcast, an invalid posture.
DynamicsError
    (a SolverInputError) A non-finite input, a pose outside the posture's tool space, a pose that
    does not close the loops of the joints, a singular matrix or a non-finite result.
"""
from __future__ import annotations

import numpy as np

from solver import Manipulator

from ._evaluate import joint_term, task_term
from ._kernels.layout import CORIOLIS, FORWARD, FRICTION, GENERALIZED, GRAVITY, INVERSE, MASS
from .parameters import DynamicParameters

__all__ = ["mass_matrix_task", "coriolis_task", "gravity_task", "friction_task", "generalized_force_task",
           "forward_dynamics_task", "inverse_dynamics_task",
           "mass_matrix", "coriolis", "gravity", "friction", "forward_dynamics", "inverse_dynamics"]


# ----------------------------------------------------------------------------- task space
def mass_matrix_task(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Task-space inertia ``M_X(X)``: kinetic energy ``T = 1/2 dX^T M_X dX``.

    ``X`` (..., 3) poses; returns (..., 3, 3), symmetric positive definite: kg (x, y block),
    kg m (coupling), kg m^2 (phi).
    """
    return task_term(params, model, MASS, posture, X=X)


def coriolis_task(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Task-space Coriolis and centrifugal force ``C_X(X, dX) dX`` (exact, analytic), N, N, N m;
    quadratic in the pose rates ``dX``."""
    return task_term(params, model, CORIOLIS, posture, X=X, dX=dX)


def gravity_task(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Task-space gravity force ``G_X = dV/dX`` (``V`` the potential energy), N, N, N m (zero
    when ``params.gravity`` is zero)."""
    return task_term(params, model, GRAVITY, posture, X=X)


def friction_task(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Task-space viscous friction force ``F_X = V_f^T B V_f dX`` (opposes the motion), N, N, N m.

    ``dX . F_X`` is the power dissipated in the 9 joints (:func:`dynamics.friction_power`).
    """
    return task_term(params, model, FRICTION, posture, X=X, dX=dX)


def generalized_force_task(params: DynamicParameters, model: Manipulator, X, dX, tau,
                           posture=1) -> np.ndarray:
    """Generalised force of the motor torques ``tau`` (N m) and friction, ``J_q^T tau - F_X``."""
    return task_term(params, model, GENERALIZED, posture, X=X, dX=dX, tau=tau)


def forward_dynamics_task(params: DynamicParameters, model: Manipulator, X, dX, tau,
                          posture=1) -> np.ndarray:
    """Platform acceleration ``ddX = M_X^{-1} (J_q^T tau - F_X - C_X dX - G_X)``, m/s^2, m/s^2,
    rad/s^2, of the pose ``X``, its rate ``dX`` and the motor torques ``tau`` (N m)."""
    return task_term(params, model, FORWARD, posture, X=X, dX=dX, tau=tau)


def inverse_dynamics_task(params: DynamicParameters, model: Manipulator, X, dX, ddX,
                          posture=1) -> np.ndarray:
    """Motor torques (N m) of a platform motion, ``tau = J_x^T (M_X ddX + C_X dX + G_X + F_X)``."""
    return task_term(params, model, INVERSE, posture, X=X, dX=dX, ddX=ddX)


# ----------------------------------------------------------------------------- joint space
def mass_matrix(params: DynamicParameters, model: Manipulator, q, X) -> np.ndarray:
    """Joint-space inertia ``M(q) = J_x^T M_X J_x`` of eq. 5, (..., 3, 3), symmetric positive
    definite, kg m^2; ``X`` is the pose of the motor angles ``q`` from the direct kinematics."""
    return joint_term(params, model, MASS, q=q, X=X)


def coriolis(params: DynamicParameters, model: Manipulator, q, dq, X) -> np.ndarray:
    """Coriolis and centrifugal torques ``C(q, dq) dq`` of eq. 5 (exact, analytic), N m;
    quadratic in the motor rates ``dq``."""
    return joint_term(params, model, CORIOLIS, q=q, dq=dq, X=X)


def gravity(params: DynamicParameters, model: Manipulator, q, X) -> np.ndarray:
    """Gravity torques ``G(q)`` of eq. 5, N m (zero when ``params.gravity`` is zero)."""
    return joint_term(params, model, GRAVITY, q=q, X=X)


def friction(params: DynamicParameters, model: Manipulator, q, dq, X) -> np.ndarray:
    """Viscous friction of all nine joints seen at the motors, ``F = J_x^T F_X``, N m: the motors'
    ``friction_active * dq`` plus the passive joints' share; linear in ``dq``."""
    return joint_term(params, model, FRICTION, q=q, dq=dq, X=X)


def forward_dynamics(params: DynamicParameters, model: Manipulator, q, dq, X, tau) -> np.ndarray:
    """Motor accelerations of eq. 7, ``ddq = M^{-1} (tau - C dq - G - F)``, rad/s^2.

    ``X`` is the pose of ``q`` from the direct kinematics (the DK FMU in the co-simulation);
    ``tau`` the motor torques, N m.
    """
    return joint_term(params, model, FORWARD, q=q, dq=dq, X=X, tau=tau)


def inverse_dynamics(params: DynamicParameters, model: Manipulator, q, dq, ddq, X) -> np.ndarray:
    """Motor torques of eq. 5, ``tau = M ddq + C dq + G + F``, N m, of the motor angles, rates and
    accelerations ``q, dq, ddq`` at the pose ``X`` of ``q``."""
    return joint_term(params, model, INVERSE, q=q, dq=dq, ddq=ddq, X=X)
