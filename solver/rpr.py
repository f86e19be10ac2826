"""Kinematics of the planar 3-RPR parallel manipulator, with a cusp-encircling assembly-mode change.

Leg ``i`` (0-based in code) joins the fixed revolute joint ``A_i = base[i]`` to the platform joint
``B_i = P + R(phi) b_i`` (``b_i = platform[i]``, platform frame) through an actuated prismatic
joint of length ``rho_i`` (m, > 0).  Pose ``X = (x, y, phi)`` in m, m, rad, phi wrapped to
(-pi, pi]; constraint ``F_i(X, rho) = |B_i - A_i|^2 - rho_i^2``; ``J = dF/dX``,
``K = dF/drho = diag(-2 rho_i)``; ``det J = 0`` are the DK (parallel, "type-2") singularities;
names as for the 3-RRR in docs/CONVENTIONS.md.  Functions take a batch ``(...)`` first.

:func:`dk_all_scan` is an independent reference direct kinematics (a dense scan in phi, no
polynomial); :func:`cusp_points` finds the cusps of the singular curve in a slice ``rho1 = const``;
:func:`assembly_mode_change_path` builds a loop around a cusp along which the continuously
followed pose changes assembly mode without meeting ``det J = 0``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .checks import GeometryError, SolverInputError, as_array
from .manipulator import _frozen, _triangle_area

__all__ = ["RPRManipulator", "ZEIN_RHO1", "ik", "constraints", "jacobians", "det_j", "dk_all_scan",
           "follow", "cusp_points", "assembly_mode_change_path", "CuspPoints", "ModeChange"]

#: Leg 1 length (m) of the joint-space slice of Zein, Wenger & Chablat (14.98 units / 10, recalled).
ZEIN_RHO1 = 1.498
_E = np.array([[0.0, -1.0], [1.0, 0.0]])            # rotation by +90 deg


@dataclass(frozen=True, eq=False)
class RPRManipulator:
    """Geometry of a planar 3-RPR manipulator (metres).

    Parameters
    ----------
    base, platform : array_like, shape (3, 2)
        Fixed joints ``A_i`` and platform joints ``b_i`` (platform frame, origin ``P``), m.
    rho_min, rho_max : float
        Joint limits, m, ``0 < rho_min < rho_max`` (recorded, not applied by the functions).
    name : str
        A label for messages and file metadata.

    Raises
    ------
    GeometryError
        Non-finite numbers, a collinear base or platform, bad joint limits (the argument named).
    """

    base: np.ndarray
    platform: np.ndarray
    rho_min: float = 0.1
    rho_max: float = 5.0
    name: str = field(default="3-RPR")

    #: The manipulator interface (:mod:`solver.manipulators`): kind, postures, joint unit.
    kind = "3-RPR"
    n_postures = 1
    joint_unit = "m"

    def __post_init__(self):
        for key in ("base", "platform"):
            arr = _frozen(key, self.__dict__[key], (3, 2))
            scale = float(np.max(np.abs(arr)))
            if scale == 0.0 or abs(_triangle_area(arr)) <= 1e-9 * scale ** 2:
                raise GeometryError(f"{key}: expected three non-collinear points, got {arr.tolist()}")
            object.__setattr__(self, key, arr)
        for key in ("rho_min", "rho_max"):
            val = _frozen(key, self.__dict__[key], ())
            if not val > 0:
                raise GeometryError(f"{key}: expected a positive length in m, got {float(val)!r}")
            object.__setattr__(self, key, float(val))
        if not self.rho_min < self.rho_max:
            raise GeometryError(f"rho_max: expected more than rho_min = {self.rho_min}, got {self.rho_max}")
        if not isinstance(self.name, str):
            raise GeometryError(f"name: expected a string, got {self.name!r}")

    @classmethod
    def zein_wenger_chablat(cls) -> "RPRManipulator":
        """The cuspidal 3-RPR of Zein, Wenger and Chablat, its numbers divided by 10 (read as dm -> m).

        M. Zein, P. Wenger, D. Chablat, "Non-singular assembly-mode changing motions for 3-RPR
        parallel manipulators", Mechanism and Machine Theory 43(4), 2008, after C. Innocenti,
        V. Parenti-Castelli, "Singularity-free evolution from one configuration to another in
        serial and fully-parallel manipulators", ASME J. Mechanical Design 120(1), 1998.
        ``A1 = (0, 0)``, ``A2 = (15.91, 0)``, ``A3 = (0, 10)``; sides ``B1B2 = 17.04``,
        ``B2B3 = 16.54``, ``B3B1 = 20.84``; slice ``rho1 = 14.98`` (:data:`ZEIN_RHO1`).  These
        numbers (and the journal volume) were recalled, NOT confirmed against the paper's text: a
        search found its title and authors only.  ``P = B1``, ``B2`` on the platform +x axis, ``B3``
        on its +y side and the limits 0.05..4 m are this module's choice; the tests check that the
        geometry has cusps in that slice and a non-singular assembly-mode change around them.
        """
        s12, s23, s31 = 1.704, 1.654, 2.084
        c = (s12 ** 2 + s31 ** 2 - s23 ** 2) / (2.0 * s12 * s31)
        platform = [[0.0, 0.0], [s12, 0.0], [s31 * c, s31 * np.sqrt(1.0 - c * c)]]
        return cls(base=[[0.0, 0.0], [1.591, 0.0], [0.0, 1.0]], platform=platform, rho_min=0.05,
                   rho_max=4.0, name="zein-wenger-chablat-2008")

    def circle_legs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every leg as a circle constraint for the compiled kernels (see
        :meth:`solver.Manipulator.circle_legs`): centres ``A_i`` (3, 2) m, no arm (``l1 = 0``);
        the radii are the joints themselves, so the squared radii returned are placeholders (1)."""
        return np.array(self.base), np.zeros(3), np.ones(3)

    def reach_discs(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (3, 2) and radii (3,) of the discs each platform joint stays in, m."""
        return np.array(self.base), np.full(3, self.rho_max)

    @property
    def platform_radius(self) -> np.ndarray:
        """Distance of each platform joint from the tool point, shape (3,), m."""
        return np.hypot(self.platform[:, 0], self.platform[:, 1])

    def to_dict(self) -> dict:
        """A JSON-ready description (floats as Python floats, lists of lists)."""
        return {"name": self.name, "base": self.base.tolist(), "platform": self.platform.tolist(),
                "rho_min": self.rho_min, "rho_max": self.rho_max}

    @classmethod
    def from_dict(cls, data: dict) -> "RPRManipulator":
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(base=data["base"], platform=data["platform"], rho_min=data["rho_min"],
                       rho_max=data["rho_max"], name=data.get("name", "3-RPR"))
        except KeyError as exc:
            raise GeometryError(f"geometry: missing key {exc.args[0]!r} in {sorted(data)}") from exc

    def digest(self) -> str:
        """SHA-256 of the geometry (name excluded), stable across platforms."""
        payload = {k: v for k, v in self.to_dict().items() if k != "name"}
        return hashlib.sha256(json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()).hexdigest()

    def __eq__(self, other):
        return self.digest() == other.digest() if isinstance(other, RPRManipulator) else NotImplemented

    def __hash__(self):
        return hash(self.digest())


# ----------------------------------------------------------------------------- checks and helpers
def _check_model(model) -> RPRManipulator:
    if not isinstance(model, RPRManipulator):
        raise SolverInputError(f"model: expected an RPRManipulator, got {type(model).__name__}")
    return model


def _rho(name, rho) -> np.ndarray:
    rho = as_array(name, rho)
    if np.any(rho <= 0):
        raise SolverInputError(f"{name}: expected positive leg lengths in m, got {rho.ravel()[:6].tolist()}")
    return rho


def _positive(name, value, kind=float):
    arr = as_array(name, value, ())
    if arr.ndim or not arr > 0 or (kind is int and arr != int(arr)):
        raise SolverInputError(f"{name}: expected one positive {kind.__name__}, got {value!r}")
    return kind(arr)


def _rot(phi, b):
    """R(phi) b for angles (...) and vectors b (..., 2), broadcast."""
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([c * b[..., 0] - s * b[..., 1], s * b[..., 0] + c * b[..., 1]], -1)


def _wrap(a):
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _joints(model, X):
    """``B_i`` and ``R b_i``, each (..., 3, 2), for poses (..., 3)."""
    Rb = _rot(X[..., None, 2], model.platform)
    return X[..., None, :2] + Rb, Rb


def _residual(model, X, rho):
    return np.sum((_joints(model, X)[0] - model.base) ** 2, axis=-1) - rho ** 2


def _jac(model, X):
    B, Rb = _joints(model, X)
    v = B - model.base
    return 2.0 * np.concatenate([v, (Rb[..., 0] * v[..., 1] - Rb[..., 1] * v[..., 0])[..., None]], axis=-1)


# ----------------------------------------------------------------------------- basic kinematics
def ik(model: RPRManipulator, X) -> np.ndarray:
    """Inverse kinematics ``rho_i = |B_i - A_i|`` (m, shape (..., 3)) of poses ``X`` (..., 3) in m, m, rad."""
    _check_model(model)
    return np.linalg.norm(_joints(model, as_array("X", X))[0] - model.base, axis=-1)


def constraints(model: RPRManipulator, X, rho) -> np.ndarray:
    """``F_i(X, rho) = |B_i - A_i|^2 - rho_i^2`` (..., 3), m^2, for ``X``, ``rho`` (..., 3) broadcast."""
    _check_model(model)
    return _residual(model, as_array("X", X), _rho("rho", rho))


def jacobians(model: RPRManipulator, X, rho):
    """``J = dF/dX`` and ``K = dF/drho`` at poses ``X`` (..., 3) m, m, rad and legs ``rho`` (..., 3) m.

    Returns
    -------
    J : ndarray, shape (..., 3, 3)
        Row ``i`` is ``2 (B_i - A_i, (R b_i) x (B_i - A_i))``; columns in m, m, m^2/rad.
    K : ndarray, shape (..., 3, 3)
        ``diag(-2 rho_i)``, m.
    """
    _check_model(model)
    X, rho = as_array("X", X), _rho("rho", rho)
    K = np.zeros(rho.shape + (3,))
    K[..., [0, 1, 2], [0, 1, 2]] = -2.0 * rho
    return _jac(model, X), K


def det_j(model: RPRManipulator, X) -> np.ndarray:
    """``det J`` at poses (..., 3), shape (...), m^4/rad; zero at the DK singularities."""
    _check_model(model)
    return np.linalg.det(_jac(model, as_array("X", X)))


# ----------------------------------------------------------------------------- reference DK by a scan
def _leg12(model, r1, r2, phi):
    """Legs 1-2 closed: ``P = m + s sqrt(h2) n`` (``s = +-1``), real where ``h2 >= 0``."""
    c1 = model.base[0] - _rot(phi, model.platform[0])
    dv = model.base[1] - _rot(phi, model.platform[1]) - c1
    d2 = np.sum(dv * dv, axis=-1)
    a = 0.5 * (r1 ** 2 - r2 ** 2 + d2) / d2
    return c1 + a[..., None] * dv, dv @ _E.T, r1 ** 2 / d2 - a ** 2


def _branch(model, r, s, phi):
    """Pose ``P`` on branch ``s`` of legs 1-2, leg 3's residual (NaN off the branch) and ``h2``."""
    m, n, h2 = _leg12(model, r[..., 0], r[..., 1], phi)
    P = m + (s * np.sqrt(np.where(h2 >= 0, h2, np.nan)))[..., None] * n
    return P, np.sum((P + _rot(phi, model.platform[2]) - model.base[2]) ** 2, axis=-1) - r[..., 2] ** 2, h2


def _bisect(fun, a, b, iters=60, keep_a=False):
    """Vectorised bisection of ``fun > 0`` changing on [a, b] (either order); ``keep_a``: a's side."""
    fa = fun(a) > 0
    for _ in range(iters):
        c = 0.5 * (a + b)
        right = (fun(c) > 0) == fa
        a, b = np.where(right, c, a), np.where(right, b, c)
    return a if keep_a else 0.5 * (a + b)


def dk_all_scan(model: RPRManipulator, rho, n_phi: int = 3600, tol: float = 1e-9):
    """All real direct-kinematics solutions by a dense scan in phi (reference, no polynomial).

    For each phi of a uniform grid, legs 1 and 2 put ``P`` on two circles (branches ``s = +-1``
    where they meet) and leg 3's residual ``f`` is sampled along each branch.  A sign change of
    ``f`` in a cell gives a root (bisection in phi) and, deflated by it, a golden-section search for
    two more; a cell next to a local minimum of ``|f|`` is searched for a close pair the same way;
    cells where the branches join (the circles tangent) are rescanned on a sub-grid uniform in
    the circles' half-chord and halving towards the junction.  Roots are polished by Newton steps
    on the full system and deduplicated (1e-7 rad, 1e-7 of the geometry's size).  Measured on
    this module's geometry: all solutions of 20000 random poses; both solutions of a pair 1e-5 m
    from a fold (det J = 0); near cusps, pairs closer than ~1e-5 m may come back ~1e-7 m off or,
    at ~1e-6 m, unresolved (float64 residuals can no longer tell them apart).

    Parameters
    ----------
    model : RPRManipulator
    rho : array_like, shape (..., 3)
        Leg lengths, m.
    n_phi : int
        Number of phi samples over a turn (default 3600: 0.1 deg).
    tol : float
        Largest accepted ``max_i |F_i|``, m^2.

    Returns
    -------
    poses : ndarray, shape (..., 6, 3)
        The real solutions sorted by phi, NaN-padded; m, m, rad.
    count : ndarray of int, shape (...)
        Number of real solutions (0..6).
    """
    _check_model(model)
    rho, n_phi = _rho("rho", rho), _positive("n_phi", n_phi, int)
    lead, r = rho.shape[:-1], rho.reshape(-1, 3)
    step = 2.0 * np.pi / n_phi
    phi = -np.pi + step * np.arange(-1, n_phi + 1)                       # one cell more at each end
    cands = []                                                            # (item, branch, phi) arrays

    def add(i, s, ph):
        cands.append((i, np.broadcast_to(s, i.shape), ph))

    def g(i, s, x, rt=None):                                             # leg 3's residual, / (x - rt)
        f = _branch(model, r[i], s, x)[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            return f if rt is None else f / (x - rt)

    def pair(i, s, a, b, rt=None):                                        # a close pair hidden in [a, b]?
        sg, lo, hi = np.sign(g(i, s, a, rt)), a, b
        for _ in range(60):                                               # golden section: min of sg * g
            c, d = hi - 0.618034 * (hi - lo), lo + 0.618034 * (hi - lo)
            left = ~(sg * g(i, s, c, rt) > sg * g(i, s, d, rt))
            lo, hi = np.where(left, lo, c), np.where(left, d, hi)
        mid = 0.5 * (lo + hi)
        two = sg * g(i, s, mid, rt) <= 0                                  # two roots, or a double root:
        inner = np.minimum(np.abs(mid - a), np.abs(mid - b)) > 1e-3 * np.abs(b - a)
        tiny = ~two & inner & (rt is None) & (np.abs(g(i, s, mid)) <= 1e-12)   # a tangency (1e-12 m^2)
        r2 = None if rt is None else rt[two]
        for u, v in ((a, mid), (mid, b)):
            add(i[two], s, _bisect(lambda x: g(i[two], s, x, r2), u[two], v[two]))
        add(i[tiny], s, mid[tiny])

    def scan(i, s, x, f):                                                 # samples f at x (rows: items i)
        ok, a, b = np.isfinite(f), x[:, :-1], x[:, 1:]
        both, change = ok[:, :-1] & ok[:, 1:], (f[:, :-1] > 0) != (f[:, 1:] > 0)
        e, j = np.nonzero(both & change)                                  # a sign change: a root, and
        ph = _bisect(lambda y: g(i[e], s, y), a[e, j], b[e, j])           # maybe two more in the cell
        add(i[e], s, ph)
        pair(i[e], s, a[e, j], b[e, j], ph)
        af = np.pad(np.where(ok, np.abs(f), np.inf), ((0, 0), (1, 1)), constant_values=np.inf)
        low = ok & (af[:, 1:-1] < af[:, :-2]) & (af[:, 1:-1] <= af[:, 2:])  # |f| at a local minimum:
        e, j = np.nonzero(both & ~change & (low[:, :-1] | low[:, 1:]))   # a pair in either cell?
        pair(i[e], s, a[e, j], b[e, j])

    items = np.arange(len(r))
    for s in (1.0, -1.0):
        _, f, h2 = _branch(model, r[:, None, :], s, phi)                # (items, n_phi + 2), NaN off branch
        scan(items, s, np.broadcast_to(phi, f.shape), f)
    ok = h2 >= 0                                                          # the branches join in a cell:
    i, k = np.nonzero(ok[:, :-1] != ok[:, 1:])                            # find where, then scan both
    start = np.where(ok[i, k], phi[k], phi[k + 1])                        # branches on a sub-grid
    edge = _bisect(lambda x: _leg12(model, r[i, 0], r[i, 1], x)[2] >= 0, start,
                   np.where(ok[i, k], phi[k + 1], phi[k]), keep_a=True)
    tau = np.r_[np.linspace(1.0, 0.0, 33)[:-1] ** 2, 2.0 ** -np.arange(11, 53), 0.0]   # uniform in sqrt(h2),
    sub = edge[:, None] + (start - edge)[:, None] * tau                   # then halving towards the junction
    fe = [_branch(model, r[i][:, None, :], t, sub)[1] for t in (1.0, -1.0)]
    for t, fs in zip((1.0, -1.0), fe):
        scan(i, t, sub, fs)
    jn = (fe[0][:, -1] > 0) != (fe[1][:, -1] > 0)
    add(i[jn], 1.0, edge[jn])                                             # a root at the junction itself
    ci, cs, cp = (np.concatenate(c) for c in zip(*cands))
    X = _polish(model, np.column_stack([_branch(model, r[ci], cs, cp)[0], cp]), r[ci])
    res = np.max(np.abs(_residual(model, X, r[ci])), axis=-1)
    ci, X = ci[res <= tol], X[res <= tol]                                  # NaN residuals drop out too
    X[:, 2] = _wrap(X[:, 2])
    poses, count = np.full((len(r), 6, 3), np.nan), np.zeros(len(r), dtype=int)
    scale = float(np.max(np.abs(model.base)) + np.max(np.abs(model.platform)))
    for item in np.unique(ci):                                            # deduplicate per item
        out = []
        for x in sorted(X[ci == item], key=lambda x: x[2]):
            if all(max(np.max(np.abs(x[:2] - y[:2])) / scale, abs(_wrap(x[2] - y[2]))) > 1e-7 for y in out):
                out.append(x)
        count[item] = min(len(out), 6)
        poses[item, :count[item]] = np.array(out[:6])
    return poses.reshape(lead + (6, 3)), count.reshape(lead)


def _polish(model, X, rho, steps=2):
    """Newton steps on the full system, each kept only where it lowers the residual."""
    for _ in range(steps):
        F = _residual(model, X, rho)
        with np.errstate(all="ignore"):
            Y = X + np.linalg.solve(_jac(model, X), -F[..., None])[..., 0]
            better = np.max(np.abs(_residual(model, Y, rho)), -1) < np.max(np.abs(F), -1)
        X = np.where(better[..., None], Y, X)
    return X


def follow(model: RPRManipulator, rho_path, X0, iters: int = 20):
    """Follow one DK solution along joint values, Newton's method from the previous pose.

    Parameters
    ----------
    model : RPRManipulator
    rho_path : array_like, shape (N, 3)
        Leg lengths along the path, m; ``X0`` (3,) m, m, rad solves ``rho_path[0]``.
    iters : int
        Newton iterations per point at most (stops at a step below 1e-12).

    Returns
    -------
    poses : ndarray, shape (N, 3)
        The followed poses (phi continuous, not wrapped), m, m, rad; NaN after a singular J.
    converged : ndarray of bool, shape (N,)
        ``max_i |F_i| < 1e-9`` m^2 at each point.
    """
    _check_model(model)
    rho_path, X = _rho("rho_path", rho_path), as_array("X0", X0, (3,)).copy()
    poses, conv = np.full((len(rho_path), 3), np.nan), np.zeros(len(rho_path), dtype=bool)
    for n, rho in enumerate(rho_path):
        try:
            for _ in range(iters):
                dX = np.linalg.solve(_jac(model, X), -_residual(model, X, rho))
                X = X + dX
                if np.max(np.abs(dX)) < 1e-12:
                    break
        except np.linalg.LinAlgError:
            break
        poses[n], conv[n] = X, np.max(np.abs(_residual(model, X, rho))) < 1e-9
    return poses, conv


# ----------------------------------------------------------------------------- cusps and the mode change
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

    def change(v):
        c = np.stack([v, np.roll(v, -1, 0), np.roll(v, -1, 1), np.roll(v, (-1, -1), (0, 1))]) > 0
        return c.any(0) & ~c.all(0)

    found = []
    for i, j in np.argwhere(change(g1) & change(ga) & change(gb)):
        z = np.array([g[i], g[j]]) + np.pi / n_grid
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
        if (np.max(np.abs(dz)) < 1e-9 and np.linalg.norm(D) > 1e-6
                and all(np.max(np.abs(_wrap(z - y))) > 1e-6 for y, _ in found)):
            found.append((z, X))
    poses = np.array([X for _, X in found]).reshape(-1, 3)
    joints = ik(model, poses)
    tangent = np.zeros((len(found), 2))
    for c, ((t, phi), _) in enumerate(found):                            # D has rank 1: its image is
        D = _slice(model, rho1, t, phi)[1]                                  # the cusp's tangent line
        tangent[c] = D[:, np.argmax(np.linalg.norm(D, axis=0))] / (2.0 * joints[c, 1:])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    ends = joints[:, None, :] + 1e-4 * np.concatenate([np.zeros((len(found), 2, 1)),
                                                       np.stack([tangent, -tangent], 1)], -1)
    k = dk_all_scan(model, np.maximum(ends, 1e-9))[1]
    tangent[k[:, 1] > k[:, 0]] *= -1.0
    order = np.argsort(joints[:, 1])
    return CuspPoints(joints[order], poses[order], tangent[order])


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
