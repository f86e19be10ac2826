"""The trajectory benchmark of the tracker: deterministic tool-space paths, their
joint streams, and how hard each one is.

Paths
-----
* The paper's circle (Fig. 16, :data:`solver.trajectories.PAPER_CIRCLE`).
* Circles that pass close to a type-1 singularity without crossing it, in
  several postures.  For a centre and an orientation the largest radius ``R*``
  at which the circle still has one sign of det J all round (and stays in the
  tool space) is found by bisection; the circle of radius ``R* - clearance``
  then passes about ``clearance`` from the singular curve.  Near it two real
  DK solutions come close: that is where Newton from the previous pose jumps
  branch.
Every path is sampled from fine (1000 points) to coarse (30 points).

The *hard suite* (:func:`hard_suite`) extends it to all eight postures:
circles, ellipses and Lissajous figures (the platform turning) passing 0.5, 2,
5 and 20 mm from a type-1 singularity, and a path far from it, each sampled
at 30, 50, 100 and 200 points: 120 paths, 480 streams.

Difficulty
----------
For a sampled path ``X_k`` the *ambiguity ratio* is
``max_k |X_k - X_{k-1}| / gap_k`` with ``gap_k`` the distance from ``X_k`` to
the nearest other real DK solution of ``q_k`` (eq. 19 distance, weights
(1, 1, rho^2)).  Below 0.5 the path is *resolvable*: the true pose is nearer
to the previous one than any other solution is, continuity alone decides.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.direct_kinematics import dk_all
from solver.kinematics import ik, jacobians, wrap_angle
from solver.manipulator import Manipulator
from solver.trajectories import PAPER_CIRCLE, circle_path

__all__ = ["SuitePath", "paper_circle_path", "near_singular_circle", "default_suite", "SAMPLINGS", "shape_path",
           "hard_suite", "HARD_SAMPLINGS"]

#: Samplings of every path (points per revolution).
SAMPLINGS = (1000, 300, 100, 30)
#: (posture, centre, phi in degrees) seeds of the near-singular circles.
NEAR_SINGULAR_SEEDS = ((1, (0.50, 0.29), 0.0), (3, (0.45, 0.35), 20.0), (5, (0.55, 0.30), -30.0))
#: Clearances from the singular curve, m.
CLEARANCES = (0.02, 0.005, 0.001)
#: The hard suite: shapes, clearances from the singular set (m; plus a path far from it), samplings.
SHAPES = ("circle", "ellipse", "lissajous")
HARD_CLEARANCES = (0.0005, 0.002, 0.005, 0.02)
HARD_SAMPLINGS = (30, 50, 100, 200)


@dataclass(frozen=True)
class SuitePath:
    """One sampled path of the suite.

    Attributes
    ----------
    name : str
    posture : int
    X : ndarray (n, 3)
        True poses, m, m, rad.
    q : ndarray (n, 3)
        Joints, rad (``ik(X, posture)``).
    ratio : float
        Ambiguity ratio (largest step / gap to the nearest other real solution).
    min_gap : float
        Smallest gap along the path, m (eq. 19 distance).
    """

    name: str
    posture: int
    X: np.ndarray
    q: np.ndarray
    ratio: float
    min_gap: float

    @property
    def resolvable(self) -> bool:
        """Continuity alone determines the answer (ratio < 0.5)."""
        return self.ratio < 0.5


def _weights(model):
    return np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])


def _wdist(a, b, w):
    d = a - b
    d[..., 2] = wrap_angle(d[..., 2])
    return np.sqrt(np.sum(w * d * d, axis=-1))


def make_path(model: Manipulator, name: str, posture: int, X: np.ndarray, q=None, closed: bool = True) -> SuitePath:
    """Joints and difficulty of a sampled path: ``closed`` (the last point steps back to the first)
    or open; ``q`` (n, 3) its joints when already known (default ``ik(model, X, posture)``)."""
    q = ik(model, X, posture) if q is None else q
    if np.any(np.isnan(q)):
        raise ValueError(f"{name}: path leaves the tool space of posture {posture}")
    w = _weights(model)
    sol = dk_all(model, q)
    d = np.where(sol.real, _wdist(sol.poses.real, X[:, None, :], w), np.inf)
    d_sorted = np.sort(d, axis=1)
    gap = d_sorted[:, 1]                                  # [:, 0] is the true pose itself
    step = _wdist(X, np.roll(X, 1, axis=0), w)
    if not closed:
        step[0] = 0.0                                     # no step into the first point
    return SuitePath(name, posture, X, q, float(np.max(step / gap)), float(np.min(gap)))


def paper_circle_path(model: Manipulator, n: int) -> SuitePath:
    """The paper's circle sampled at ``n`` points."""
    return make_path(model, f"paper-circle/{n}", PAPER_CIRCLE["posture"], circle_path(n))


