"""Cusps of the type-2 singular surface in a sampled tool space: where the basic regions stop being enough.

The paper's procedures assume a non-cuspidal manipulator: in one posture, the platform changes its
assembly mode only by crossing a singularity (or a characteristic surface).  A manipulator with cusp
points on its type-2 singular surface ``det J(X) = 0`` (J = dF/dX of the velocity model, eq. 3) can
change assembly mode around them without meeting a singularity (Innocenti and Parenti-Castelli; Zein,
Wenger and Chablat for the 3-RPR), and a planar 3-RRR with all revolute legs non-cuspidal can still have
such points for some geometries.  A map built for such a robot labels the tool space correctly, but the
tracker meets more label changes near the cusps; users should know before they drive there.

The test, per posture: on the singular surface S the map ``X -> q`` folds along the kernel ``v`` of J
(``J v = 0``); at a fold ``v`` crosses S, at a cusp it is tangent to S: ``grad(det J) . v = 0``.  The
vector ``g = grad(det J)^T adj(J)`` (``adj(J) = lambda v w^T`` at rank 2, ``w^T J = 0``) is
``lambda (grad(det J) . v) w^T``: well defined whatever the signs chosen for ``v`` and ``w``, continuous
along S, zero at a cusp and reversed across it.  The finder samples S where det J changes sign on the
grid's edges (a linear root along the edge, one secant step), evaluates ``g`` there and flags a grid
cell whose points on S carry opposite ``g`` (cosine below ``-0.5``): a cusp curve crosses that cell.

Each flagged cell is then confirmed by the direct kinematics it implies: at a cusp three assembly
modes of the posture coincide, so the joints of the flagged points must have at least three DK
solutions of that posture within a few cells (``confirm``); a cell where two sheets of S merely pass
close by has two.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .checks import SolverInputError
from .kinematics import ik, jacobians

__all__ = ["CuspScan", "find_cusps", "map_cusps", "refine_cusps", "coinciding_modes"]


class CuspScan(NamedTuple):
    """Result of :func:`find_cusps` for one posture.

    Attributes
    ----------
    posture : int
    poses : ndarray, shape (k, 3)
        One point of S in each flagged cell, m, m, rad (near a cusp point: within a cell).
    singular_points : int
        Points of S sampled (grid edges where det J changes sign).
    cells : int
        Grid cells the scan covered.
    """

    posture: int
    poses: np.ndarray
    singular_points: int
    cells: int

    @property
    def count(self) -> int:
        """Flagged cells (cusp curves cross them)."""
        return len(self.poses)


def _adjugate(J):
    """adj(J) for J of shape (..., 3, 3): the transposed cofactor matrix."""
    c0, c1, c2 = J[..., :, 0], J[..., :, 1], J[..., :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=-2)


def _det_j(model, X, posture):
    """det J at poses X (..., 3) in ``posture``; NaN outside the posture's tool space (and for NaN poses)."""
    fin = np.all(np.isfinite(X), axis=-1, keepdims=True)
    X = np.where(fin, X, 0.0)
    q = np.where(fin, ik(model, X, posture), np.nan)
    ok = np.all(np.isfinite(q), axis=-1)
    J = jacobians(model, X, np.where(ok[..., None], q, 1.0))[0]        # 1: a valid joint value of either kind
    return np.where(ok, np.linalg.det(J), np.nan), J


def _g_vector(model, X, posture, h):
    """``g = grad(det J)^T adj(J)`` at X (n, 3), central differences with steps ``h`` (3,)."""
    grad = np.empty(X.shape)
    for a in range(3):
        e = np.zeros(3)
        e[a] = h[a]
        grad[:, a] = (_det_j(model, X + e, posture)[0] - _det_j(model, X - e, posture)[0]) / (2 * h[a])
    J = _det_j(model, X, posture)[1]
    return np.einsum("na,nab->nb", grad, _adjugate(J))


def _edge_roots(model, posture, X0, X1, d0, d1):
    """Points of S on the edges X0 -> X1 (n, 3) where det J goes from d0 to d1 (opposite signs)."""
    t = d0 / (d0 - d1)
    Xc = X0 + t[:, None] * (X1 - X0)
    dc = _det_j(model, Xc, posture)[0]                 # one secant step on the side that keeps the sign change
    left = np.sign(dc) == np.sign(d0)
    a_t, a_d = np.where(left, t, 0.0), np.where(left, dc, d0)
    b_t, b_d = np.where(left, 1.0, t), np.where(left, d1, dc)
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = np.where(np.isfinite(dc) & (a_d != b_d), a_t + a_d * (b_t - a_t) / (a_d - b_d), t)
    return X0 + np.clip(t2, 0.0, 1.0)[:, None] * (X1 - X0)


