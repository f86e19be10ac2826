"""Energies of the 3-RRR: kinetic (body by body), gravitational potential, total, friction power.

Computed with numpy from the body velocities and positions (:mod:`dynamics.geometry`), not from
the mass matrix: they check the equations of motion independently (energy balance), and the
plant reports the total energy (its compiled twin, ``dynamics._kernels.steps``, is tested
against :func:`total_energy`).
"""
from __future__ import annotations

import numpy as np

from solver import Manipulator

from ._checks import task_args
from .geometry import geometry, motion
from .parameters import DynamicParameters, row_constants

__all__ = ["kinetic_energy", "potential_energy", "total_energy", "friction_power"]


def _positions(params, model, X, q):
    """Positions (..., 7, 2) of the platform, proximal and distal centres of mass."""
    g = geometry(model, params.com_platform, X, q)
    Pc = np.stack([X[..., 0] + g.Rcx, X[..., 1] + g.Rcy], -1)[..., None, :]
    e = np.stack([g.cq, g.sq], -1)
    prox = model.motors + params.com_proximal[:, None] * e
    D = model.motors + model.l1[:, None] * e
    dist = D + (params.com_distal / model.l2)[:, None] * np.stack([g.Lx, g.Ly], -1)
    return np.concatenate([Pc, prox, dist], axis=-2)


def kinetic_energy(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Kinetic energy (J, shape (...)) of the seven bodies and the rotors, body by body
    (``1/2 m v^2 + 1/2 I omega^2``) from the body velocities, not from ``M_X``."""
    (X, dX), q = task_args(params, model, X, posture, dX=dX)
    return _kinetic(params, model, X, q, dX)


def _kinetic(params, model, X, q, dX):
    mo = motion(params, model, geometry(model, params.com_platform, X, q), dX)
    return 0.5 * np.sum(row_constants(params)["w"] * mo.v * mo.v, axis=-1)


def potential_energy(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Gravitational potential energy ``-sum_b m_b g . p_b`` (J, shape (...); zero with all masses
    at the origin)."""
    (X,), q = task_args(params, model, X, posture)
    return _potential(params, model, X, q)


def _potential(params, model, X, q):
    m = row_constants(params)["m"]
    p = _positions(params, model, X, q)
    return -np.sum(m * (p @ params.gravity), axis=-1)


def total_energy(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Kinetic plus potential energy, J, shape (...)."""
    (X, dX), q = task_args(params, model, X, posture, dX=dX)
    return _kinetic(params, model, X, q, dX) + _potential(params, model, X, q)


def friction_power(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Power dissipated by viscous friction in the nine joints, W (>= 0), shape (...):
    ``sum b_a dq^2 + sum b_e (omega - dq)^2 + sum b_p (dphi - omega)^2``, with ``omega`` the distal
    link rates."""
    (X, dX), q = task_args(params, model, X, posture, dX=dX)
    mo = motion(params, model, geometry(model, params.com_platform, X, q), dX)
    rates = np.concatenate([mo.dq, mo.omega - mo.dq, dX[..., 2:3] - mo.omega], axis=-1)
    return np.sum(row_constants(params)["b"] * rates * rates, axis=-1)
