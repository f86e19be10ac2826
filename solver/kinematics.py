"""Kinematics of the planar 3-RRR: inverse kinematics in 8 postures, the loop constraints,
the Jacobians J and K of eq. 3 and the singularity measures of eq. 4.

Conventions (``shared/CONVENTIONS.md``): pose ``X = (x, y, phi)`` in m, m, rad; motor
angles ``q = (q1, q2, q3)`` in rad measured from +x; leg ``i`` is ``M_i - D_i - A_i`` with
``D_i = M_i + l1_i (cos q_i, sin q_i)`` and ``A_i = P + R(phi) b_i``.  Every function takes
arrays with any leading shape ``(...)`` and the single call runs through the same code.

The inverse kinematics and J / K are computed by the package's one compiled
implementation (:mod:`solver._kernels.kinematics`); :func:`ik_pose` is that inverse
kinematics for one pose, callable from other numba code.  All six direct-kinematics
solutions are in :mod:`solver.direct_kinematics`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._kernels import kinematics as _kin
from .angles import wrap_angle
from .checks import SolverInputError, as_array, check_instance, check_posture
from . import rpr as _rpr
from .manipulator import Manipulator
from .manipulators import check_manipulator

__all__ = [
    "SingularityMeasures", "wrap_angle", "elbow_points", "platform_points", "constraints", "ik", "ik_pose",
    "posture_of", "jacobians", "singularity_measures", "check_model", "check_manipulator",
]

#: The compiled inverse kinematics of one pose, ``ik_pose(x, y, phi, elbow_bits, motors, l1, l2, platform, q)
#: -> bool`` with ``elbow_bits = posture - 1``: what :func:`ik` runs, for other packages' numba kernels.
ik_pose = _kin.ik_pose


class SingularityMeasures(NamedTuple):
    """Closeness to the singularities of eq. 4.

    Attributes
    ----------
    det_J : ndarray, shape (...)
        ``det J`` (units m^5/rad), zero at the type-1 singularity of eq. 4.
    det_K : ndarray, shape (...)
        ``det K`` (units m^6/rad^3), zero at the type-2 singularity.
    type1 : ndarray, shape (...)
        Inverse condition number of J with its phi column scaled by the mean
        platform radius (dimensionless, in [0, 1]; 0 at the type-1 singularity).
    type2 : ndarray, shape (...)
        ``min_i |sin(beta_i)|``, beta_i the elbow angle of leg i (dimensionless,
        in [0, 1]; 0 when a leg is stretched or folded, the type-2 singularity).
    """

    det_J: np.ndarray
    det_K: np.ndarray
    type1: np.ndarray
    type2: np.ndarray


# ----------------------------------------------------------------------------- helpers
def _rot(c, s, b):
    """R(phi) b for cos/sin arrays ``c, s`` (...) and vectors ``b`` (..., 2)."""
    return np.stack([c * b[..., 0] - s * b[..., 1], s * b[..., 0] + c * b[..., 1]], axis=-1)


def check_model(model) -> Manipulator:
    """``model`` if it is a :class:`Manipulator` (3-RRR), else :class:`SolverInputError`."""
    if isinstance(model, Manipulator):                 # the fast path of every call
        return model
    return check_instance("model", model, Manipulator, "a Manipulator")


def _is_rpr(model) -> bool:
    return isinstance(model, _rpr.RPRManipulator)


def elbow_points(model: Manipulator, q) -> np.ndarray:
    """Elbow positions ``D_i = M_i + l1_i (cos q_i, sin q_i)``.

    Parameters
    ----------
    model : Manipulator
        A 3-RRR (the 3-RPR has no elbows; its platform points: :mod:`solver.rpr`).
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray, shape (..., 3, 2)
        ``D_i`` in m.
    """
    check_model(model)
    q = as_array("q", q)
    return _elbows(model, q)


def _elbows(model, q):
    return model.motors + model.l1[:, None] * np.stack([np.cos(q), np.sin(q)], axis=-1)


def platform_points(model: Manipulator, X) -> np.ndarray:
    """Platform joints ``A_i = P + R(phi) b_i``.

    Parameters
    ----------
    model : Manipulator
        A 3-RRR.
    X : array_like, shape (..., 3)
        Poses ``(x, y, phi)``, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3, 2)
        ``A_i`` in m.
    """
    check_model(model)
    X = as_array("X", X)
    return _platform(model, X)


def _platform(model, X):
    c, s = np.cos(X[..., 2])[..., None], np.sin(X[..., 2])[..., None]
    return X[..., None, :2] + _rot(c, s, model.platform)


def constraints(model: Manipulator, X, q) -> np.ndarray:
    """The loop constraints ``F_i(X, q) = |A_i - D_i|^2 - l2_i^2``.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad (broadcast against ``X``).

    Returns
    -------
    ndarray, shape (..., 3)
        ``F_i`` in m^2; zero where ``(X, q)`` is an assembled configuration.
    """
    if _is_rpr(model):
        return _rpr.constraints(model, X, q)
    check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    L = _platform(model, X) - _elbows(model, q)
    return np.sum(L * L, axis=-1) - model.l2 ** 2


# ----------------------------------------------------------------------------- inverse kinematics
def ik(model: Manipulator, X, posture=1) -> np.ndarray:
    """Inverse kinematics in one posture (paper eq. 11, ``q = g_j(X)``).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    X : array_like, shape (..., 3)
        Poses ``(x, y, phi)``, m, m, rad.
    posture : int or array_like of int, shape broadcastable to (...)
        Posture index 1..8: ``j = 1 + sum_i [s_i < 0] 2^(i-1)`` with ``s_i`` the
        elbow sign of leg ``i`` (CONVENTIONS.md).  Posture 1 has all elbows positive.

    Returns
    -------
    ndarray, shape (..., 3)
        Motor angles in (-pi, pi], rad; NaN (the whole row) where a leg cannot
        reach its platform joint, i.e. the pose is outside the posture's tool space.

    Raises
    ------
    SolverInputError
        Wrong shape, non-finite pose, posture outside 1..8.
    """
    if _is_rpr(model):                             # one posture: rho_i = |B_i - A_i|
        if np.any(check_posture(posture) != 1):
            raise SolverInputError(f"posture: a 3-RPR has posture 1 only, got {posture!r}")
        rho = _rpr.ik(model, X)                    # NaN outside the joint limits (the tool space)
        return np.where(np.any((rho < model.rho_min) | (rho > model.rho_max), axis=-1, keepdims=True), np.nan, rho)
    check_model(model)
    X = as_array("X", X)
    j = check_posture(posture)
    lead = X.shape[:-1]
    try:
        elbow_bits = np.broadcast_to(j - 1, lead)
    except ValueError:
        raise SolverInputError(f"posture: expected a shape broadcastable to {lead}, "
                               f"got {np.shape(posture)}") from None
    Xf = np.ascontiguousarray(X.reshape(-1, 3))
    out = np.empty(Xf.shape)
    _kin.ik_batch(Xf, np.ascontiguousarray(elbow_bits.reshape(-1)), model.motors, model.l1, model.l2,
                  model.platform, out)
    return out.reshape(X.shape)


def posture_of(model: Manipulator, X, q) -> np.ndarray:
    """The posture index 1..8 of configurations ``(X, q)``.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray of int, shape (...)
        ``1 + sum_i [s_i < 0] 2^(i-1)`` with ``s_i`` the sign of the z-component of
        ``(D_i - M_i) x (A_i - D_i)``; a leg exactly stretched or folded (``s_i = 0``)
        counts as positive, as the formula says.
    """
    if _is_rpr(model):
        X, q = as_array("X", X), as_array("q", q)
        return np.ones(np.broadcast_shapes(X.shape, q.shape)[:-1], dtype=int)
    check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    D = _elbows(model, q)
    a, b = D - model.motors, _platform(model, X) - D
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return 1 + np.sum((cross < 0) << np.arange(3), axis=-1)


# ----------------------------------------------------------------------------- Jacobians
def jacobians(model: Manipulator, X, q) -> tuple[np.ndarray, np.ndarray]:
    """The matrices J and K of the velocity model ``J dX/dt + K dq/dt = 0`` (eq. 3).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    J : ndarray, shape (..., 3, 3)
        ``dF/dX``: row ``i`` is ``2 (L_x, L_y, L . dR/dphi b_i)`` with
        ``L = A_i - D_i``; units m (columns x, y) and m^2/rad (column phi).
    K : ndarray, shape (..., 3, 3)
        ``dF/dq``, diagonal, ``K_ii = -2 L . dD_i/dq_i``, m^2/rad.
    """
    if _is_rpr(model):
        return _rpr.jacobians(model, X, q)
    check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    return _jacobians(model, X, q)


def _jacobians(model, X, q):
    try:
        X, q = np.broadcast_arrays(X, q)
    except ValueError:
        raise SolverInputError(f"X, q: expected broadcastable shapes, got {X.shape} and {q.shape}") from None
    Xf, qf = np.ascontiguousarray(X.reshape(-1, 3)), np.ascontiguousarray(q.reshape(-1, 3))
    J, kd = np.empty((len(Xf), 3, 3)), np.empty((len(Xf), 3))
    _kin.jacobian_batch(Xf, qf, model.motors, model.l1, model.l2 ** 2, model.platform, J, kd)
    kd = kd.reshape(X.shape)
    return J.reshape(X.shape + (3,)), kd[..., :, None] * np.eye(3)


def singularity_measures(model: Manipulator, X, q) -> SingularityMeasures:
    """Closeness of configurations to the type-1 and type-2 singularities (eq. 4).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    SingularityMeasures
        ``det_J``, ``det_K`` and the normalised measures ``type1``, ``type2``
        (shape (...), 0 at the singularity, 1 far from it).
    """
    if _is_rpr(model):
        J, K = _rpr.jacobians(model, X, q)
    else:
        check_model(model)
        J, K = _jacobians(model, as_array("X", X), as_array("q", q))
    Js = J * np.array([1.0, 1.0, 1.0 / float(np.mean(model.platform_radius))])
    sv = np.linalg.svd(Js, compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        type1 = np.where(sv[..., 0] > 0, sv[..., -1] / sv[..., 0], 0.0)
    if _is_rpr(model):                             # |K_ii| = 2 rho_i: singular only at a zero leg
        type2 = np.min(np.abs(np.diagonal(K, axis1=-2, axis2=-1)) / (2.0 * model.rho_max), axis=-1)
    else:                                          # |K_ii| = 2 l1 l2 |sin beta_i|
        type2 = np.min(np.abs(np.diagonal(K, axis1=-2, axis2=-1)) / (2.0 * model.l1 * model.l2), axis=-1)
    return SingularityMeasures(np.linalg.det(J), np.linalg.det(K), type1, type2)
