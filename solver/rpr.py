"""Kinematics of the planar 3-RPR parallel manipulator, with a cusp-encircling assembly-mode change.

Leg ``i`` (0-based in code) joins the fixed revolute joint ``A_i = base[i]`` to the platform joint
``B_i = P + R(phi) b_i`` (``b_i = platform[i]``, platform frame) through an actuated prismatic
joint of length ``rho_i`` (m, > 0).  Pose ``X = (x, y, phi)`` in m, m, rad, phi wrapped to
(-pi, pi]; constraint ``F_i(X, rho) = |B_i - A_i|^2 - rho_i^2``; ``J = dF/dX``,
``K = dF/drho = diag(-2 rho_i)``; ``det J = 0`` are the DK (parallel, "type-2") singularities;
names as for the 3-RRR in docs/CONVENTIONS.md.  Functions take a batch ``(...)`` first.

The model and its basic kinematics are here; the experiments' :mod:`experiments.rpr_scan` holds an independent reference
direct kinematics (a dense scan in phi, no polynomial) and :mod:`experiments.rpr_cusps` the cusps of the
singular curve in a slice ``rho1 = const`` and the loops around them along which the continuously
followed pose changes assembly mode without meeting ``det J = 0``.  The six DK solutions come from
the same sextic kernel as the 3-RRR's (:func:`solver.dk_all`, :mod:`solver.manipulators`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .angles import wrap_angle as _wrap  # noqa: F401  (the one wrap, under the name experiments.rpr_scan imports)
from .checks import GeometryError, SolverInputError, as_array, check_instance
from .manipulator import GeometryIdentity, _frozen, _triangle_area

__all__ = ["RPRManipulator", "ZEIN_RHO1", "RPR_HOME_POSE", "RPR_WORK_BOUNDS", "ik", "constraints", "jacobians",
           "det_j"]

#: Leg 1 length (m) of the joint-space slice of Zein, Wenger & Chablat (14.98 units / 10, recalled).
ZEIN_RHO1 = 1.498
#: A pose of the cuspidal geometry (m, m, rad): the start of the loop around cusp 1 of that slice
#: (:func:`experiments.rpr_suite.cusp_loop_path`), the start values of the 3-RPR DK FMU.
RPR_HOME_POSE = (-1.4918043755112846, -0.1361018192581785, 0.07873145427675467)
#: The region of the tool space (x, y in m; phi) where the suite and the cusp loops of that slice run:
#: what the 3-RPR's map tensors cover (its joint limits allow far more).
RPR_WORK_BOUNDS = ((-2.0, 2.5), (-1.5, 2.5), (-np.pi, np.pi))
_E = np.array([[0.0, -1.0], [1.0, 0.0]])            # rotation by +90 deg


@dataclass(frozen=True, eq=False)
class RPRManipulator(GeometryIdentity):
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
        the radii are the joints themselves, which the squared radii mark by -1 (prismatic legs)."""
        return np.array(self.base), np.zeros(3), np.full(3, -1.0)

    def reach_discs(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (3, 2) and radii (3,) of the discs each platform joint stays in, m."""
        return np.array(self.base), np.full(3, self.rho_max)

    def to_dict(self) -> dict:
        """A JSON-ready description (floats as Python floats, lists of lists)."""
        return {"name": self.name, "base": self.base.tolist(), "platform": self.platform.tolist(),
                "rho_min": self.rho_min, "rho_max": self.rho_max}

    @classmethod
    def from_dict(cls, data: dict) -> "RPRManipulator":
        """Inverse of :meth:`to_dict`."""
        return cls._from_fields(data, ("base", "platform", "rho_min", "rho_max"), "3-RPR")


# ----------------------------------------------------------------------------- checks and helpers
def _check_model(model) -> RPRManipulator:
    return check_instance("model", model, RPRManipulator, "an RPRManipulator")


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
