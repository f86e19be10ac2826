"""A robot a person describes: one TOML file (or a dict) -> its model, home pose and defaults.

The description (``docs/robots.md`` documents every field; ``robots/`` holds the paper's robot and an
irregular example)::

    name = "my-3rrr"
    kind = "3-RRR"                 # or "3-RPR"
    [geometry]                     # m, base frame: the keys of Manipulator.to_dict()
    motors = [[0.0, 0.0], [1.0, 0.0], [0.5, 0.8660254]]
    l1 = [0.6, 0.6, 0.6]
    l2 = [0.6, 0.6, 0.6]
    platform = [[-0.15, -0.0866], [0.15, -0.0866], [0.0, 0.1732]]   # joints in the platform frame
    [home]
    pose = [0.5, 0.2887, 0.0]      # x, y (m), phi (rad)
    posture = 1
    [dynamics]                     # optional (the plant and the controller need it)
    [map]                          # optional: resolution = [m, deg]
    [tolerance]                    # optional: the robot as built, length = half-width in m (+ per field)

:func:`load_robot` reads a file, :func:`robot_from_dict` a dict; both check everything before any
work and raise :class:`RobotDescriptionError` (a ``ValueError``) naming the source, the field, its
value and what was expected.  The math knows nothing of dynamics: ``[dynamics]`` is kept as given
(:attr:`Robot.dynamics`) and checked by :func:`dynamics.parameters.DynamicParameters.from_robot`.
"""
from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .checks import GeometryError, SolverInputError
from .geometry_tolerance import GeometryTolerance, TOLERANCE_KEYS, geometry_tolerance
from .kinematics import ik, singularity_measures
from .manipulator import Manipulator
from .rpr import RPRManipulator

__all__ = ["Robot", "RobotDescriptionError", "load_robot", "robot_from_dict", "start_pose", "default_circle",
           "is_number_tree", "ROBOTS", "KINDS", "SINGULAR_MEASURE", "MAP_NODES_PER_REACH"]

#: the folder of the robot descriptions that ship with the repository (the paper's robot, an irregular example)
ROBOTS = Path(__file__).resolve().parent.parent / "robots"
#: the kinds of robot a description may name, and the keys of their ``[geometry]``
KINDS = {"3-RRR": ("motors", "l1", "l2", "platform"), "3-RPR": ("base", "platform", "rho_min", "rho_max")}
_SHAPES = {"motors": (3, 2), "platform": (3, 2), "base": (3, 2), "l1": (3,), "l2": (3,), "rho_min": (), "rho_max": ()}
_TOP = {"name": True, "kind": True, "geometry": True, "home": True, "dynamics": False, "map": False,
        "tolerance": False}
#: below this normalised singularity measure (0 singular, 1 far) a home pose is refused as singular
SINGULAR_MEASURE = 1e-3
#: the default map spacing: the longest leg reach over this many nodes (the paper's 1.2 m: 10 mm)
MAP_NODES_PER_REACH = 120
_DEFAULT_ANGLE_DEG = 2.0


class RobotDescriptionError(ValueError):
    """A robot description that cannot be used; the message names the source, the field and the value."""