def _regularity(model, posture, X):
    """(reachable, one sign of det J all along, index of the first sign change or -1) of poses X."""
    q = ik(model, X, posture)
    if np.any(np.isnan(q)):
        return False, False, -1
    det = np.linalg.det(jacobians(model, X, q)[0])
    flip = np.nonzero(np.sign(det) != np.sign(det[0]))[0]
    return True, bool(np.all(det > 0) or np.all(det < 0)), int(flip[0]) if flip.size else -1


def _critical_scale(model, posture, path_at, lo, hi, iters):
    """Bisection on the scale of a family of closed paths ``path_at(scale)``: the largest scale at
    which the path is reachable with one sign of det J all along.  Returns ``(lo, hi)``."""
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        reach, same, _ = _regularity(model, posture, path_at(mid))
        if reach and same:
            lo = mid
        else:
            hi = mid
    return lo, hi


def near_singular_circle(model: Manipulator, posture: int, centre, phi_deg: float, clearance: float):
    """Radius of the circle about ``centre`` that passes ``clearance`` from the type-1 singularity.

    Returns ``(radius, r_star)``; raises ValueError if the tool-space boundary is
    met before the singular curve (no type-1 singularity to pass close to).
    """
    phi = np.deg2rad(phi_deg)
    path_at = lambda radius: circle_path(4000, centre, radius, phi)          # noqa: E731
    reach, same, _ = _regularity(model, posture, path_at(1e-3))
    if not (reach and same):
        raise ValueError(f"centre {centre} at phi {phi_deg} deg is not a regular pose of posture {posture}")
    lo, hi = _critical_scale(model, posture, path_at, 1e-3, 0.8, 40)
    if not _regularity(model, posture, path_at(hi))[0]:
        raise ValueError(f"posture {posture}, centre {centre}: the tool-space boundary comes first")
    return lo - clearance, lo


def default_suite(model: Manipulator | None = None, samplings=SAMPLINGS) -> list[SuitePath]:
    """The deterministic suite: the paper circle and the near-singular circles, at every sampling."""
    model = Manipulator.paper() if model is None else model
    paths = [paper_circle_path(model, n) for n in samplings]
    for posture, centre, phd in NEAR_SINGULAR_SEEDS:
        for clearance in CLEARANCES:
            radius, _ = near_singular_circle(model, posture, centre, phd, clearance)
            for n in samplings:
                X = circle_path(n, centre, radius, np.deg2rad(phd))
                paths.append(make_path(model, f"p{posture}-near-sing-{clearance * 1e3:g}mm/{n}", posture, X))
    return paths


