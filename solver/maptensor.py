"""Procedure 1 (the map tensor) and procedure 2 (near labels) of the paper.

Procedure 1 (section 3.2): discretise the tool space of one posture into a
regular grid of nodes, map every node into the joint space with the posture's
inverse kinematics, map it back with *all* direct-kinematics solutions numbered
by one ordering rule, and label the node with the number of the solution that
is the node itself (eq. 15-16).  Label 0: outside the tool space.

Procedure 2 (section 4.1): the labels of the nodes within a weighted distance
``r`` of a pose (eq. 18-19).  One label: the pose is inside a basic region, far
from its border; several: near a border.  Computed by grid index arithmetic
over a precomputed stencil of node offsets: O(1) per pose, no scan.

The grid is described in :mod:`solver.grid`, the file format in :mod:`solver.mapfile`, the
cache shared by every command in :mod:`solver.mapcache`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import mapfile
from ._kernels import maptensor as _mk
from .checks import SolverInputError, as_array, check_posture
from .direct_kinematics import dk_all
from .grid import DEFAULT_STEP, default_bounds, grid_shape
from .kinematics import ik, wrap_angle
from .manipulators import check_manipulator
from .manipulator import Manipulator
from .ordering import DEFAULT_RULE, rule_code
from .progress import bar

__all__ = ["MapTensor", "label_poses", "MATCH_TOL"]

#: A node is labelled with the DK solution within this distance of it (m, m, rad).
MATCH_TOL = 1e-6


def _pose_distance(a, b):
    d = np.abs(a - b)
    d[..., 2] = np.abs(wrap_angle(a[..., 2] - b[..., 2]))
    return d.max(axis=-1)


def label_poses(model: Manipulator, X, posture: int, rule: str = DEFAULT_RULE):
    """Procedure 1, steps 4-6, for arbitrary poses: the number of the DK solution that is the pose.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    posture : int
        Posture 1..8.
    rule : str
        Ordering rule (:data:`solver.ORDERING_RULES`).

    Returns
    -------
    labels : ndarray of int8, shape (...)
        Solution number 1..6; 0 where the pose is outside the posture's tool space.
    mismatch : ndarray of float, shape (...)
        Distance from the pose to the solution chosen (0 outside); above
        :data:`MATCH_TOL` would mean the DK did not find the node (never seen).
    """
    X = as_array("X", X)
    lead = X.shape[:-1]
    Xf = X.reshape(-1, 3)
    q = ik(model, Xf, posture)
    reach = ~np.isnan(q[:, 0])
    labels = np.zeros(len(Xf), dtype=np.int8)
    mismatch = np.zeros(len(Xf))
    if np.any(reach):
        sol = dk_all(model, q[reach], rule=rule)
        d = np.where(sol.real, _pose_distance(sol.poses.real, Xf[reach][:, None, :]), np.inf)
        m = np.argmin(d, axis=1)
        labels[reach] = (m + 1).astype(np.int8)
        mismatch[reach] = d[np.arange(len(m)), m]
    return labels.reshape(lead), mismatch.reshape(lead)


def _grid(bounds, shape):
    """Node spacing and the coordinates of node (0, 0, 0), each (3,), of a grid; phi over the full
    circle is periodic (its first node one step above the lower bound)."""
    n = np.asarray(shape, dtype=float)
    span = bounds[:, 1] - bounds[:, 0]
    step = span / np.maximum(n - 1, 1)
    origin = bounds[:, 0].copy()
    if _periodic(bounds):
        step[2] = span[2] / n[2]
        origin[2] = bounds[2, 0] + step[2]
    return step, origin


def _periodic(bounds) -> bool:
    return bool(abs((bounds[2, 1] - bounds[2, 0]) - 2 * np.pi) < 1e-9)


def _check_build(model, posture, bounds, shape, rule):
    """The arguments of :meth:`MapTensor.build`, checked and with their defaults."""
    check_manipulator(model)
    posture = int(check_posture(posture))
    if posture > model.n_postures:
        raise SolverInputError(f"posture: a {model.kind} has postures 1..{model.n_postures}, got {posture}")
    rule = DEFAULT_RULE if rule is None else rule
    rule_code(rule)
    bounds = default_bounds(model) if bounds is None else as_array("bounds", bounds, (3, 2))
    if bounds.shape != (3, 2) or np.any(bounds[:, 1] <= bounds[:, 0]):
        raise SolverInputError(f"bounds: expected shape (3, 2) with min < max per axis, got {bounds.tolist()}")
    shape = tuple(int(n) for n in (grid_shape(bounds, DEFAULT_STEP) if shape is None else shape))
    if len(shape) != 3 or min(shape) < 2:
        raise SolverInputError(f"shape: expected three node counts >= 2, got {shape}")
    return posture, bounds, shape, rule


def _label_grid(model, posture, rule, bounds, shape, progress):
    """Procedure 1 over a grid, phi slice by phi slice: labels (int8, ``shape``) and the largest
    node-solution distance."""
    step, origin = _grid(bounds, shape)
    xs, ys, phis = (origin[a] + np.arange(shape[a]) * step[a] for a in range(3))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    labels = np.zeros(shape, dtype=np.int8)
    worst = 0.0
    with bar(total=shape[0] * shape[1] * shape[2], desc=f"map tensor posture {posture}", unit="node",
             unit_scale=True, enabled=progress) as progress_bar:
        for k, phi in enumerate(phis):
            X = np.stack([gx, gy, np.full_like(gx, phi)], axis=-1)
            labels[:, :, k], mm = label_poses(model, X, posture, rule)
            worst = max(worst, float(mm.max()))
            progress_bar.update(gx.size)
    return labels, worst


@dataclass(frozen=True, eq=False)
class MapTensor:
    """The map tensor of one posture (paper eq. 16) with its grid.

    Attributes
    ----------
    model : Manipulator
        The geometry the map was built for.
    posture : int
        Posture 1..8.
    bounds : ndarray, shape (3, 2)
        ``[[x_min, x_max], [y_min, y_max], [phi_min, phi_max]]``, m, m, rad.
    shape : tuple of int
        Nodes per axis ``(n_x, n_y, n_phi)``.
    rule : str
        The ordering rule that numbered the DK solutions.
    labels : ndarray of int8, shape ``shape``
        Solution number of each node, 0 outside the tool space (read-only).
    stats : dict
        Build statistics stored with the map (node counts, label counts, largest node-solution
        distance); no wall times, so the same build gives the same file.
    build_seconds : float or None
        Wall time of :meth:`build`, s; None for a map read from a file (never stored).
    step : ndarray, shape (3,)
        Node spacing per axis, m, m, rad (derived from ``bounds`` and ``shape``).
    origin : ndarray, shape (3,)
        Coordinates of node (0, 0, 0), m, m, rad (derived from ``bounds`` and ``shape``).
    """

    model: Manipulator
    posture: int
    bounds: np.ndarray
    shape: tuple
    rule: str
    labels: np.ndarray
    stats: dict = field(default_factory=dict)
    build_seconds: float | None = None
    step: np.ndarray = field(init=False, repr=False)
    origin: np.ndarray = field(init=False, repr=False)
    _stencils: dict = field(init=False, repr=False, default_factory=dict)     # procedure-2 stencils by (r, w)

    def __post_init__(self):
        # the derived grid data, set once here (a frozen dataclass sets fields with object.__setattr__)
        for name, value in zip(("step", "origin"), _grid(self.bounds, self.shape)):
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ grid
    @property
    def periodic(self) -> bool:
        """Whether the phi axis covers the full circle (index arithmetic modulo n_phi)."""
        return _periodic(self.bounds)

    def axes(self) -> list[np.ndarray]:
        """Node coordinates per axis: [x (n_x,), y (n_y,), phi (n_phi,)]."""
        return [self.origin[a] + np.arange(self.shape[a]) * self.step[a] for a in range(3)]

    def node_pose(self, index) -> np.ndarray:
        """Pose of node(s) ``index`` (..., 3) int -> (..., 3) float (m, m, rad)."""
        return self.origin + np.asarray(index) * self.step

    @property
    def default_weights(self) -> np.ndarray:
        """Eq. 19 weights (a, b, c) = (1, 1, rho^2), rho the mean platform radius: distance in m."""
        rho = float(np.mean(self.model.platform_radius))
        return np.array([1.0, 1.0, rho * rho])

    def default_radius(self, weights=None) -> float:
        """Procedure-2 radius: 2.5 times the largest weighted node spacing (paper: 2-3 spacings)."""
        w = self.default_weights if weights is None else np.asarray(weights, float)
        return float(2.5 * np.max(np.sqrt(w) * self.step))

    # ------------------------------------------------------------------ procedure 1
    @classmethod
    def build(cls, model: Manipulator, posture: int, bounds=None, shape=None, rule: str | None = None,
              progress: bool | None = None) -> "MapTensor":
        """Procedure 1: label every node of a regular grid of the tool space.

        Parameters
        ----------
        model : Manipulator
        posture : int
            Posture 1..8.
        bounds : array_like, shape (3, 2), optional
            Grid bounds (m, m, rad); default :func:`default_bounds` (the whole
            reachable tool space, phi over (-pi, pi]).
        shape : (int, int, int), optional
            Nodes per axis; default from :data:`DEFAULT_STEP` over the bounds.
        rule : str, optional
            Ordering rule; default :data:`solver.DEFAULT_RULE`.
        progress : bool, optional
            A progress bar on stderr over the phi slices (:func:`solver.progress.bar`: shown once
            the build has run 2 s); None: the process default (:mod:`solver.progress`).

        Returns
        -------
        MapTensor
            Its ``build_seconds`` is the wall time of the labelling, s.

        Notes
        -----
        Runs phi slice by phi slice (memory bounded by one slice); the labels
        are deterministic: the same inputs give byte-identical labels.
        """
        posture, bounds, shape, rule = _check_build(model, posture, bounds, shape, rule)
        t0 = time.perf_counter()
        labels, worst = _label_grid(model, posture, rule, bounds, shape, progress)
        seconds = time.perf_counter() - t0
        counts = np.bincount(labels.ravel(), minlength=7)
        stats = {"nodes": int(labels.size), "reachable_nodes": int(labels.size - counts[0]),
                 "label_counts": [int(c) for c in counts], "max_node_solution_distance": worst}
        labels.setflags(write=False)
        return cls(model, posture, bounds, shape, rule, labels, stats, build_seconds=seconds)

    # ------------------------------------------------------------------ procedure 2
    def label_at(self, X) -> np.ndarray:
        """The label of the node nearest to each pose.

        Parameters
        ----------
        X : array_like, shape (..., 3)
            Poses, m, m, rad.

        Returns
        -------
        ndarray of int8, shape (...)
            0 outside the grid.
        """
        X = as_array("X", X)
        lead = X.shape[:-1]
        Xf = np.ascontiguousarray(X.reshape(-1, 3))
        out = np.empty(len(Xf), dtype=np.int8)
        _mk.label_at_batch(self.labels, self.origin, self.step, self.periodic, Xf, out)
        return out.reshape(lead)

    def _stencil(self, r, w):
        key = (float(r), tuple(float(v) for v in w))
        cache = self._stencils
        if key not in cache:
            # offsets o from the cell base floor(f) whose node can be within r of a pose in the
            # cell: the nearest point of [0, 1) to o_a is o_a - 1 (o_a >= 1), 0, or -o_a (o_a <= 0)
            reach = np.ceil(r / (np.sqrt(w) * self.step)).astype(int) + 1
            grids = np.meshgrid(*[np.arange(-k, k + 2) for k in reach], indexing="ij")
            off = np.stack([g.ravel() for g in grids], axis=-1).astype(np.int64)    # (S, 3) offsets
            gap = np.maximum(np.maximum(off - 1, -off), 0) * self.step
            keep = np.sum(w * gap * gap, axis=1) <= r * r * (1 + 1e-12)
            cache[key] = np.ascontiguousarray(off[keep])
        return cache[key]

    def near_labels(self, X, r: float | None = None, weights=None) -> np.ndarray:
        """Procedure 2 (eq. 18-19): which labels the nodes within distance ``r`` of a pose carry.

        Parameters
        ----------
        X : array_like, shape (..., 3)
            Poses, m, m, rad.
        r : float, optional
            Radius in the units of the weighted distance; default
            :meth:`default_radius`.
        weights : array_like, shape (3,), optional
            ``(a, b, c)`` of eq. 19, ``||dX|| = sqrt(a dx^2 + b dy^2 + c dphi^2)``
            with ``dphi`` wrapped; default :attr:`default_weights` (1, 1, rho^2).

        Returns
        -------
        ndarray of bool, shape (..., 7)
            ``out[..., l]`` is true when a near node has label ``l`` (0..6).
            Nodes outside the grid do not exist and contribute nothing.
        """
        X = as_array("X", X)
        w = self.default_weights if weights is None else as_array("weights", weights, (3,))
        if np.any(w <= 0):
            raise SolverInputError(f"weights: expected three positive numbers, got {w.tolist()}")
        r = self.default_radius(w) if r is None else float(r)
        if not (np.isfinite(r) and r > 0):
            raise SolverInputError(f"r: expected a positive radius, got {r!r}")
        lead = X.shape[:-1]
        Xf = np.ascontiguousarray(X.reshape(-1, 3))
        out = np.empty((len(Xf), 7), dtype=np.bool_)
        _mk.near_mask_batch(self.labels, self.origin, self.step, self.periodic, Xf, r * r,
                            np.ascontiguousarray(w, dtype=float), self._stencil(r, w), out)
        return out.reshape(lead + (7,))

    # ------------------------------------------------------------------ measurements
    def border_nodes(self, r: float | None = None, weights=None) -> np.ndarray:
        """Reachable nodes whose procedure-2 neighbourhood holds more than one nonzero label.

        Returns
        -------
        ndarray of bool, shape ``shape``
        """
        w = self.default_weights if weights is None else np.asarray(weights, float)
        r = self.default_radius(w) if r is None else float(r)
        lab = self.labels
        border = np.zeros(self.shape, dtype=bool)
        for o in self._stencil(r, w):
            dist2 = np.sum(w * (o * self.step) ** 2)
            if dist2 > r * r or not np.any(o):
                continue
            other = self._shifted(lab, o)
            border |= (other != lab) & (other != 0)
        return border & (lab != 0)

    def _shifted(self, lab, o):
        """``out[i] = lab[i + o]``: 0 beyond the x/y edges (and the phi edges unless periodic)."""
        out = np.roll(lab, [-int(k) for k in o], axis=(0, 1, 2))
        for a in range(2 if self.periodic else 3):
            k, edge = int(o[a]), [slice(None)] * 3
            if k:
                edge[a] = slice(self.shape[a] - k, None) if k > 0 else slice(0, -k)
                out[tuple(edge)] = 0
        return out

    def border_fraction(self, r: float | None = None, weights=None) -> float:
        """Share of reachable nodes that are near a label border (procedure 2 says 'near')."""
        reach = np.count_nonzero(self.labels)
        return float(np.count_nonzero(self.border_nodes(r, weights)) / max(reach, 1))

    def summary(self) -> str:
        """A human-readable description (CLI ``inspect``)."""
        counts = np.bincount(self.labels.ravel(), minlength=7)
        lines = [f"map tensor: posture {self.posture}, rule {self.rule!r}, geometry {self.model.name!r} "
                 f"({self.model.digest()[:12]})",
                 f"  grid {self.shape[0]} x {self.shape[1]} x {self.shape[2]} = {self.labels.size:,} nodes, "
                 f"step {self.step[0] * 1e3:.1f} mm, {self.step[1] * 1e3:.1f} mm, "
                 f"{np.rad2deg(self.step[2]):.2f} deg",
                 f"  bounds x [{self.bounds[0, 0]:.3f}, {self.bounds[0, 1]:.3f}] m, "
                 f"y [{self.bounds[1, 0]:.3f}, {self.bounds[1, 1]:.3f}] m, phi (-pi, pi]",
                 f"  reachable nodes {self.labels.size - counts[0]:,} "
                 f"({100 * (1 - counts[0] / self.labels.size):.1f} %)"]
        for lab in range(1, 7):
            if counts[lab]:
                lines.append(f"  region {lab}: {counts[lab]:,} nodes "
                             f"({100 * counts[lab] / max(self.labels.size - counts[0], 1):.1f} % of reachable)")
        if "max_node_solution_distance" in self.stats:
            lines.append(f"  max node solution distance: {self.stats['max_node_solution_distance']}")
        return "\n".join(lines)

    # ------------------------------------------------------------------ file (solver.mapfile)
    def checksum(self) -> str:
        """SHA-256 of the labels (C order, int8)."""
        return mapfile.labels_checksum(self.labels)

    def metadata(self) -> dict:
        """The file's metadata record (:func:`solver.mapfile.metadata`)."""
        return mapfile.metadata(self)

    def save(self, path) -> Path:
        """Write the map to a compressed ``.npz`` file with its metadata; returns the path."""
        return mapfile.save_map(self, path)

    @classmethod
    def load(cls, path, model: Manipulator | None = None, posture: int | None = None) -> "MapTensor":
        """Read a map written by :meth:`save`, refusing anything that does not check out
        (:class:`MapTensorFileError`; the checks are :func:`solver.mapfile.read_map`'s).

        ``model`` / ``posture``, if given, are the geometry and posture the file must hold.
        """
        return cls(**mapfile.read_map(path, model, posture))
