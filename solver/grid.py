"""The grid of a map tensor over the tool space: its default bounds (the exact bounding box of
every reachable pose of a geometry), its default spacing, and its node counts.

Axis ``a`` has ``shape[a]`` nodes at ``origin[a] + i * step[a]``.  The x and y axes run
from ``bounds[a][0]`` to ``bounds[a][1]`` inclusive (``u_a = shape[a] - 1`` increments,
eq. 13-14).  The phi axis covers the circle (-pi, pi]: ``shape[2]`` nodes at
``-pi + (k + 1) * 2 pi / shape[2]`` with index arithmetic modulo ``shape[2]`` (a pose at
phi = -pi is at the node phi = pi).
"""
from __future__ import annotations

import numpy as np

from .checks import SolverInputError
from .manipulator import Manipulator

__all__ = ["DEFAULT_STEP", "default_bounds", "grid_shape", "default_grid"]

#: Default node spacing: 10 mm in x and y, 2 degrees in phi.
DEFAULT_STEP = (0.01, 0.01, float(np.deg2rad(2.0)))


def default_bounds(model: Manipulator, step=DEFAULT_STEP) -> np.ndarray:
    """Bounds that cover the whole reachable tool space, computed from the geometry.

    For an orientation phi the platform centre must lie in the three discs of
    radius ``l1_i + l2_i`` centred at ``M_i - R(phi) b_i`` (and outside the
    discs of radius ``|l1_i - l2_i|``, which cannot move an extreme point of the
    set outward).  The extreme x and y of an intersection of discs lie at an
    extreme point of one disc or at an intersection point of two circles; the
    candidates inside all discs give the exact bounding box per phi.  Its union
    over phi (sampled at 0.05 degrees, plus the largest motion of a platform
    joint between samples), rounded outward to whole steps, contains every
    reachable pose of every posture.

    Parameters
    ----------
    model : Manipulator
    step : (float, float, float)
        Node spacing (m, m, rad); x and y bounds are rounded outward to it.

    Returns
    -------
    ndarray, shape (3, 2)
        ``[[x_min, x_max], [y_min, y_max], [-pi, pi]]``, m, m, rad.
    """
    phis = np.linspace(-np.pi, np.pi, 7201)
    c, s = np.cos(phis)[:, None], np.sin(phis)[:, None]
    b = model.platform
    Rb = np.stack([c * b[:, 0] - s * b[:, 1], s * b[:, 0] + c * b[:, 1]], axis=-1)
    centres, R = model.reach_discs()                                      # (3, 2), (3,)
    C = centres - Rb                                                      # (n, 3, 2) disc centres
    cands = [C + R[:, None] * np.array(e) for e in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        d = C[:, j] - C[:, i]
        dist = np.linalg.norm(d, axis=-1, keepdims=True)
        a = (R[i] ** 2 - R[j] ** 2 + dist ** 2) / (2 * dist)
        h = np.sqrt(np.maximum(R[i] ** 2 - a ** 2, 0.0))
        e = d / dist
        perp = np.stack([-e[:, 1], e[:, 0]], axis=-1)
        base = C[:, i] + a * e
        cands += [(base + h * perp)[:, None, :], (base - h * perp)[:, None, :]]
    P = np.concatenate(cands, axis=1)                                     # (n, m, 2)
    inside = np.all(np.linalg.norm(P[:, :, None, :] - C[:, None, :, :], axis=-1) <= R * (1 + 1e-12), axis=-1)
    if not np.any(inside):
        raise SolverInputError(f"model: the geometry {model.name!r} has no reachable pose")
    margin = float(np.max(model.platform_radius)) * (phis[1] - phis[0])
    lo = np.where(inside[..., None], P, np.inf).min(axis=(0, 1)) - margin
    hi = np.where(inside[..., None], P, -np.inf).max(axis=(0, 1)) + margin
    st = np.asarray(step[:2], dtype=float)
    lo, hi = np.floor(lo / st) * st, np.ceil(hi / st) * st
    return np.array([[lo[0], hi[0]], [lo[1], hi[1]], [-np.pi, np.pi]])


def grid_shape(bounds, step) -> tuple:
    """Node counts for ``bounds`` (3, 2) at spacing ``step`` (m, m, rad): x, y inclusive, phi periodic."""
    span = np.asarray(bounds, float)[:, 1] - np.asarray(bounds, float)[:, 0]
    return (int(round(span[0] / step[0])) + 1, int(round(span[1] / step[1])) + 1, int(round(span[2] / step[2])))


def default_grid(model: Manipulator, step=DEFAULT_STEP) -> tuple[np.ndarray, tuple]:
    """Bounds and shape of the grid at spacing ``step`` over the whole reachable tool space."""
    bounds = default_bounds(model, step)
    return bounds, grid_shape(bounds, step)
