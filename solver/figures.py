"""The paper's figures: cross-sections of the basic regions (Figs 13-15) and the
circle experiment (Figs 16-18).  matplotlib is imported inside the functions so
that importing :mod:`solver` stays light.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .kinematics import DEFAULT_RULE, ik, jacobians
from .manipulator import Manipulator
from .maptensor import default_bounds, label_poses

#: One colour per label 0..6 (0: outside the tool space).
LABEL_COLOURS = ["#ffffff", "#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948"]


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap
    return plt, ListedColormap(LABEL_COLOURS), BoundaryNorm(np.arange(-0.5, 7.5), 7)


def cross_section(model: Manipulator, posture: int, phi: float, step: float = 0.004,
                  rule: str = DEFAULT_RULE, bounds=None):
    """Labels and det J on a 2-D grid at one orientation (procedure 1 at exact phi).

    Parameters
    ----------
    model : Manipulator
    posture : int
    phi : float
        Orientation of the section, rad.
    step : float
        Grid spacing in x and y, m.
    rule : str
        Ordering rule.
    bounds : array_like, shape (3, 2), optional
        x and y ranges (m); default :func:`solver.maptensor.default_bounds`.

    Returns
    -------
    xs : ndarray (n_x,), m
    ys : ndarray (n_y,), m
    labels : ndarray of int8 (n_x, n_y)
    det_j : ndarray (n_x, n_y)
        det J at each reachable node (NaN outside), m^5/rad.
    """
    b = default_bounds(model) if bounds is None else np.asarray(bounds, float)
    xs = np.arange(b[0, 0], b[0, 1] + step / 2, step)
    ys = np.arange(b[1, 0], b[1, 1] + step / 2, step)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    X = np.stack([gx, gy, np.full_like(gx, phi)], axis=-1)
    labels, _ = label_poses(model, X, posture, rule)
    q = ik(model, X, posture)
    J, _ = jacobians(model, X, np.nan_to_num(q))
    det_j = np.where(np.isnan(q[..., 0]), np.nan, np.linalg.det(J))
    return xs, ys, labels, det_j


def singular_border_stats(labels: np.ndarray, det_j: np.ndarray) -> dict:
    """How singular curves and label borders coincide on a grid (2-D or 3-D).

    A *border node* has a 4- (or 6-) neighbour with another nonzero label; a
    *singular node* has a reachable neighbour where det J has the other sign
    (the det J = 0 surface passes between them).

    Returns
    -------
    dict
        ``singular_near_border``: share of singular nodes within one cell of a
        border node; ``border_singular``: share of border nodes within one cell
        of a singular node; and the node counts.
    """
    reach = labels != 0
    sign = np.sign(np.nan_to_num(det_j))
    border = np.zeros_like(reach)
    sing = np.zeros_like(reach)
    for ax in range(labels.ndim):
        for sh in (1, -1):
            lab_n = np.roll(labels, sh, axis=ax)
            sg_n = np.roll(sign, sh, axis=ax)
            valid = np.roll(reach, sh, axis=ax) & reach
            edge = [slice(None)] * labels.ndim
            edge[ax] = 0 if sh == 1 else -1
            valid[tuple(edge)] = False                       # no wrap-around at the grid edge
            border |= valid & (lab_n != labels)
            sing |= valid & (sg_n != sign)

    def dilate(m):
        out = m.copy()
        for ax in range(m.ndim):
            for sh in (1, -1):
                out |= np.roll(m, sh, axis=ax)
        return out

    nb, ns = int(border.sum()), int(sing.sum())
    return {"border_nodes": nb, "singular_nodes": ns,
            "singular_near_border": float((sing & dilate(border)).sum() / max(ns, 1)),
            "border_singular": float((border & dilate(sing)).sum() / max(nb, 1))}


def plot_cross_sections(model: Manipulator, posture: int = 1, phis_deg=(-60.0, 0.0, 60.0),
                        out_dir="results/figures", step: float = 0.004, rule: str = DEFAULT_RULE):
    """Figs 13-15: one PNG per orientation, regions coloured by solution number,
    singular curves (det J = 0) in black.  Returns {phi_deg: (path, stats)}.
    """
    plt, cmap, norm = _mpl()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {}
    for k, phd in enumerate(phis_deg):
        xs, ys, labels, det_j = cross_section(model, posture, np.deg2rad(phd), step, rule)
        stats = singular_border_stats(labels, det_j)
        fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
        ax.pcolormesh(xs, ys, labels.T, cmap=cmap, norm=norm, shading="nearest")
        ax.contour(xs, ys, np.where(labels.T > 0, det_j.T, np.nan), levels=[0.0], colors="k", linewidths=1.2)
        ax.plot(*model.motors.T, "k^", ms=8)
        present = [lab for lab in range(1, 7) if np.any(labels == lab)]
        handles = [plt.Rectangle((0, 0), 1, 1, color=LABEL_COLOURS[lab]) for lab in present]
        handles.append(plt.Line2D([], [], color="k", lw=1.2))
        ax.legend(handles, [f"solution {lab}" for lab in present] + ["det J = 0"], loc="upper right",
                  fontsize=8, framealpha=0.9)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"Fig. {13 + k}: basic regions, posture {posture}, phi = {phd:g} deg\n"
                     f"rule {rule!r}; singular nodes on a border: "
                     f"{100 * stats['singular_near_border']:.0f} %, border nodes singular: "
                     f"{100 * stats['border_singular']:.0f} %", fontsize=9)
        fig.tight_layout()
        path = out_dir / f"fig{13 + k}_regions_phi{int(phd):+d}.png"
        fig.savefig(path)
        plt.close(fig)
        result[phd] = (path, stats)
    return result


def plot_map_slice(mt, phi_deg: float, out_dir="results/figures"):
    """Plot the stored map tensor's slice nearest to ``phi_deg`` (with det J = 0 curves).

    Returns the PNG path.
    """
    plt, cmap, norm = _mpl()
    xs, ys, ps = mt.axes()
    k = int(np.argmin(np.abs(np.angle(np.exp(1j * (ps - np.deg2rad(phi_deg)))))))
    labels = mt.labels[:, :, k]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    X = np.stack([gx, gy, np.full_like(gx, ps[k])], axis=-1)
    q = ik(mt.model, X, mt.posture)
    J, _ = jacobians(mt.model, X, np.nan_to_num(q))
    det_j = np.where(labels > 0, np.linalg.det(J), np.nan)
    fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
    ax.pcolormesh(xs, ys, labels.T, cmap=cmap, norm=norm, shading="nearest")
    if np.any(np.isfinite(det_j)):
        ax.contour(xs, ys, det_j.T, levels=[0.0], colors="k", linewidths=1.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"map tensor posture {mt.posture}, rule {mt.rule!r}, phi = {np.rad2deg(ps[k]):.1f} deg")
    fig.tight_layout()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"map_posture{mt.posture}_phi{np.rad2deg(ps[k]):+.0f}.png"
    fig.savefig(path)
    plt.close(fig)
    return path