# ----------------------------------------------------------------------------- the hard suite
def shape_path(shape: str, centre, phi0: float, tilt: float, scale: float, n: int) -> np.ndarray:
    """``n`` poses (n, 3) of a closed path: ``shape`` about ``centre`` (m), scaled by ``scale`` (m),
    its axes turned by ``tilt`` (rad), orientation ``phi0`` (rad) plus the shape's own turning.

    Shapes: ``circle``; ``ellipse`` (axes 1 and 0.55); ``lissajous`` (a figure of eight,
    ``(sin t, 0.6 sin 2t)``, the platform turning +-8 degrees with ``sin t``).
    """
    t = 2.0 * np.pi * np.arange(n) / n
    if shape == "circle":
        u, dphi = np.column_stack([np.cos(t), np.sin(t)]), np.zeros(n)
    elif shape == "ellipse":
        u, dphi = np.column_stack([np.cos(t), 0.55 * np.sin(t)]), np.zeros(n)
    elif shape == "lissajous":
        u, dphi = np.column_stack([np.sin(t), 0.6 * np.sin(2.0 * t)]), np.deg2rad(8.0) * np.sin(t)
    else:
        raise ValueError(f"shape: expected one of {SHAPES}, got {shape!r}")
    c, s = np.cos(tilt), np.sin(tilt)
    return np.column_stack([centre[0] + scale * (c * u[:, 0] - s * u[:, 1]),
                            centre[1] + scale * (s * u[:, 0] + c * u[:, 1]), phi0 + dphi])


def _hard_seed(model, posture, shape, centre, phi0, tilt):
    """(critical scale, |offset| of the contact point) of one seed, or None if it does not pass
    close to a type-1 singularity before leaving the tool space (or is too small)."""
    path_at = lambda scale: shape_path(shape, centre, phi0, tilt, scale, 2000)   # noqa: E731
    reach, same, _ = _regularity(model, posture, path_at(1e-3))
    if not (reach and same):
        return None
    lo, hi = _critical_scale(model, posture, path_at, 1e-3, 0.6, 36)
    reach, same, k = _regularity(model, posture, path_at(hi))
    if not reach or same or lo < 0.03:
        return None
    contact = shape_path(shape, (0.0, 0.0), 0.0, tilt, 1.0, 2000)[k]
    return lo, float(np.hypot(contact[0], contact[1]))


def hard_suite(model: Manipulator | None = None, samplings=HARD_SAMPLINGS, seed: int = 2026) -> list[SuitePath]:
    """All eight postures, three shapes each, passing 0.5 to 20 mm from a type-1 singularity or far from it.

    Per posture, seeds (centre, orientation, tilt) are drawn from a fixed random
    stream until each shape has one whose family of scaled paths meets a type-1
    singularity before the tool-space boundary; the critical scale ``s*`` is found
    by bisection and the path of scale ``s* - clearance / |u|`` (``|u|`` the shape's
    offset at the contact point) passes about ``clearance`` from the singular set;
    ``far`` is the path of scale ``s* / 2``.  Deterministic: 8 x 3 x 5 paths, each
    at every sampling in ``samplings``.
    """
    model = Manipulator.paper() if model is None else model
    from solver.grid import default_bounds
    bounds = default_bounds(model, (0.01, 0.01, 0.01))
    rng = np.random.default_rng(seed)
    paths = []
    for posture in range(1, 9):
        for shape in SHAPES:
            for _ in range(4000):
                centre = (rng.uniform(*bounds[0]), rng.uniform(*bounds[1]))
                phi0, tilt = rng.uniform(-np.pi / 3, np.pi / 3), rng.uniform(0.0, np.pi)
                found = _hard_seed(model, posture, shape, centre, phi0, tilt)
                if found is not None:
                    break
            else:                                                     # pragma: no cover - geometry dependent
                raise ValueError(f"posture {posture}: no {shape} passing near a type-1 singularity found")
            s_star, umag = found
            for clearance in HARD_CLEARANCES + (None,):
                scale = 0.5 * s_star if clearance is None else s_star - clearance / umag
                tag = "far" if clearance is None else f"{clearance * 1e3:g}mm"
                for n in samplings:
                    X = shape_path(shape, centre, phi0, tilt, scale, n)
                    paths.append(make_path(model, f"p{posture}-{shape}-{tag}/{n}", posture, X))
    return paths
