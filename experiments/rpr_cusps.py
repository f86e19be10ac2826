"""Cusps of the 3-RPR's singular curve in a joint-space slice, and loops around them.

In the slice ``rho1 = const`` the singular curve (det J = 0 mapped to (rho2, rho3)) has cusp
points where three DK solutions meet.  A small loop of (rho2, rho3) around one brings the legs
back to where they started and the platform to *another* assembly mode without meeting a
singularity: the non-singular assembly-mode change of cuspidal manipulators (Innocenti and
Parenti-Castelli; Zein, Wenger and Chablat), the case the basic regions are made for.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver.checks import SolverInputError
from solver.rpr import ZEIN_RHO1, RPRManipulator, _check_model, _E, _joints, _positive, _rot, _wrap, det_j, ik

from .rpr_scan import dk_all_scan, follow

__all__ = ["cusp_points", "assembly_mode_change_path", "CuspPoints", "ModeChange"]


class CuspPoints(NamedTuple):
    """Cusps of the singular curve in a slice ``rho1 = const``.

    Attributes
    ----------
    joints, poses : ndarray, shape (k, 3)
        ``(rho1, rho2, rho3)``, m, and the pose where three DK solutions coincide, m, m, rad.
    tangent : ndarray, shape (k, 2)
        Unit tangent of the cusp in ``(rho2, rho3)``, pointing into its wedge (the side with two
        more real solutions, seen 1e-4 m away).
    """

    joints: np.ndarray
    poses: np.ndarray
    tangent: np.ndarray


def _slice(model, rho1, t, phi):
    """Slice map ``(t, phi) -> X`` (leg 1 at angle t) and ``D = d(rho2^2, rho3^2)/d(t, phi)`` (..., 2, 2)."""
    u = np.stack([np.cos(t), np.sin(t)], -1)
    X = np.concatenate([model.base[0] + rho1 * u - _rot(phi, model.platform[0]), phi[..., None]], -1)
    B, Rb = _joints(model, X)
    v, w = (B - model.base)[..., 1:, :], (Rb[..., 1:, :] - Rb[..., :1, :]) @ _E.T   # w = dB_i/dphi
    return X, 2.0 * np.stack([np.sum(v * (rho1 * u @ _E.T)[..., None, :], -1), np.sum(v * w, -1)], -1)


def _cusp_eqs(model, rho1, t, phi, rows=(0, 1), h=1e-6):
    """``det D`` and ``grad(det D) . k_j`` for the kernel ``k_j`` of D built from row ``j`` in ``rows``."""
    def det(a, b):
        D = _slice(model, rho1, a, b)[1]
        return D[..., 0, 0] * D[..., 1, 1] - D[..., 0, 1] * D[..., 1, 0]
    D = _slice(model, rho1, t, phi)[1]
    gt, gp = (det(t + h, phi) - det(t - h, phi)) / (2 * h), (det(t, phi + h) - det(t, phi - h)) / (2 * h)
    return det(t, phi), [gp * D[..., j, 0] - gt * D[..., j, 1] for j in rows], D


def cusp_points(model: RPRManipulator, rho1: float, n_grid: int = 600) -> CuspPoints:
    """Cusps of the singular curve ``det J = 0`` in the joint-space slice ``rho1 = const``.

    The slice is the torus of poses ``(t, phi)``, ``B_1 = A_1 + rho1 (cos t, sin t)``, mapped to
    ``(rho2, rho3)``; its singular curve is ``det D = 0`` (``D`` the map's 2x2 derivative, zero
    exactly where ``det J`` is) and a cusp is where the kernel of ``D`` is tangent to that curve
    (Whitney's condition), where three DK solutions merge.  Grid cells (``n_grid`` per angle)
    where both conditions change sign are refined by Newton's method (finite differences).

    Parameters
    ----------
    rho1 : float
        Length of leg 1, m.
    n_grid : int
        Grid samples per angle of the torus.

    Returns
    -------
    CuspPoints
        Sorted by rho2.
    """
    _check_model(model)
    rho1, n_grid = _positive("rho1", rho1), _positive("n_grid", n_grid, int)
    g = -np.pi + 2 * np.pi * np.arange(n_grid) / n_grid
    g1, (ga, gb), _ = _cusp_eqs(model, rho1, *np.meshgrid(g, g, indexing="ij"))
    found = []
    for i, j in np.argwhere(_changes(g1) & _changes(ga) & _changes(gb)):
        z, X, ok = _refine_cusp(model, rho1, np.array([g[i], g[j]]) + np.pi / n_grid)
        if ok and all(np.max(np.abs(_wrap(z - y))) > 1e-6 for y, _ in found):
            found.append((z, X))
    poses = np.array([X for _, X in found]).reshape(-1, 3)
    joints = ik(model, poses)
    tangent = _cusp_tangents(model, rho1, [z for z, _ in found], joints)
    order = np.argsort(joints[:, 1])
    return CuspPoints(joints[order], poses[order], tangent[order])


def _changes(v):
    """Grid cells (torus) whose four corners do not all have one sign of ``v``."""
    c = np.stack([v, np.roll(v, -1, 0), np.roll(v, -1, 1), np.roll(v, (-1, -1), (0, 1))]) > 0
    return c.any(0) & ~c.all(0)


def _refine_cusp(model, rho1, z):
    """Newton's method (finite differences) on the two cusp conditions from ``z = (t, phi)``:
    the cusp (wrapped), its pose and whether it converged to a point where ``D`` is not zero."""
    row = int(np.argmax(np.linalg.norm(_cusp_eqs(model, rho1, *z)[2], axis=-1)))

    def fz(y):
        a, (b,), _ = _cusp_eqs(model, rho1, y[0], y[1], (row,))
        return np.array([a, b])
    for _ in range(40):
        Jz = np.column_stack([(fz(z + e) - fz(z - e)) / 2e-7 for e in 1e-7 * np.eye(2)])
        dz = np.linalg.lstsq(Jz, -fz(z), rcond=None)[0]
        z = z + dz
        if np.max(np.abs(dz)) < 1e-13:
            break
    z = _wrap(z)
    X, D = _slice(model, rho1, z[0], z[1])
    return z, X, bool(np.max(np.abs(dz)) < 1e-9 and np.linalg.norm(D) > 1e-6)


def _cusp_tangents(model, rho1, zs, joints):
    """Unit tangents (k, 2) in (rho2, rho3) of the cusps at torus points ``zs``, pointing into each
    wedge (the side with more real DK solutions 1e-4 m away, by the reference scan)."""
    tangent = np.zeros((len(zs), 2))
    for c, (t, phi) in enumerate(zs):                                   # D has rank 1: its image is
        D = _slice(model, rho1, t, phi)[1]                                  # the cusp's tangent line
        tangent[c] = D[:, np.argmax(np.linalg.norm(D, axis=0))] / (2.0 * joints[c, 1:])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    ends = joints[:, None, :] + 1e-4 * np.concatenate([np.zeros((len(zs), 2, 1)),
                                                       np.stack([tangent, -tangent], 1)], -1)
    k = dk_all_scan(model, np.maximum(ends, 1e-9))[1]
    tangent[k[:, 1] > k[:, 0]] *= -1.0
    return tangent


class ModeChange(NamedTuple):
    """A closed joint-space loop around a cusp and the pose followed along it.

    Attributes
    ----------
    rho, poses : ndarray, shape (N, 3)
        The loop (``rho[-1] == rho[0]``), m, and the followed pose (phi not wrapped), m, m, rad.
    det_j : ndarray, shape (N,)
        ``det J`` along the path, m^4/rad; ``min_abs_det`` its smallest magnitude.
    start, end : ndarray, shape (3,)
        First and last pose (phi wrapped): two assembly modes of the same joints, m, m, rad.
    cusp : ndarray, shape (3,)
        Joints of the encircled cusp, m.
    """

    rho: np.ndarray
    poses: np.ndarray
    det_j: np.ndarray
    start: np.ndarray
    end: np.ndarray
    min_abs_det: float
    cusp: np.ndarray


def assembly_mode_change_path(model: RPRManipulator, rho1: float = ZEIN_RHO1, cusp: int | None = None,
                              radius: float = 0.02, n: int = 1441) -> ModeChange:
    """A circle in ``(rho2, rho3)`` around a cusp that changes assembly mode without a singularity.

    The circle starts inside the cusp's wedge (more real solutions than just outside it) on the
    cusp's tangent; each solution there, nearest the cusp pose first, is followed around the loop
    (:func:`follow`) until one keeps the sign of ``det J`` and comes back as another solution.

    Parameters
    ----------
    rho1, radius : float
        Length of leg 1 (fixed along the loop) and radius of the circle, m.
    cusp : int, optional
        Index into ``cusp_points(model, rho1)``; default: the cusps in turn, farthest from the
        joint limits first, until one gives a mode change.
    n : int
        Number of points of the loop (the first and last are equal).

    Raises
    ------
    SolverInputError
        No such cusp, or no non-singular assembly-mode change around it at this radius.
    """
    _check_model(model)
    rho1, radius, n = _positive("rho1", rho1), _positive("radius", radius), _positive("n", n, int)
    cusps = cusp_points(model, rho1)
    if cusp is None:
        margin = np.minimum(cusps.joints - model.rho_min, model.rho_max - cusps.joints).min(axis=1)
        order = np.argsort(-margin)
    elif not 0 <= cusp < len(cusps.joints):
        raise SolverInputError(f"cusp: expected an index below {len(cusps.joints)}, got {cusp!r}")
    else:
        order = [cusp]
    for c in order:
        found = _loop_around(model, cusps.joints[c], cusps.poses[c], cusps.tangent[c], radius, n)
        if found is not None:
            return found
    raise SolverInputError(f"radius: no non-singular assembly-mode change found at {radius} m around "
                           f"cusp(s) {list(order)} of rho1 = {rho1} m")


def _loop_around(model, qc, Xc, tang, radius, n):
    th = np.linspace(0.0, 2 * np.pi, n)[:, None]                          # start inside the wedge
    loop = qc + radius * np.c_[np.zeros(n), np.cos(th) * tang + np.sin(th) * (_E @ tang)]
    loop[-1] = loop[0]
    if np.any(loop <= 0):
        return None
    X0, k = dk_all_scan(model, loop[0])
    X0 = X0[:k][np.argsort(np.max(np.abs(np.c_[X0[:k, :2] - Xc[:2], _wrap(X0[:k, 2] - Xc[2])]), -1))]
    for X in X0:
        poses, ok = follow(model, loop, X)
        dj = det_j(model, poses)
        end = np.r_[poses[-1, :2], _wrap(poses[-1, 2])]
        moved = np.max(np.abs(np.r_[end[:2] - X[:2], _wrap(end[2] - X[2])]))
        if ok.all() and np.all(np.sign(dj) == np.sign(dj[0])) and moved > 1e-6:
            return ModeChange(loop, poses, dj, X, end, float(np.min(np.abs(dj))), qc)
    return None
