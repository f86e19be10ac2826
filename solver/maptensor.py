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

The grid
--------
Axis ``a`` has ``shape[a]`` nodes at ``origin[a] + i * step[a]``.  The x and y
axes run from ``bounds[a][0]`` to ``bounds[a][1]`` inclusive (``u_a = shape[a] - 1``
increments, eq. 13-14).  The phi axis covers the circle (-pi, pi]: ``shape[2]``
nodes at ``-pi + (k + 1) * 2 pi / shape[2]`` with index arithmetic modulo
``shape[2]`` (a pose at phi = -pi is at the node phi = pi).

The file
--------
``save`` writes a compressed ``.npz`` holding the int8 labels and a JSON
metadata record: format version, geometry (and its SHA-256 digest), posture,
bounds, shape, ordering rule, library version, build statistics and the
SHA-256 of the labels.  ``load`` refuses an unknown format version, a
checksum mismatch, a truncated or foreign file, and a geometry or posture
other than the expected one, with a message that says which.
"""
from __future__ import annotations

import hashlib
import io
import json
import sys
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _map_kernel as _mk
from ._checks import SolverInputError, as_array, check_posture
from .kinematics import DEFAULT_RULE, ORDERING_RULES, dk_all, ik, wrap_angle
from .manipulator import Manipulator

__all__ = ["MapTensor", "MapTensorFileError", "FORMAT_VERSION", "DEFAULT_STEP",
           "default_bounds", "label_poses", "grid_shape", "load_or_build"]

#: Version of the map file format; the loader refuses any other.
FORMAT_VERSION = 1
#: Default node spacing: 10 mm in x and y, 2 degrees in phi.
DEFAULT_STEP = (0.01, 0.01, float(np.deg2rad(2.0)))
#: A node is labelled with the DK solution within this distance of it (m, m, rad).
MATCH_TOL = 1e-6


class MapTensorFileError(ValueError):
    """A map tensor file cannot be used: unreadable, tampered, foreign geometry, wrong version."""


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
    C = model.motors - Rb                                                 # (n, 3, 2) disc centres
    R = model.l1 + model.l2                                               # (3,) radii
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


def _progress(enabled, text):
    if enabled:
        sys.stderr.write("\r" + text)
        sys.stderr.flush()


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
        Build statistics (time, counts, largest node-solution distance).
    """

    model: Manipulator
    posture: int
    bounds: np.ndarray
    shape: tuple
    rule: str
    labels: np.ndarray
    stats: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ grid
    @property
    def periodic(self) -> bool:
        """Whether the phi axis covers the full circle (index arithmetic modulo n_phi)."""
        return bool(abs((self.bounds[2, 1] - self.bounds[2, 0]) - 2 * np.pi) < 1e-9)

    @property
    def step(self) -> np.ndarray:
        """Node spacing per axis, shape (3,), m, m, rad."""
        cached = self.__dict__.get("_step")
        if cached is not None:
            return cached
        n = np.asarray(self.shape, dtype=float)
        span = self.bounds[:, 1] - self.bounds[:, 0]
        st = span / np.maximum(n - 1, 1)
        if self.periodic:
            st[2] = span[2] / n[2]
        object.__setattr__(self, "_step", st)
        return st

    @property
    def origin(self) -> np.ndarray:
        """Coordinates of node (0, 0, 0), shape (3,), m, m, rad."""
        cached = self.__dict__.get("_origin")
        if cached is not None:
            return cached
        o = self.bounds[:, 0].copy()
        if self.periodic:
            o[2] = self.bounds[2, 0] + self.step[2]
        object.__setattr__(self, "_origin", o)
        return o

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
              progress: bool = False) -> "MapTensor":
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
        progress : bool
            Print a progress line to stderr.

        Returns
        -------
        MapTensor

        Notes
        -----
        Runs phi slice by phi slice (memory bounded by one slice); the labels
        are deterministic: the same inputs give byte-identical labels.
        """
        if not isinstance(model, Manipulator):
            raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")
        posture = int(check_posture(posture))
        rule = DEFAULT_RULE if rule is None else rule
        if rule not in ORDERING_RULES:
            raise SolverInputError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
        bounds = default_bounds(model) if bounds is None else as_array("bounds", bounds, (3, 2))
        if bounds.shape != (3, 2) or np.any(bounds[:, 1] <= bounds[:, 0]):
            raise SolverInputError(f"bounds: expected shape (3, 2) with min < max per axis, got {bounds.tolist()}")
        if shape is None:
            span = bounds[:, 1] - bounds[:, 0]
            shape = (int(round(span[0] / DEFAULT_STEP[0])) + 1, int(round(span[1] / DEFAULT_STEP[1])) + 1,
                     int(round(span[2] / DEFAULT_STEP[2])))
        shape = tuple(int(n) for n in shape)
        if len(shape) != 3 or min(shape) < 2:
            raise SolverInputError(f"shape: expected three node counts >= 2, got {shape}")
        empty = cls(model, posture, bounds, shape, rule, np.zeros(shape, dtype=np.int8))
        xs, ys, phis = empty.axes()
        labels = np.zeros(shape, dtype=np.int8)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        t0 = time.perf_counter()
        worst = 0.0
        for k, phi in enumerate(phis):
            X = np.stack([gx, gy, np.full_like(gx, phi)], axis=-1)
            labels[:, :, k], mm = label_poses(model, X, posture, rule)
            worst = max(worst, float(mm.max()))
            if progress and (k % 4 == 0 or k == len(phis) - 1):
                done = (k + 1) / len(phis)
                rate = (k + 1) * gx.size / (time.perf_counter() - t0)
                _progress(True, f"map tensor posture {posture}: {100 * done:5.1f}% "
                                f"({(k + 1) * gx.size:,} nodes, {rate:,.0f} nodes/s)")
        if progress:
            sys.stderr.write("\n")
        seconds = time.perf_counter() - t0
        counts = np.bincount(labels.ravel(), minlength=7)
        stats = {"build_seconds": round(seconds, 3), "nodes": int(labels.size),
                 "reachable_nodes": int(labels.size - counts[0]),
                 "label_counts": [int(c) for c in counts],
                 "max_node_solution_distance": worst}
        labels.setflags(write=False)
        return cls(model, posture, bounds, shape, rule, labels, stats)

    # ------------------------------------------------------------------ procedure 2
    def _fractional_index(self, X):
        return (X - self.origin) / self.step

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
        cache = self.__dict__.setdefault("_stencils", {})
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
        """``out[i] = lab[i + o]`` with 0 beyond the x/y edges and wrap-around in phi."""
        out = np.roll(lab, -int(o[2]), axis=2) if self.periodic else lab
        res = np.zeros_like(lab)
        sl_dst, sl_src = [], []
        for a in range(2 if self.periodic else 3):
            k = int(o[a])
            n = self.shape[a]
            if k >= 0:
                sl_dst.append(slice(0, n - k))
                sl_src.append(slice(k, n))
            else:
                sl_dst.append(slice(-k, n))
                sl_src.append(slice(0, n + k))
        if self.periodic:
            sl_dst.append(slice(None))
            sl_src.append(slice(None))
        res[tuple(sl_dst)] = out[tuple(sl_src)]
        return res

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
        for key in ("build_seconds", "max_node_solution_distance"):
            if key in self.stats:
                lines.append(f"  {key.replace('_', ' ')}: {self.stats[key]}")
        return "\n".join(lines)

    # ------------------------------------------------------------------ file
    def checksum(self) -> str:
        """SHA-256 of the labels (C order, int8)."""
        return hashlib.sha256(np.ascontiguousarray(self.labels, dtype=np.int8).tobytes()).hexdigest()

    def metadata(self) -> dict:
        from . import __version__
        return {"format": "rrr-dk map tensor", "format_version": FORMAT_VERSION,
                "library_version": __version__, "geometry": self.model.to_dict(),
                "geometry_sha256": self.model.digest(), "posture": self.posture,
                "bounds": self.bounds.tolist(), "shape": list(self.shape), "rule": self.rule,
                "rule_description": ORDERING_RULES[self.rule], "labels_dtype": "int8",
                "labels_sha256": self.checksum(), "stats": self.stats}

    def save(self, path) -> Path:
        """Write the map to a compressed ``.npz`` file with its metadata; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = json.dumps(self.metadata(), sort_keys=True)
        buf = io.BytesIO()
        np.savez_compressed(buf, labels=np.ascontiguousarray(self.labels), metadata=np.array(meta))
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_bytes(buf.getvalue())
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path, model: Manipulator | None = None, posture: int | None = None) -> "MapTensor":
        """Read a map written by :meth:`save`, refusing anything that does not check out.

        Parameters
        ----------
        path : str or Path
        model : Manipulator, optional
            If given, the file's geometry must be this one.
        posture : int, optional
            If given, the file's posture must be this one.

        Raises
        ------
        MapTensorFileError
            Missing, truncated or foreign file; unknown format version; labels
            whose SHA-256 differs from the recorded one; another geometry or posture.
        """
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as data:
                if "labels" not in data.files or "metadata" not in data.files:
                    raise MapTensorFileError(f"{path}: not a map tensor file (arrays {data.files})")
                labels = np.array(data["labels"])
                meta = json.loads(str(data["metadata"]))
        except MapTensorFileError:
            raise
        except FileNotFoundError:
            raise MapTensorFileError(f"{path}: no such map tensor file") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
            raise MapTensorFileError(f"{path}: unreadable or truncated map tensor file ({exc})") from None
        version = meta.get("format_version")
        if meta.get("format") != "rrr-dk map tensor" or version != FORMAT_VERSION:
            raise MapTensorFileError(f"{path}: format version {version!r} of {meta.get('format')!r}; "
                                     f"this library reads version {FORMAT_VERSION}")
        if labels.dtype != np.int8 or list(labels.shape) != list(meta.get("shape", [])):
            raise MapTensorFileError(f"{path}: labels {labels.dtype} {labels.shape} do not match the "
                                     f"metadata shape {meta.get('shape')}")
        digest = hashlib.sha256(np.ascontiguousarray(labels).tobytes()).hexdigest()
        if digest != meta.get("labels_sha256"):
            raise MapTensorFileError(f"{path}: labels checksum {digest[:16]}... does not match the recorded "
                                     f"{str(meta.get('labels_sha256'))[:16]}... (file modified or corrupted)")
        try:
            file_model = Manipulator.from_dict(meta["geometry"])
        except (KeyError, ValueError) as exc:
            raise MapTensorFileError(f"{path}: invalid geometry record ({exc})") from None
        if file_model.digest() != meta.get("geometry_sha256"):
            raise MapTensorFileError(f"{path}: geometry record does not match its recorded digest")
        if model is not None and model.digest() != file_model.digest():
            raise MapTensorFileError(f"{path}: built for geometry {file_model.name!r} "
                                     f"({file_model.digest()[:12]}), expected {model.name!r} "
                                     f"({model.digest()[:12]})")
        if posture is not None and int(posture) != meta.get("posture"):
            raise MapTensorFileError(f"{path}: built for posture {meta.get('posture')}, expected {posture}")
        if meta.get("rule") not in ORDERING_RULES:
            raise MapTensorFileError(f"{path}: unknown ordering rule {meta.get('rule')!r}")
        if labels.size and (labels.min() < 0 or labels.max() > 6):
            raise MapTensorFileError(f"{path}: labels outside 0..6")
        labels.setflags(write=False)
        return cls(model if model is not None else file_model, int(meta["posture"]),
                   np.asarray(meta["bounds"], dtype=float), tuple(meta["shape"]), meta["rule"], labels,
                   meta.get("stats", {}))


