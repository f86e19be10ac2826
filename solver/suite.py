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

from .kinematics import dk_all, ik, jacobians, wrap_angle
from .manipulator import Manipulator
from .trajectories import PAPER_CIRCLE, circle_path

__all__ = ["SuitePath", "paper_circle_path", "near_singular_circle", "default_suite", "SAMPLINGS"]

#: Samplings of every path (points per revolution).
SAMPLINGS = (1000, 300, 100, 30)
#: (posture, centre, phi in degrees) seeds of the near-singular circles.
NEAR_SINGULAR_SEEDS = ((1, (0.50, 0.29), 0.0), (3, (0.45, 0.35), 20.0), (5, (0.55, 0.30), -30.0))
#: Clearances from the singular curve, m.
CLEARANCES = (0.02, 0.005, 0.001)


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


def make_path(model: Manipulator, name: str, posture: int, X: np.ndarray) -> SuitePath:
    """Joints and difficulty of a closed sampled path (the last point steps back to the first)."""
    q = ik(model, X, posture)
    if np.any(np.isnan(q)):
        raise ValueError(f"{name}: path leaves the tool space of posture {posture}")
    w = _weights(model)
    sol = dk_all(model, q)
    d = np.where(sol.real, _wdist(sol.poses.real, X[:, None, :], w), np.inf)
    d_sorted = np.sort(d, axis=1)
    gap = d_sorted[:, 1]                                  # [:, 0] is the true pose itself
    step = _wdist(X, np.roll(X, 1, axis=0), w)
    return SuitePath(name, posture, X, q, float(np.max(step / gap)), float(np.min(gap)))


def paper_circle_path(model: Manipulator, n: int) -> SuitePath:
    """The paper's circle sampled at ``n`` points."""
    return make_path(model, f"paper-circle/{n}", PAPER_CIRCLE["posture"], circle_path(n))


def _circle_ok(model, posture, centre, radius, phi, n=4000):
    X = circle_path(n, centre, radius, phi)
    q = ik(model, X, posture)
    if np.any(np.isnan(q)):
        return False, False
    det = np.linalg.det(jacobians(model, X, q)[0])
    return True, bool(np.all(det > 0) or np.all(det < 0))


def near_singular_circle(model: Manipulator, posture: int, centre, phi_deg: float, clearance: float):
    """Radius of the circle about ``centre`` that passes ``clearance`` from the type-1 singularity.

    Returns ``(radius, r_star)``; raises ValueError if the tool-space boundary is
    met before the singular curve (no type-1 singularity to pass close to).
    """
    phi = np.deg2rad(phi_deg)
    reach, same = _circle_ok(model, posture, centre, 1e-3, phi)
    if not (reach and same):
        raise ValueError(f"centre {centre} at phi {phi_deg} deg is not a regular pose of posture {posture}")
    lo, hi = 1e-3, 0.8
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        reach, same = _circle_ok(model, posture, centre, mid, phi)
        if reach and same:
            lo = mid
        else:
            hi = mid
    reach, _ = _circle_ok(model, posture, centre, hi, phi)
    if not reach:
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
