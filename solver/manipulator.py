"""The constant model of a planar 3-RRR parallel manipulator.

A :class:`Manipulator` is frozen geometry, nothing else: the algorithms of
:mod:`solver.kinematics` are plain functions of ``(model, inputs)``.  Lengths
are metres.

Leg ``i`` (0-based in code, 1-based in the text) is ``M_i - D_i - A_i``:

* ``M_i`` motor (fixed revolute joint), ``motors[i]``;
* ``D_i = M_i + l1[i] (cos q_i, sin q_i)`` elbow, ``q_i`` the motor angle from +x;
* ``A_i = P + R(phi) platform[i]`` platform joint, ``P = (x, y)`` the platform
  centre and ``platform[i]`` the joint in the platform frame;
* ``|A_i - D_i| = l2[i]``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import numpy as np

from .checks import GeometryError

__all__ = ["Manipulator", "HOME_POSE", "GeometryIdentity"]

#: Platform joint angles g_i of the paper's manipulator (CONVENTIONS.md), degrees.
PAPER_PLATFORM_ANGLES_DEG = (210.0, 330.0, 90.0)
#: The home pose of the paper's manipulator (x, y, phi; m, m, rad): the centroid of the motor
#: triangle, phi = 0 (the DK FMU's start values).
HOME_POSE = (0.5, float(np.sqrt(3.0) / 6.0), 0.0)


def _frozen(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{name}: expected numbers of shape {shape}, got {value!r}") from exc
    if arr.shape != shape:
        raise GeometryError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f"{name}: expected finite numbers, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def _triangle_area(p: np.ndarray) -> float:
    u, v = p[1] - p[0], p[2] - p[0]
    return 0.5 * float(u[0] * v[1] - u[1] * v[0])


class GeometryIdentity:
    """What the frozen manipulator models share: identity by geometry (``digest``, ``==``, ``hash``,
    all from ``to_dict`` without the name) and the platform joints' distances from the tool point."""

    def digest(self) -> str:
        """SHA-256 of the geometry (name excluded), stable across platforms.

        Two manipulators with the same digest have the same kinematics; map
        tensor files record it so a map is never used with another geometry.
        """
        payload = {k: v for k, v in self.to_dict().items() if k != "name"}
        # repr of a float is exact and round-trips, so the text is canonical.
        text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    def __eq__(self, other):
        if not isinstance(other, type(self)):
            return NotImplemented
        return self.digest() == other.digest()

    def __hash__(self):
        return hash(self.digest())

    @classmethod
    def _from_fields(cls, data: dict, fields: tuple, default_name: str):
        """``cls(**fields of data, name=...)``; GeometryError naming a missing key."""
        try:
            return cls(**{k: data[k] for k in fields}, name=data.get("name", default_name))
        except KeyError as exc:
            raise GeometryError(f"geometry: missing key {exc.args[0]!r} in {sorted(data)}") from exc

    @property
    def platform_radius(self) -> np.ndarray:
        """Distance of each platform joint from the tool point, shape (3,), m."""
        return np.hypot(self.platform[:, 0], self.platform[:, 1])