def grid_shape(bounds, step) -> tuple:
    """Node counts for ``bounds`` (3, 2) at spacing ``step`` (m, m, rad): x, y inclusive, phi periodic."""
    span = np.asarray(bounds, float)[:, 1] - np.asarray(bounds, float)[:, 0]
    return (int(round(span[0] / step[0])) + 1, int(round(span[1] / step[1])) + 1, int(round(span[2] / step[2])))


def load_or_build(model: Manipulator, posture: int, rule: str = DEFAULT_RULE, step=DEFAULT_STEP,
                  folder="build/maps", progress: bool = False) -> MapTensor:
    """The map of ``posture`` at node spacing ``step`` from the cache folder, built and saved if missing
    (or if the cached file does not check out).

    Files are named ``map_posture<j>_<rule>_<mm>mm_<deg>deg.npz``.
    """
    name = f"map_posture{int(posture)}_{rule}_{step[0] * 1e3:g}mm_{np.rad2deg(step[2]):g}deg.npz"
    path = Path(folder) / name
    try:
        return MapTensor.load(path, model=model, posture=posture)
    except MapTensorFileError:
        bounds = default_bounds(model, step)
        mt = MapTensor.build(model, posture, bounds=bounds, shape=grid_shape(bounds, step), rule=rule,
                             progress=progress)
        mt.save(path)
        return mt