@dataclass(frozen=True)
class Robot:
    """A checked robot description (constant, like the model it holds).

    Attributes
    ----------
    name : str
    kind : str
        ``"3-RRR"`` or ``"3-RPR"``.
    model : Manipulator or RPRManipulator
        The geometry (m).
    home_pose : tuple of 3 float
        x, y (m), phi (rad): the start pose of the FMUs and the loop.
    home_posture : int
        1..8 for a 3-RRR (CONVENTIONS.md), 1 for a 3-RPR.
    home_joints : tuple of 3 float
        The inverse kinematics of the home pose in that posture (rad, or m for a 3-RPR).
    dynamics : dict or None
        The ``[dynamics]`` table as written (checked by ``DynamicParameters.from_robot``).
    resolution : tuple of 2 float
        The map spacing (m, rad): ``[map] resolution`` or the default scaled with the robot.
    source : str
        The file it came from, or ``"<dict>"``.
    description : dict
        The description as read (JSON-ready), what the FMUs carry.
    tolerance : GeometryTolerance
        The robot as built: ``[tolerance]``'s half-widths (m), zero when the description has none; what
        a tracker of this robot takes as ``geometry_tolerance`` (:mod:`solver.geometry_tolerance`).
    """

    name: str
    kind: str
    model: object
    home_pose: tuple
    home_posture: int
    home_joints: tuple
    dynamics: dict | None
    resolution: tuple
    source: str
    description: dict = field(repr=False)
    tolerance: GeometryTolerance = field(default=None, repr=False)

    @property
    def reach(self) -> float:
        """The longest leg reach (m): ``max(l1 + l2)`` of a 3-RRR, ``rho_max`` of a 3-RPR; the robot's size."""
        return _reach(self.model)

    @property
    def digest(self) -> str:
        """SHA-256 (hex, 16 digits) of the description's canonical JSON: what an FMU's build records."""
        text = json.dumps(self.description, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def require_dynamics(self, what: str) -> dict:
        """The ``[dynamics]`` table, or :class:`RobotDescriptionError` saying ``what`` needs it."""
        if self.dynamics is None:
            raise RobotDescriptionError(f"{self.source}: [dynamics]: {what} needs the robot's masses and inertias; "
                                        "the description has no [dynamics] table (docs/robots.md)")
        return self.dynamics

    @classmethod
    def paper(cls) -> "Robot":
        """The paper's 3-RRR (Table 1) from its shipped description ``robots/paper-3rrr.toml``."""
        return load_robot(ROBOTS / "paper-3rrr.toml")


def start_pose(robot: Robot, posture: int) -> tuple:
    """A start pose of ``robot`` in ``posture``: its home pose when that posture reaches it away from
    singularities, else the well-conditioned pose of that posture nearest to it (x, y in m, phi in rad).

    The search samples the tool space's bounding box (:func:`solver.grid.default_bounds`, 48 x 48 x 72
    poses) and keeps the poses whose singularity measures are both above 0.05; their nearest to the home
    pose (distance in m, phi scaled by the platform radius) wins.

    Raises
    ------
    RobotDescriptionError
        No pose of the sample is reachable and well conditioned in ``posture``.
    """
    from .grid import default_bounds

    model, home = robot.model, np.array(robot.home_pose)
    if posture == robot.home_posture:
        return robot.home_pose
    q = ik(model, home, posture)
    if np.all(np.isfinite(q)):
        m = singularity_measures(model, home, q)
        if min(float(m.type1), float(m.type2)) >= 0.05:
            return robot.home_pose
    b = default_bounds(model, (robot.resolution[0],) * 2 + (robot.resolution[1],))
    axes = [np.linspace(b[0, 0], b[0, 1], 48), np.linspace(b[1, 0], b[1, 1], 48),
            np.linspace(-np.pi, np.pi, 72, endpoint=False)]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    q = ik(model, X, posture)
    ok = np.all(np.isfinite(q), axis=1)
    X, q = X[ok], q[ok]
    if len(X):
        m = singularity_measures(model, X, q)
        keep = np.minimum(m.type1, m.type2) >= 0.05
        X = X[keep]
    if not len(X):
        raise RobotDescriptionError(f"{robot.source}: posture {posture}: the robot reaches no well-conditioned pose "
                                    "in it (sampled over its tool space); choose another posture")
    radius = float(np.mean(model.platform_radius))
    dphi = np.angle(np.exp(1j * (X[:, 2] - home[2])))
    best = X[np.argmin(np.hypot(X[:, 0] - home[0], X[:, 1] - home[1]) ** 2 + (radius * dphi) ** 2)]
    return tuple(float(v) for v in best)


def default_circle(robot: Robot, posture: int | None = None) -> dict:
    """The robot's default reference circle (the closed loop's scenario): ``{"center": (x, y), "radius",
    "phi"}`` (m, m, rad), starting at :func:`start_pose` (its first point, polar angle 0) with the
    orientation held.  The radius is a 24th of the longest leg reach (the paper's robot: 50 mm), halved
    until the whole circle is reachable in ``posture`` (default the home posture) with both singularity
    measures at least 0.05.

    Raises
    ------
    RobotDescriptionError
        No circle of at least a 1000th of the reach fits.
    """
    posture = robot.home_posture if posture is None else int(posture)
    X0 = np.array(start_pose(robot, posture))
    reach = robot.reach
    a = np.linspace(0.0, 2.0 * np.pi, 181)
    radius = reach / 24.0
    while radius >= reach / 1000.0:
        center = X0[:2] - (radius, 0.0)
        X = np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a), np.full_like(a, X0[2])], axis=1)
        q = ik(robot.model, X, posture)
        if np.all(np.isfinite(q)):
            m = singularity_measures(robot.model, X, q)
            if float(np.min(np.minimum(m.type1, m.type2))) >= 0.05:
                return {"center": (float(center[0]), float(center[1])), "radius": float(radius), "phi": float(X0[2])}
        radius /= 2.0
    raise RobotDescriptionError(f"{robot.source}: home.pose: no reference circle about it fits posture {posture} "
                                "away from singularities; choose another home pose")


