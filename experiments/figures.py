"""The paper's figures: cross-sections of the basic regions (Figs 13-15) and the
circle experiment (Figs 16-18).  matplotlib is imported inside the functions so
that importing this module (``python -m solver`` does) stays light.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from solver.direct_kinematics import dk_all
from solver.grid import default_bounds
from solver.kinematics import ik, jacobians, wrap_angle
from solver.manipulator import Manipulator
from solver.maptensor import label_poses
from solver.ordering import DEFAULT_RULE
from solver.tracker import Tracker
from solver.trajectories import PAPER_CIRCLE, circle_path

#: One colour per label 0..6 (0: outside the tool space).
LABEL_COLOURS = ["#ffffff", "#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948"]


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap
    return plt, ListedColormap(LABEL_COLOURS), BoundaryNorm(np.arange(-0.5, 7.5), 7)


def _save(plt, fig, path) -> Path:
    """Lay out, write and close a figure; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


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
        x and y ranges (m); default :func:`solver.default_bounds`.

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
    J, _ = jacobians(model, X, np.where(np.isnan(q), 1.0, q))     # masked below
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
                        out_dir="results/figures", step: float = 0.004, rule: str = DEFAULT_RULE, bounds=None):
    """Figs 13-15: one PNG per orientation, regions coloured by solution number,
    singular curves (det J = 0) in black.  Returns {phi_deg: (path, stats)}.

    Any manipulator of the interface (:mod:`solver.manipulators`); a 3-RPR's files are named
    ``rpr_regions_phi<deg>.png``.  ``bounds``: x and y ranges (m), default the tool space.
    """
    rrr = model.kind == "3-RRR"
    plt, cmap, norm = _mpl()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {}
    for k, phd in enumerate(phis_deg):
        xs, ys, labels, det_j = cross_section(model, posture, np.deg2rad(phd), step, rule, bounds)
        stats = singular_border_stats(labels, det_j)
        fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
        ax.pcolormesh(xs, ys, labels.T, cmap=cmap, norm=norm, shading="nearest")
        ax.contour(xs, ys, np.where(labels.T > 0, det_j.T, np.nan), levels=[0.0], colors="k", linewidths=1.2)
        ax.plot(*model.reach_discs()[0].T, "k^", ms=8)
        present = [lab for lab in range(1, 7) if np.any(labels == lab)]
        handles = [plt.Rectangle((0, 0), 1, 1, color=LABEL_COLOURS[lab]) for lab in present]
        handles.append(plt.Line2D([], [], color="k", lw=1.2))
        ax.legend(handles, [f"solution {lab}" for lab in present] + ["det J = 0"], loc="upper right",
                  fontsize=8, framealpha=0.9)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title((f"Fig. {13 + k}: basic regions, posture {posture}" if rrr else f"{model.kind} basic regions")
                     + f", phi = {phd:g} deg\n"
                     f"rule {rule!r}; singular nodes on a border: "
                     f"{100 * stats['singular_near_border']:.0f} %, border nodes singular: "
                     f"{100 * stats['border_singular']:.0f} %", fontsize=9)
        name = f"fig{13 + k}_regions_phi{int(phd):+d}.png" if rrr else f"rpr_regions_phi{int(phd):+d}.png"
        path = _save(plt, fig, out_dir / name)
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
    J, _ = jacobians(mt.model, X, np.where(np.isnan(q), 1.0, q))     # masked below
    det_j = np.where(labels > 0, np.linalg.det(J), np.nan)
    fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
    ax.pcolormesh(xs, ys, labels.T, cmap=cmap, norm=norm, shading="nearest")
    if np.any(np.isfinite(det_j)):
        ax.contour(xs, ys, det_j.T, levels=[0.0], colors="k", linewidths=1.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"map tensor posture {mt.posture}, rule {mt.rule!r}, phi = {np.rad2deg(ps[k]):.1f} deg")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return _save(plt, fig, out / f"map_posture{mt.posture}_phi{np.rad2deg(ps[k]):+.0f}.png")