@dataclass(frozen=True, eq=False)
class Manipulator(GeometryIdentity):
    """Geometry of a planar 3-RRR manipulator (metres).

    Parameters
    ----------
    motors : array_like, shape (3, 2)
        Motor positions ``M_i`` in the base frame, m.
    l1 : array_like, shape (3,) or float
        Proximal link lengths ``|M_i D_i|``, m.
    l2 : array_like, shape (3,) or float
        Distal link lengths ``|D_i A_i|``, m.
    platform : array_like, shape (3, 2)
        Platform joints ``A_i`` in the platform frame (origin at the tool
        point ``P``, orientation ``phi = 0``), m.
    name : str
        A label for messages and file metadata.

    Raises
    ------
    GeometryError
        Non-finite or non-positive lengths, coincident motors, a degenerate
        (collinear) base or platform triangle.

    Examples
    --------
    >>> m = Manipulator.paper()
    >>> m.l1.tolist(), m.l2.tolist()
    ([0.6, 0.6, 0.6], [0.6, 0.6, 0.6])
    """

    motors: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    platform: np.ndarray
    name: str = field(default="3-RRR")

    #: The manipulator interface (:mod:`solver.manipulators`): kind, postures, joint unit.
    kind = "3-RRR"
    n_postures = 8
    joint_unit = "rad"

    def __post_init__(self):
        object.__setattr__(self, "motors", _frozen("motors", self.motors, (3, 2)))
        for key in ("l1", "l2"):
            raw = self.__dict__[key]
            arr = _frozen(key, np.full(3, raw, dtype=object) if np.ndim(raw) == 0 else raw, (3,))
            if np.any(arr <= 0):
                raise GeometryError(f"{key}: expected positive link lengths in m, got {arr.tolist()}")
            object.__setattr__(self, key, arr)
        object.__setattr__(self, "platform", _frozen("platform", self.platform, (3, 2)))
        scale = float(np.max(np.abs(self.motors))) + float(np.max(self.l1 + self.l2))
        if abs(_triangle_area(self.motors)) <= 1e-9 * scale**2:
            raise GeometryError(f"motors: expected three non-collinear points, got {self.motors.tolist()}")
        pscale = float(np.max(np.abs(self.platform)))
        if pscale == 0.0 or abs(_triangle_area(self.platform)) <= 1e-9 * pscale**2:
            raise GeometryError(
                f"platform: expected three non-collinear joint positions, got {self.platform.tolist()}")
        if not isinstance(self.name, str):
            raise GeometryError(f"name: expected a string, got {self.name!r}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def paper(cls) -> "Manipulator":
        """The manipulator of the paper's Table 1 (see ``CONVENTIONS.md``).

        Motors at (0, 0), (1, 0), (1/2, sqrt(3)/2) m; ``l1 = l2 = 0.6`` m; an
        equilateral platform of circumradius ``0.3/sqrt(3)`` m with joints at
        210, 330 and 90 degrees, so that at ``phi = 0`` the platform triangle is
        parallel to the base triangle.
        """
        return cls.symmetric(base_side=1.0, l1=0.6, l2=0.6, platform_side=0.3, name="paper-table-1")

    @classmethod
    def symmetric(cls, base_side: float, l1: float, l2: float, platform_side: float,
                  name: str = "symmetric") -> "Manipulator":
        """An equilateral 3-RRR with the paper's layout, scaled.

        Parameters
        ----------
        base_side : float
            Side of the motor triangle, m (motor 1 at the origin, motor 2 on +x).
        l1, l2 : float
            Proximal and distal link lengths, m.
        platform_side : float
            Side of the platform triangle, m.
        """
        for key, val in (("base_side", base_side), ("platform_side", platform_side)):
            if not (np.isfinite(val) and val > 0):
                raise GeometryError(f"{key}: expected a positive length in m, got {val!r}")
        motors = base_side * np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3.0) / 2.0]])
        radius = platform_side / np.sqrt(3.0)
        g = np.deg2rad(PAPER_PLATFORM_ANGLES_DEG)
        platform = radius * np.stack([np.cos(g), np.sin(g)], axis=1)
        return cls(motors=motors, l1=np.full(3, float(l1)), l2=np.full(3, float(l2)),
                   platform=platform, name=name)

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict:
        """A JSON-ready description (floats as Python floats, lists of lists)."""
        return {"name": self.name, "motors": self.motors.tolist(), "l1": self.l1.tolist(),
                "l2": self.l2.tolist(), "platform": self.platform.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> "Manipulator":
        """Inverse of :meth:`to_dict`."""
        return cls._from_fields(data, ("motors", "l1", "l2", "platform"), "3-RRR")

    @property
    def reach(self) -> np.ndarray:
        """Largest distance ``|M_i A_i|`` per leg, ``l1 + l2``, shape (3,), m."""
        return self.l1 + self.l2

    def circle_legs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every leg as a circle constraint ``|P + R(phi) b_i - D_i(q_i)|^2 = r_i(q_i)^2`` for the
        compiled kernels: the leg bases ``M_i`` (3, 2) m, the arms ``l1`` (3,) m that move ``D_i``
        (``D_i = M_i + l1_i (cos q_i, sin q_i)``) and the squared radii ``l2^2`` (3,) m^2."""
        return np.array(self.motors), np.array(self.l1), self.l2 ** 2

    def reach_discs(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (3, 2) and radii (3,) of the discs each platform joint stays in, m."""
        return np.array(self.motors), self.l1 + self.l2

    def __repr__(self):
        return (f"Manipulator(name={self.name!r}, motors={self.motors.tolist()}, l1={self.l1.tolist()}, "
                f"l2={self.l2.tolist()}, platform={np.round(self.platform, 6).tolist()})")