def load_robot(path) -> Robot:
    """Read and check the robot description file ``path`` (TOML).

    Raises
    ------
    RobotDescriptionError
        The file cannot be read or parsed, or a field is missing, unknown or wrong (the message names
        the file, the field, its value and what was expected).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RobotDescriptionError(f"{path}: cannot read the robot description ({exc.strerror or exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotDescriptionError(f"{path}: not valid TOML: {exc}") from None
    return robot_from_dict(data, source=str(path))


def _reach(model) -> float:
    return float(np.max(model.l1 + model.l2)) if hasattr(model, "l1") else float(model.rho_max)


def _fail(source: str, where: str, value, expected: str):
    raise RobotDescriptionError(f"{source}: {where} = {value!r}: expected {expected}")


def is_number_tree(value) -> bool:
    """Whether ``value`` is an int or float (not a bool), or a list of such trees."""
    if isinstance(value, list):
        return all(is_number_tree(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _numbers(source: str, where: str, value, shape: tuple) -> np.ndarray:
    """``value`` as a float array of ``shape`` (finite numbers: no bool, no string), or the error naming it."""
    what = "a number" if shape == () else f"an array of shape {shape} (m)"
    if not is_number_tree(value):
        _fail(source, where, value, what + ("" if shape == () else " of numbers"))
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        _fail(source, where, value, what + " of numbers")
    if arr.shape != shape:
        _fail(source, where, value, f"{what}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        _fail(source, where, value, "finite numbers")
    return arr


def _table(source: str, data: dict, key: str, required: dict) -> dict:
    """The sub-table ``key`` of ``data`` with exactly the keys allowed (``required``: key -> needed)."""
    table = data.get(key)
    if not isinstance(table, dict):
        _fail(source, f"[{key}]", table, "a table")
    missing = [k for k, need in required.items() if need and k not in table]
    if missing:
        raise RobotDescriptionError(f"{source}: [{key}]: missing {', '.join(missing)} (expected the keys "
                                    f"{', '.join(required)}; docs/robots.md)")
    unknown = sorted(set(table) - set(required))
    if unknown:
        raise RobotDescriptionError(f"{source}: [{key}]: unknown key {', '.join(unknown)} (expected "
                                    f"{', '.join(required)}; docs/robots.md)")
    return table


def _tolerance(source: str, model, table) -> GeometryTolerance:
    """``[tolerance]``: ``length`` (m, every length and coordinate) and per-field half-widths."""
    keys = {"length": False, **{k: False for k in TOLERANCE_KEYS[model.kind]}}
    table = _table(source, {"tolerance": table}, "tolerance", keys)
    if not table:
        _fail(source, "[tolerance]", table, f"length = <m> and/or per-field half-widths ({', '.join(keys)})")
    try:
        return geometry_tolerance(model, table, name="tolerance")
    except SolverInputError as exc:
        msg = str(exc).removeprefix("tolerance.").removeprefix("tolerance")
        raise RobotDescriptionError(f"{source}: [tolerance] {msg.lstrip(': ')} (docs/robots.md)") from None


def _model(source: str, kind: str, geometry: dict, name: str):
    values = {}
    for key in KINDS[kind]:
        arr = _numbers(source, f"geometry.{key}", geometry[key], _SHAPES[key])
        if key in ("l1", "l2", "rho_min", "rho_max") and np.any(arr <= 0):
            _fail(source, f"geometry.{key}", geometry[key], "positive lengths in m")
        values[key] = arr if arr.shape else float(arr)
    try:
        if kind == "3-RRR":
            return Manipulator(name=name, **values)
        if values["rho_min"] >= values["rho_max"]:
            _fail(source, "geometry.rho_max", geometry["rho_max"], f"more than rho_min = {geometry['rho_min']!r}")
        return RPRManipulator(name=name, **values)
    except GeometryError as exc:
        field_name = str(exc).split(":")[0]
        raise RobotDescriptionError(f"{source}: geometry.{field_name}" + str(exc)[len(field_name):]) from None


def _home(source: str, kind: str, model, home: dict) -> tuple:
    pose = _numbers(source, "home.pose", home["pose"], (3,))
    posture = home.get("posture", 1)
    n = 8 if kind == "3-RRR" else 1
    if isinstance(posture, bool) or not isinstance(posture, int) or not 1 <= posture <= n:
        _fail(source, "home.posture", posture, f"an integer in 1..{n}")
    q = ik(model, pose, posture)
    if not np.all(np.isfinite(q)):
        legs = ", ".join(str(i + 1) for i in range(3) if not np.isfinite(q[i])) or "a leg"
        _fail(source, "home.pose", home["pose"], f"a pose the robot reaches in posture {posture} (leg {legs} "
                                                   "cannot reach its platform joint: check [geometry])")
    m = singularity_measures(model, pose, q)
    worst = min(float(m.type1), float(m.type2))
    if worst < SINGULAR_MEASURE:
        kind_s = "parallel (type 1)" if m.type1 <= m.type2 else "serial (type 2: a leg stretched or folded)"
        _fail(source, "home.pose", home["pose"], f"a pose away from singularities; it is {kind_s} singular "
                                                   f"(measure {worst:.2g} < {SINGULAR_MEASURE:g})")
    return tuple(float(v) for v in pose), int(posture), tuple(float(v) for v in q)


#: the most nodes a map of a description may have (the paper's robot at its default: 5.6 million)
MAX_MAP_NODES = 2e8


def _resolution(source: str, model, table: dict | None) -> tuple:
    if table and "resolution" in table:
        step = _numbers(source, "map.resolution", table["resolution"], (2,))
        if step[0] <= 0 or not 0 < step[1] <= 30:
            _fail(source, "map.resolution", table["resolution"], "[m > 0, deg in (0, 30]]")
        nodes = (2.0 * _reach(model) / step[0]) ** 2 * 360.0 / step[1]      # the tool space's box, roughly
        if nodes > MAX_MAP_NODES:
            _fail(source, "map.resolution", table["resolution"], f"a spacing giving at most {MAX_MAP_NODES:.0e} map "
                  f"nodes for a reach of {_reach(model):g} m (this one: about {nodes:.1e})")
        return float(step[0]), math.radians(float(step[1]))
    return _reach(model) / MAP_NODES_PER_REACH, math.radians(_DEFAULT_ANGLE_DEG)


def _plain(source: str, value, where: str) -> None:
    """Refuse what a description may not hold: TOML dates and times (the FMUs carry it as JSON)."""
    if isinstance(value, dict):
        for k, v in value.items():
            _plain(source, v, f"{where}.{k}" if where else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _plain(source, v, f"{where}[{i}]")
    elif not isinstance(value, (str, int, float, bool)):
        _fail(source, where, value, "a number, a string, a boolean, or a list or table of them (no date or time)")


def robot_from_dict(data: dict, source: str = "<dict>") -> Robot:
    """Check the robot description ``data`` (the TOML file's content as a dict) and build its :class:`Robot`.

    Raises
    ------
    RobotDescriptionError
        A missing, unknown or wrong field: collinear motors or platform joints, non-positive lengths, a
        home pose out of reach, singular or outside its posture (the message names ``source``, the field,
        its value and what was expected).
    """
    if not isinstance(data, dict):
        _fail(source, "the description", data, "a table of name, kind, [geometry], [home]")
    missing = [k for k, need in _TOP.items() if need and k not in data]
    if missing:
        raise RobotDescriptionError(f"{source}: missing {', '.join(missing)} (a description needs name, kind, "
                                    "[geometry] and [home]; docs/robots.md)")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise RobotDescriptionError(f"{source}: unknown key {', '.join(unknown)} (expected {', '.join(_TOP)}; "
                                    "docs/robots.md)")
    _plain(source, data, "")
    name, kind = data["name"], data["kind"]
    if not isinstance(name, str) or not name.strip():
        _fail(source, "name", name, "a non-empty string")
    if not isinstance(kind, str) or kind not in KINDS:
        _fail(source, "kind", kind, f"one of {', '.join(KINDS)}")
    geometry = _table(source, data, "geometry", {k: True for k in KINDS[kind]})
    home = _table(source, data, "home", {"pose": True, "posture": False})
    try:
        model = _model(source, kind, geometry, name)
        pose, posture, joints = _home(source, kind, model, home)
    except (ArithmeticError, FloatingPointError) as exc:           # e.g. lengths of 1e200 m
        raise RobotDescriptionError(f"{source}: [geometry] or [home]: numbers out of range for the kinematics "
                                    f"({type(exc).__name__}: {exc}); expected lengths of a real robot in m") from None
    dynamics = data.get("dynamics")
    if dynamics is not None and not isinstance(dynamics, dict):
        _fail(source, "[dynamics]", dynamics, "a table (the keys of DynamicParameters.to_dict())")
    if dynamics is not None and kind != "3-RRR":
        _fail(source, "[dynamics]", "...", "no [dynamics] for a 3-RPR (its dynamics are not modelled)")
    table = _table(source, data, "map", {"resolution": False}) if "map" in data else None
    tolerance = _tolerance(source, model, data["tolerance"]) if "tolerance" in data else geometry_tolerance(model, 0.0)
    description = json.loads(json.dumps(data))            # JSON-ready (TOML dates are not allowed above)
    return Robot(name=name, kind=kind, model=model, home_pose=pose, home_posture=posture, home_joints=joints,
                 dynamics=dict(dynamics) if dynamics is not None else None, resolution=_resolution(source, model, table),
                 source=source, description=description, tolerance=tolerance)