def plot_circle_experiment(model: Manipulator, map_tensor, out_dir="results/figures", n: int = 1000,
                           hard_path=None, hard_map=None, circle: dict | None = None):
    """Figs 16-18: the discretised circle, all DK branches of its joint path, the tracked result.

    Parameters
    ----------
    model : Manipulator
    map_tensor : MapTensor
        Map of the circle's posture (used by the tracker and for the region colours).
    out_dir : path
    n : int
        Points on the circle (paper: 1000).
    hard_path : experiments.suite.SuitePath, optional
        A second path for Fig. 18's right panel (near a singularity, where borders matter).
    hard_map : MapTensor, optional
        Map of ``hard_path``'s posture.
    circle : dict, optional
        Another robot's circle, ``{"center": (x, y), "radius", "phi", "posture"}`` (m, m, rad;
        :func:`solver.robot.default_circle`); default the paper's (:data:`solver.PAPER_CIRCLE`).

    Returns
    -------
    list of Path
        The three PNG files.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if circle is None:
        X, posture, label = circle_path(n), PAPER_CIRCLE["posture"], "paper circle"
    else:
        X = circle_path(n, circle["center"], circle["radius"], circle["phi"])
        posture, label = circle["posture"], f"{model.name} circle"
    q = ik(model, X, posture)
    panels = [(label, X, q, map_tensor)]
    if hard_path is not None:
        panels.append((hard_path.name, hard_path.X, hard_path.q, hard_map))
    return [_fig16(model, X, map_tensor.rule, out / "fig16_circle.png"),
            _fig17(model, q, map_tensor.rule, out / "fig17_all_branches.png"),
            _fig18(model, panels, map_tensor, out / "fig18_tracked.png")]


def _fig16(model, X, rule, path):
    """Fig. 16: the circle on the cross-section of the basic regions at its orientation."""
    plt, cmap, norm = _mpl()
    posture = PAPER_CIRCLE["posture"]
    xs, ys, labels, det_j = cross_section(model, posture, PAPER_CIRCLE["phi"], 0.006, rule)
    fig, ax = plt.subplots(figsize=(6.0, 5.6), dpi=110)
    ax.pcolormesh(xs, ys, labels.T, cmap=cmap, norm=norm, shading="nearest", alpha=0.35)
    ax.contour(xs, ys, np.where(labels.T > 0, det_j.T, np.nan), levels=[0.0], colors="k", linewidths=0.8)
    ax.plot(X[:, 0], X[:, 1], ".", ms=2.5, color="k", label=f"{len(X)} points")
    ax.plot(*model.motors.T, "k^", ms=8, label="motors")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"Fig. 16: the discretised circle (posture {posture}, phi = "
                 f"{np.rad2deg(PAPER_CIRCLE['phi']):g} deg)\nbackground: basic regions, rule {rule!r}", fontsize=9)
    return _save(plt, fig, path)


def _fig17(model, q, rule, path):
    """Fig. 17: every real DK solution of every joint vector, coloured by solution number; the legend
    lists the solutions that are real somewhere on the path (the ones drawn)."""
    plt, _, _ = _mpl()
    sol = dk_all(model, q, rule=rule)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), dpi=110)
    handles = []
    for k in np.nonzero(np.any(sol.real, axis=0))[0]:
        m = sol.real[:, k]
        P = sol.poses[m, k].real
        axes[0].plot(P[:, 0], P[:, 1], ".", ms=2, color=LABEL_COLOURS[k + 1])
        axes[1].plot(np.nonzero(m)[0], np.rad2deg(P[:, 2]), ".", ms=2, color=LABEL_COLOURS[k + 1])
        handles.append(plt.Line2D([], [], ls="", marker="o", ms=5, color=LABEL_COLOURS[k + 1],
                                  label=f"solution {k + 1}"))
    handles.append(axes[0].plot(*model.motors.T, "k^", ms=7, label="motors")[0])
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(handles=handles, fontsize=7, loc="best")
    axes[1].set_xlabel("point index along the circle")
    axes[1].set_ylabel("phi [deg]")
    axes[1].axhline(np.rad2deg(PAPER_CIRCLE["phi"]), color="k", lw=0.6, ls="--")
    fig.suptitle(f"Fig. 17: all real DK solutions of the circle's joint path, coloured by solution number "
                 f"(rule {rule!r}); the true path is phi = {np.rad2deg(PAPER_CIRCLE['phi']):g} deg", fontsize=9)
    return _save(plt, fig, path)


def _fig18(model, panels, map_tensor, path):
    """Fig. 18: the tracked result of each panel's path (title, poses, joints, map), near-border steps marked."""
    plt, _, _ = _mpl()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels), 5.2), dpi=110, squeeze=False)
    for ax, (title, Xt, qt, mt) in zip(axes[0], panels):
        for mode, colour, marker in (("default", "tab:blue", "o"), ("paper", "tab:red", "x")):
            res = Tracker(model, mt, mode=mode).track(qt, Xt[0])
            d = np.abs(res.X - Xt)
            d[:, 2] = np.abs(wrap_angle(res.X[:, 2] - Xt[:, 2]))
            err = d.max(axis=1) > 1e-6
            if mode == "default":
                ax.plot(res.X[:, 0], res.X[:, 1], "-", color=colour, lw=1.2, label="tracked (default mode)")
                nb = res.near_border
                ax.plot(res.X[nb, 0], res.X[nb, 1], "o", mfc="none", color="tab:orange", ms=5,
                        label=f"near a border ({int(nb.sum())} steps)")
            ax.plot(res.X[err, 0], res.X[err, 1], marker, color=colour, ms=6,
                    label=f"{mode} mode: {int(err.sum())} branch errors")
        ax.plot(Xt[:, 0], Xt[:, 1], ":", color="k", lw=0.8, label="true path")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.legend(fontsize=7, loc="best")
        ax.set_title(f"{title} ({len(Xt)} points)", fontsize=9)
    fig.suptitle("Fig. 18: procedures 2-3 at work (map rule "
                 f"{map_tensor.rule!r}, {map_tensor.step[0] * 1e3:g} mm / "
                 f"{np.rad2deg(map_tensor.step[2]):g} deg)", fontsize=10)
    return _save(plt, fig, path)