def find_cusps(model, posture: int, bounds, shape, chunk: int = 8, confirm: bool = True) -> CuspScan:
    """Cells of a tool-space grid crossed by a cusp curve of the type-2 singular surface (see module doc).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    posture : int
        1..8 (1 for the 3-RPR).
    bounds : array_like, shape (3, 2)
        ``[[x_min, x_max], [y_min, y_max], [phi_min, phi_max]]``, m, m, rad; phi periodic when it spans
        2 pi (the map tensor's grid).
    shape : (int, int, int)
        Node counts in x, y, phi (phi periodic: ``phi_max`` is not a node).
    chunk : int
        Phi slices per batch (memory: about ``nx * ny * chunk * 2 kB``).
    confirm : bool
        Keep only cells whose joints have at least three DK solutions of the posture within three
        cell diagonals (the cusp's three coinciding assembly modes); False keeps every flagged cell.

    Returns
    -------
    CuspScan
    """
    bounds = np.asarray(bounds, dtype=float)
    if bounds.shape != (3, 2) or not np.all(np.isfinite(bounds)) or np.any(bounds[:, 1] <= bounds[:, 0]):
        raise SolverInputError(f"bounds: expected (3, 2) finite [lo, hi] rows with lo < hi, got {bounds.tolist()}")
    shape = tuple(int(n) for n in shape)
    if len(shape) != 3 or min(shape) < 2:
        raise SolverInputError(f"shape: expected three node counts >= 2, got {shape}")
    periodic = bool(np.isclose(bounds[2, 1] - bounds[2, 0], 2 * np.pi))
    step = (bounds[:, 1] - bounds[:, 0]) / (np.array(shape) - np.array([1, 1, 0 if periodic else 1]))
    axes = [bounds[a, 0] + np.arange(shape[a]) * step[a] for a in range(3)]
    h = step * 1e-3
    nk = shape[2] if periodic else shape[2] - 1             # cell layers in phi
    flagged, n_points = [], 0
    for k0 in range(0, nk, chunk):
        ks = np.arange(k0, min(k0 + chunk, nk) + 1)           # node layers k0 .. k0+chunk (wrapping)
        phis = bounds[2, 0] + ks * step[2]
        X = np.stack(np.meshgrid(axes[0], axes[1], phis, indexing="ij"), axis=-1)
        d = _det_j(model, X, posture)[0]
        g_edges = []
        for a in range(3):                                   # g at the root on each edge along axis a
            sl0 = [slice(None)] * 3
            sl1 = [slice(None)] * 3
            sl0[a], sl1[a] = slice(0, -1), slice(1, None)
            d0, d1 = d[tuple(sl0)], d[tuple(sl1)]
            cross = np.isfinite(d0) & np.isfinite(d1) & (np.sign(d0) * np.sign(d1) < 0)
            g = np.full(d0.shape + (3,), np.nan)
            idx = np.nonzero(cross)
            if idx[0].size:
                X0, X1 = X[tuple(sl0)][idx], X[tuple(sl1)][idx]
                Xc = _edge_roots(model, posture, X0, X1, d0[idx], d1[idx])
                gv = _g_vector(model, Xc, posture, h)
                g[idx] = gv / np.linalg.norm(gv, axis=-1, keepdims=True)
                pts = np.full(d0.shape + (3,), np.nan)
                pts[idx] = Xc
                g_edges.append((g, pts))
                n_points += int(idx[0].size)
            else:
                g_edges.append((g, np.full(d0.shape + (3,), np.nan)))
        flagged += _flag_cells(g_edges)
    poses = np.array(flagged).reshape(-1, 3)
    if confirm and len(poses):
        cusps = refine_cusps(model, posture, poses, step)
        near = np.all(np.abs(cusps - poses) <= 2 * step, axis=-1)
        three = coinciding_modes(model, posture, np.where(near[:, None], cusps, poses), 1e-2 * float(np.min(step[:2])))
        poses = cusps[near & (three >= 3)]
    cells = (shape[0] - 1) * (shape[1] - 1) * nk
    return CuspScan(int(posture), poses, n_points, cells)


