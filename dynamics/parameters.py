"""The dynamic parameters of a 3-RRR: inertial, friction and gravity data, and their defaults.

:class:`DynamicParameters` is one frozen dataclass, constant like the geometry
(:class:`solver.Manipulator`); every algorithm of :mod:`dynamics` is a plain function of
``(params, model, state...)``.  The default numbers are derived below from stated assumptions
(all SI).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

import numpy as np

from solver.identity_cache import by_identity

__all__ = ["DynamicParameters", "ParameterError", "row_constants"]


class ParameterError(ValueError):
    """A dynamic parameter is invalid (wrong shape, non-finite, negative mass...)."""


# Where the default numbers come from (all SI):
#: Density of aluminium alloy 6061, kg/m^3.
ALUMINIUM_DENSITY = 2700.0
#: Links: round aluminium tube, 25 mm outer diameter, 2 mm wall, 0.6 m long (Table 1).
TUBE_OUTER, TUBE_WALL, LINK_LENGTH = 0.025, 0.002, 0.6
_TUBE_AREA = math.pi / 4.0 * (TUBE_OUTER ** 2 - (TUBE_OUTER - 2 * TUBE_WALL) ** 2)   # 1.445e-4 m^2
_LINK_MASS = ALUMINIUM_DENSITY * _TUBE_AREA * LINK_LENGTH                             # 0.2341 kg
_LINK_INERTIA = _LINK_MASS * LINK_LENGTH ** 2 / 12.0                                  # 7.023e-3 kg m^2
#: Platform: aluminium plate, equilateral triangle of side 0.3 m (Table 1), 6 mm thick.
PLATE_SIDE, PLATE_THICKNESS = 0.3, 0.006
_PLATE_MASS = ALUMINIUM_DENSITY * math.sqrt(3.0) / 4.0 * PLATE_SIDE ** 2 * PLATE_THICKNESS   # 0.6313 kg
_PLATE_INERTIA = _PLATE_MASS * PLATE_SIDE ** 2 / 12.0                                 # 4.735e-3 kg m^2
#: Motor: 200 W class AC servo, rotor inertia 0.2 kg cm^2 (typical datasheet value of that
#: class), through a 10:1 gear; reflected to the link side N^2 J_m.
ROTOR_INERTIA, GEAR_RATIO = 0.2e-4, 10.0
_ROTOR_REFLECTED = GEAR_RATIO ** 2 * ROTOR_INERTIA                                     # 2.0e-3 kg m^2


def _vector(name: str, value, shape: tuple[int, ...], *, lower: float | None = None,
            strict: bool = False, unit: str = "") -> np.ndarray:
    """Freeze ``value`` as a read-only float array of ``shape`` or raise ParameterError."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: expected numbers of shape {shape}{unit}, got {value!r}") from exc
    if arr.ndim == 0 and shape:
        arr = np.full(shape, float(arr))
    if arr.shape != shape:
        raise ParameterError(f"{name}: expected shape {shape} (or a scalar){unit}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name}: expected finite numbers{unit}, got {arr.tolist()}")
    if lower is not None:
        bad = arr <= lower if strict else arr < lower
        if np.any(bad):
            what = "positive" if strict else "non-negative"
            raise ParameterError(f"{name}: expected {what} values{unit}, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class DynamicParameters:
    """Inertial, friction and gravity data of a 3-RRR (constant, like the geometry).

    Per-leg fields take a scalar (same for the three legs) or shape (3,).  The
    defaults are estimates for Table 1's geometry (0.6 m links, 0.3 m platform
    side), computed in this module from stated assumptions:

    * links: aluminium tube (density 2700 kg/m^3), 25 mm outer diameter, 2 mm
      wall, 0.6 m long: mass 0.2341 kg, slender-rod centroidal inertia
      ``m l^2 / 12 = 7.023e-3`` kg m^2, centre of mass at mid-length 0.3 m
      (joint hardware neglected);
    * platform: 6 mm aluminium plate, equilateral triangle of side 0.3 m:
      mass 0.6313 kg, polar inertia about the centroid ``m a^2 / 12 =
      4.735e-3`` kg m^2, centre of mass at the tool point (the centroid);
    * motors: a 200 W class AC servo with rotor inertia 0.2 kg cm^2 (order of
      magnitude of such datasheets) behind a 10:1 gear, reflected to the link
      side ``N^2 J_m = 2.0e-3`` kg m^2 (gear inertia neglected);
    * viscous friction: 0.02 N m s/rad at each motor (reflected, an
      order-of-magnitude estimate for a small geared servo), 1e-3 N m s/rad at
      each passive ball-bearing joint; both to be identified on a real robot;
    * gravity (0, 0): the robot moves in a horizontal plane.

    Parameters
    ----------
    mass_proximal : float or array_like (3,)
        Mass of proximal link ``M_i D_i``, kg (> 0).
    inertia_proximal : float or array_like (3,)
        Its centroidal moment of inertia about the z axis, kg m^2 (>= 0).
    com_proximal : float or array_like (3,)
        Distance of its centre of mass from the motor axis along ``M_i -> D_i``, m.
    mass_distal, inertia_distal : float or array_like (3,)
        Same for distal link ``D_i A_i``, kg and kg m^2.
    com_distal : float or array_like (3,)
        Distance of its centre of mass from the elbow along ``D_i -> A_i``, m.
    mass_platform : float
        Platform mass, kg (> 0).
    inertia_platform : float
        Platform moment of inertia about its centre of mass, kg m^2 (>= 0).
    com_platform : array_like (2,)
        Platform centre of mass in the platform frame, relative to the tool point ``P``, m.
    rotor_inertia : float or array_like (3,)
        Motor rotor (and gear) inertia reflected to the link side, kg m^2 (>= 0).
    friction_active : float or array_like (3,)
        Viscous friction at the motors (reflected), N m s/rad (>= 0).
    friction_elbow : float or array_like (3,)
        Viscous friction at the passive elbow joints ``D_i`` (relative rate
        ``psi_i - q_i``), N m s/rad (>= 0).
    friction_platform : float or array_like (3,)
        Viscous friction at the passive platform joints ``A_i`` (relative rate
        ``phi - psi_i``), N m s/rad (>= 0).
    gravity : array_like (2,)
        Gravity acceleration in the plane of motion, m/s^2; ``(0, 0)`` for a
        horizontal robot, ``(0, -9.81)`` for a vertical one with +y up.

    Raises
    ------
    ParameterError
        (a ValueError) naming the field, its value and the expectation.
    """

    mass_proximal: np.ndarray = _LINK_MASS
    inertia_proximal: np.ndarray = _LINK_INERTIA
    com_proximal: np.ndarray = LINK_LENGTH / 2.0
    mass_distal: np.ndarray = _LINK_MASS
    inertia_distal: np.ndarray = _LINK_INERTIA
    com_distal: np.ndarray = LINK_LENGTH / 2.0
    mass_platform: float = _PLATE_MASS
    inertia_platform: float = _PLATE_INERTIA
    com_platform: np.ndarray = (0.0, 0.0)
    rotor_inertia: np.ndarray = _ROTOR_REFLECTED
    friction_active: np.ndarray = 0.02
    friction_elbow: np.ndarray = 1e-3
    friction_platform: np.ndarray = 1e-3
    gravity: np.ndarray = field(default=(0.0, 0.0))

    _SPEC = {  # field: (shape, lower bound, strict, unit)
        "mass_proximal": ((3,), 0.0, True, " in kg"),
        "inertia_proximal": ((3,), 0.0, False, " in kg m^2"),
        "com_proximal": ((3,), None, False, " in m"),
        "mass_distal": ((3,), 0.0, True, " in kg"),
        "inertia_distal": ((3,), 0.0, False, " in kg m^2"),
        "com_distal": ((3,), None, False, " in m"),
        "mass_platform": ((), 0.0, True, " in kg"),
        "inertia_platform": ((), 0.0, False, " in kg m^2"),
        "com_platform": ((2,), None, False, " in m"),
        "rotor_inertia": ((3,), 0.0, False, " in kg m^2"),
        "friction_active": ((3,), 0.0, False, " in N m s/rad"),
        "friction_elbow": ((3,), 0.0, False, " in N m s/rad"),
        "friction_platform": ((3,), 0.0, False, " in N m s/rad"),
        "gravity": ((2,), None, False, " in m/s^2"),
    }

    def __post_init__(self):
        for f in fields(self):
            shape, lower, strict, unit = self._SPEC[f.name]
            arr = _vector(f.name, getattr(self, f.name), shape, lower=lower, strict=strict, unit=unit)
            object.__setattr__(self, f.name, float(arr) if shape == () else arr)

    # -------------------------------------------------------------- helpers
    def with_scaled_masses(self, factor: float, *, rotor: bool = False) -> "DynamicParameters":
        """A copy with every link and platform mass (and centroidal inertia) times ``factor``.

        Models a uniformly denser or lighter structure of the same shape, e.g.
        ``factor = 1.2`` for "masses off by +20 %".  Centres of mass, friction and
        gravity are unchanged; the rotor inertia too unless ``rotor`` is true
        (it is a motor datasheet value, not part of the structure).

        Parameters
        ----------
        factor : float
            Positive scale factor.
        rotor : bool
            Also scale ``rotor_inertia``.

        Raises
        ------
        ParameterError
            ``factor`` not a positive finite number.
        """
        if not (isinstance(factor, (int, float, np.floating, np.integer)) and np.isfinite(factor)
                and factor > 0):
            raise ParameterError(f"factor: expected a positive finite number, got {factor!r}")
        keys = ["mass_proximal", "inertia_proximal", "mass_distal", "inertia_distal",
                "mass_platform", "inertia_platform"] + (["rotor_inertia"] if rotor else [])
        return replace(self, **{k: np.asarray(getattr(self, k)) * float(factor) for k in keys})

    def to_dict(self) -> dict:
        """JSON-ready description (floats and lists of floats)."""
        return {f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
                for f in fields(self)}

    @classmethod
    def from_dict(cls, data: dict) -> "DynamicParameters":
        """Inverse of :meth:`to_dict`; missing keys take the defaults, unknown keys are refused."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ParameterError(f"parameters: unknown keys {unknown}, expected a subset of {sorted(names)}")
        return cls(**data)

    @classmethod
    def from_robot(cls, robot, what: str = "the plant and the controller") -> "DynamicParameters":
        """The ``[dynamics]`` table of a robot description (:class:`solver.robot.Robot`), every key given
        (the defaults are the paper's robot's, not yours).

        Raises
        ------
        solver.robot.RobotDescriptionError
            No ``[dynamics]`` (``what`` needs it), a key missing or unknown, a value refused (the file,
            the key and the value named).
        """
        from solver.robot import RobotDescriptionError, is_number_tree

        table = robot.require_dynamics(what)
        names = [f.name for f in fields(cls)]
        missing = [n for n in names if n not in table]
        if missing:
            raise RobotDescriptionError(f"{robot.source}: [dynamics]: missing {', '.join(missing)} (give every key "
                                        f"of DynamicParameters: {', '.join(names)}; docs/robots.md)")
        for name in names:                      # numbers only: no boolean or string read as one
            if not is_number_tree(table[name]):
                raise RobotDescriptionError(f"{robot.source}: [dynamics].{name} = {table[name]!r}: expected a number "
                                            "or a list of numbers (no boolean, no string)")
        try:
            params = cls.from_dict(table)
        except (ParameterError, TypeError, ValueError, ArithmeticError) as exc:
            raise RobotDescriptionError(f"{robot.source}: [dynamics]: {exc}") from None
        for name in ("inertia_proximal", "inertia_distal", "inertia_platform"):   # a real body's: positive
            if np.any(np.asarray(getattr(params, name)) <= 0.0):
                raise RobotDescriptionError(f"{robot.source}: [dynamics].{name} = {table[name]!r}: expected positive "
                                            "inertias in kg m^2 (a link or plate of a real robot has one)")
        return params

    def __eq__(self, other):
        if not isinstance(other, DynamicParameters):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None

    @property
    def total_mass(self) -> float:
        """Mass of all moving bodies, kg."""
        return float(np.sum(self.mass_proximal) + np.sum(self.mass_distal) + self.mass_platform)


def _row_constants(params) -> MappingProxyType:
    """Per-parameter constant vectors (read-only), the data of :func:`row_constants`.

    ``w`` (21,): weights of the velocity rows -- platform (x, y, rot), proximal
    x3 / y3 / rot3 (rotor included), distal x3 / y3 / rot3; ``gamma`` (21,): gravity
    acceleration of each row (zero on rotation rows); ``b`` (9,): viscous
    coefficients of the motors, elbows and platform joints; ``m`` (7,): masses of
    the platform, proximal and distal links.
    """
    gx, gy = params.gravity
    z3, o3 = np.zeros(3), np.ones(3)
    k = {
        "w": np.concatenate([[params.mass_platform, params.mass_platform, params.inertia_platform],
                             params.mass_proximal, params.mass_proximal,
                             params.inertia_proximal + params.rotor_inertia,
                             params.mass_distal, params.mass_distal, params.inertia_distal]),
        "gamma": np.concatenate([[gx, gy, 0.0], gx * o3, gy * o3, z3, gx * o3, gy * o3, z3]),
        "b": np.concatenate([params.friction_active, params.friction_elbow, params.friction_platform]),
        "m": np.concatenate([[params.mass_platform], params.mass_proximal, params.mass_distal]),
    }
    for v in k.values():
        v.setflags(write=False)
    return MappingProxyType(k)


#: ``row_constants(params)``: :func:`_row_constants` built once per parameter object and kept beside it
#: (:func:`solver.identity_cache.by_identity`; the parameters are frozen, nothing is stored on them).
row_constants = by_identity(_row_constants)