def map_cusps(mt, coarsen: int = 2) -> CuspScan:
    """:func:`find_cusps` over a map tensor's tool space (its model, posture and bounds), on a grid
    ``coarsen`` times coarser than the map's (a cusp curve is found from the singular surface around it,
    not from its own width).

    Parameters
    ----------
    mt : solver.MapTensor
    coarsen : int
        Node-count divisor per axis (at least 8 nodes per axis are kept).
    """
    shape = tuple(max(8, -(-n // int(coarsen))) for n in mt.shape)
    return find_cusps(mt.model, mt.posture, mt.bounds, shape)


def _flag_cells(g_edges) -> list:
    """Cells (of one chunk) whose edge roots carry opposite g; one root pose per flagged cell."""
    (gx, px), (gy, py), (gp, pp) = g_edges
    # the 12 edges of cell (i, j, k): x-edges (i, j|j+1, k|k+1), y-edges (i|i+1, j, k|k+1), phi-edges (i|i+1, j|j+1, k)
    ex = [gx[:, j:j + gy.shape[1], k:k + gp.shape[2]] for j in (0, 1) for k in (0, 1)]
    ey = [gy[i:i + gx.shape[0], :, k:k + gp.shape[2]] for i in (0, 1) for k in (0, 1)]
    ez = [gp[i:i + gx.shape[0], j:j + gy.shape[1], :] for i in (0, 1) for j in (0, 1)]
    qx = [px[:, j:j + gy.shape[1], k:k + gp.shape[2]] for j in (0, 1) for k in (0, 1)]
    qy = [py[i:i + gx.shape[0], :, k:k + gp.shape[2]] for i in (0, 1) for k in (0, 1)]
    qz = [pp[i:i + gx.shape[0], j:j + gy.shape[1], :] for i in (0, 1) for j in (0, 1)]
    G = np.stack(ex + ey + ez, axis=-2)                       # (cx, cy, ck, 12, 3)
    P = np.stack(qx + qy + qz, axis=-2)
    have = np.all(np.isfinite(G), axis=-1)
    cand = np.nonzero(np.sum(have, axis=-1) >= 2)
    out = []
    if cand[0].size:
        Gc, Pc, hc = G[cand], P[cand], have[cand]
        Gc = np.where(hc[..., None], Gc, 0.0)
        cos = np.einsum("nia,nja->nij", Gc, Gc)
        hit = np.nonzero(np.min(cos, axis=(1, 2)) < -0.5)[0]
        for n in hit:
            out.append(Pc[n][np.argmax(hc[n])])
    return out


def _cusp_residual(model, posture, X, v_ref, h):
    """``(det J, grad(det J) . v)`` at poses X (n, 3), v the unit kernel of J signed like ``v_ref``."""
    d, J = _det_j(model, X, posture)
    grad = np.stack([(_det_j(model, X + e, posture)[0] - _det_j(model, X - e, posture)[0]) / (2 * e[a])
                     for a, e in enumerate(np.diag(h))], axis=-1)
    v = np.linalg.svd(J)[2][..., -1, :]
    v = v * np.where(np.sum(v * v_ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return np.stack([d, np.sum(grad * v, axis=-1)], axis=-1), v


def refine_cusps(model, posture: int, poses, step, iterations: int = 30):
    """Project poses near a cusp curve onto it: Gauss-Newton (minimum-norm steps) on
    ``det J = 0, grad(det J) . v = 0`` (two equations in x, y, phi).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    posture : int
    poses : array_like, shape (k, 3)
        Starting poses, m, m, rad (a :class:`CuspScan`'s).
    step : array_like, shape (3,)
        The grid's spacing, m, m, rad: the finite-difference and trust scales.

    Returns
    -------
    poses : ndarray, shape (k, 3)
        Cusp points, m, m, rad; NaN rows where the iteration left the posture's tool space or did not
        converge (residual above 1e-9 of its start).
    """
    X = np.array(poses, dtype=float).reshape(-1, 3)
    step = np.asarray(step, dtype=float)
    h = step * 1e-5
    _, v_ref = _cusp_residual(model, posture, X, np.ones(3), h)
    moved = np.full(len(X), np.inf)
    for _ in range(iterations):
        r, v_ref = _cusp_residual(model, posture, X, v_ref, h)
        D = np.stack([(_cusp_residual(model, posture, X + e, v_ref, h)[0] - r) / e[a]
                      for a, e in enumerate(np.diag(h))], axis=-1) * step        # (k, 2, 3), per grid step
        bad = ~(np.all(np.isfinite(D), axis=(1, 2)) & np.all(np.isfinite(r), axis=-1))
        X[bad] = np.nan
        Dn = np.where(bad[:, None, None], 0.0, D)
        norm = np.linalg.norm(Dn, axis=-1, keepdims=True) + 1e-300                 # row equilibration
        u = -np.einsum("kab,kb->ka", np.linalg.pinv(Dn / norm), np.where(bad[:, None], 0.0, r) / norm[..., 0])
        u = u / np.maximum(1.0, np.max(np.abs(u), axis=-1, keepdims=True))         # at most a cell a step
        X = X + u * step
        moved = np.max(np.abs(u), axis=-1)
    ok = np.isfinite(moved) & (moved < 1e-7)
    return np.where(ok[:, None], X, np.nan)


def coinciding_modes(model, posture: int, poses, radius: float) -> np.ndarray:
    """DK solutions (real or complex, all postures' slots) of the joints ``ik(poses)`` that lie within
    ``radius`` (m; phi scaled by the platform radius) of the pose: 3 at a cusp, 1 at a regular pose.

    Parameters
    ----------
    poses : array_like, shape (k, 3)
        m, m, rad.
    radius : float
        m.

    Returns
    -------
    ndarray, shape (k,), int
    """
    from .direct_kinematics import dk_all
    X = np.asarray(poses, dtype=float).reshape(-1, 3)
    q = ik(model, X, posture)
    ok = np.all(np.isfinite(q), axis=-1)
    out = np.zeros(len(X), dtype=int)
    if not np.any(ok):
        return out
    sols = dk_all(model, q[ok]).poses                                   # (m, 6, 3) complex
    rho = float(np.mean(model.platform_radius))
    dphi = np.angle(np.exp(1j * (sols[..., 2] - X[ok][:, None, 2])))
    dist = np.sqrt(np.sum(np.abs(sols[..., :2] - X[ok][:, None, :2]) ** 2, axis=-1) + (rho * np.abs(dphi)) ** 2)
    out[ok] = np.sum(dist < radius, axis=-1)
    return out
