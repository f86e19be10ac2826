"""The robot as built: geometric tolerances and how far they move a leg's closure.

No built robot has its model's exact lengths. After calibration a 0.6 m link is known to a few
hundredths of a millimetre, before it to about half a millimetre. :class:`GeometryTolerance` holds the
half-widths (m) of the geometry's lengths and coordinates; the tracker's option ``geometry_tolerance``
makes ``certain`` and ``pose_bound`` hold for every robot inside them, not for the model alone
(:mod:`solver.as_built`: where the tracker carries it).

The offset bound (exact, leg by leg; no linearisation)
------------------------------------------------------
Both manipulators are fully parallel: leg ``i`` is one circle constraint of its own joint ``q_i``.
Take a robot as built, geometry ``g'`` within the tolerance of the model's ``g``, at pose ``X'`` with
joints ``q``. Let ``B_i`` be the model's platform joint at ``X'`` and ``D_i(q_i)`` the model's elbow
(3-RPR: its base joint). The built leg closes, ``|B'_i - D'_i| = l2'_i`` (3-RPR: ``= q_i``), so by the
triangle inequality ``| |B_i - D_i| - l2_i | <= |dB_i| + |dM_i| + |dl1_i| + |dl2_i| <= e_i``, the leg's
*offset bound* (:meth:`GeometryTolerance.offset_bound`: ``sqrt(2)`` times the coordinate half-widths of
``M_i`` and ``b_i``, plus the two lengths').

* 3-RRR: the model's ``F_i = |B_i - D_i|^2 - l2_i^2`` lies within ``sigma_i = e_i (2 l2_i + e_i)`` of 0:
  the tracker's certificates take that slack (:mod:`solver.as_built`).
* 3-RPR: ``h(t) = |B_i - A_i| - t`` has ``|h'| = 1``: the model reaches ``X'`` with each leg length
  within ``e_i`` of the built robot's, a joint width.

:func:`joint_equivalent` gives the 3-RRR's joint width too: ``h(t) = |B_i - M_i - l1_i u(t)| - l2_i``
has ``|h'| = l1_i |sin alpha_i|`` (``alpha_i`` the elbow angle), so where it stays above ``m_i > 0`` on
``[q_i - e_i/m_i, q_i + e_i/m_i]`` the model reaches ``X'`` with joint ``i`` within ``e_i / m_i`` of the
built robot's, in the same posture (the intermediate value theorem); ``m_i`` is bounded from below over
a box (:func:`elbow_margin`: ``|sin alpha| >= |sin alpha_c| - |alpha - alpha_c|``). Unbounded near a
straight elbow, the tracker does not use it; the benchmark's fold floor does (the joint box a sound
method cannot shrink). :func:`built_robot` draws a robot inside the tolerance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ._kernels import geometry_width as _gw
from .checks import SolverInputError

__all__ = ["GeometryTolerance", "TOLERANCE_KEYS", "geometry_tolerance", "built_robot", "elbow_margin",
           "joint_equivalent"]

#: Per-field keys of a tolerance (m): the geometry's fields by kind, besides ``length`` (all of them).
TOLERANCE_KEYS = {"3-RRR": ("motors", "l1", "l2", "platform"), "3-RPR": ("base", "platform")}

_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class GeometryTolerance:
    """Half-widths (m) of a model's geometric fields: the robot as built lies within them.

    Attributes
    ----------
    kind : str
        "3-RRR" or "3-RPR".
    widths : dict
        Field -> half-width, m (:data:`TOLERANCE_KEYS`): every coordinate of ``motors`` / ``base`` and
        ``platform``, every entry of ``l1`` and ``l2``.
    """

    kind: str
    widths: Mapping[str, float]

    @property
    def zero(self) -> bool:
        """No tolerance: the model is the robot (the certificates as they have always been)."""
        return all(w == 0.0 for w in self.widths.values())

    def offset_bound(self) -> np.ndarray:
        """The legs' offset bounds ``e_i`` (3,), m: how far a built leg's closure can be from the model's
        at the same pose and joint (see the module docstring)."""
        w = self.widths
        if self.kind == "3-RPR":
            return np.full(3, _SQRT2 * (w["base"] + w["platform"]))
        return np.full(3, _SQRT2 * (w["motors"] + w["platform"]) + w["l1"] + w["l2"])

    def to_dict(self) -> dict:
        return {"kind": self.kind, **{k: float(v) for k, v in self.widths.items()}}


def _shortest(model) -> float:
    """The shortest link (m) the tolerance is measured against: min(l1, l2) of a 3-RRR, the shortest side
    of the base and platform triangles of a 3-RPR (its legs have no fixed length)."""
    if model.kind == "3-RPR":
        sides = [np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1) for p in (model.base, model.platform)]
        return float(np.min(np.concatenate(sides)))
    return float(min(np.min(model.l1), np.min(model.l2)))


def _width(name: str, value, limit: float) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not math.isfinite(float(value)) or float(value) < 0.0:
        raise SolverInputError(f"{name}: expected a half-width in m, a finite number >= 0, got {value!r}")
    if float(value) > limit:
        raise SolverInputError(f"{name}: expected at most a tenth of the shortest link, {limit:.6g} m, "
                               f"got {float(value)!r} m")
    return float(value)


def geometry_tolerance(model, value, name: str = "geometry_tolerance") -> GeometryTolerance:
    """Check ``value`` into a :class:`GeometryTolerance` of ``model``.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    value : float, mapping or GeometryTolerance
        A half-width (m) of every length and coordinate, or a mapping ``{"length": m, <field>: m}``
        (fields: :data:`TOLERANCE_KEYS`; ``length`` the default of the fields not given; 0 when absent).
    name : str
        What to call ``value`` in an error.

    Raises
    ------
    SolverInputError
        A negative, non-finite or non-number half-width, one above a tenth of the shortest link, an
        unknown field (each named).
    """
    keys = TOLERANCE_KEYS[model.kind]
    limit = 0.1 * _shortest(model)
    if isinstance(value, GeometryTolerance):
        if value.kind != model.kind:
            raise SolverInputError(f"{name}: a tolerance of a {value.kind}, not of a {model.kind}")
        value = dict(value.widths)
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(keys) - {"length"})
        if unknown:
            raise SolverInputError(f"{name}: unknown field(s) {unknown}; expected 'length' and any of {list(keys)} (m)")
        default = _width(f"{name}.length", value.get("length", 0.0), limit)
        widths = {k: _width(f"{name}.{k}", value[k], limit) if k in value else default for k in keys}
    else:
        w = _width(name, value, limit)
        widths = {k: w for k in keys}
    return GeometryTolerance(model.kind, widths)


def built_robot(model, tolerance, rng, corner: bool = False):
    """A robot as built: ``model`` with every length and coordinate of its geometry moved within
    ``tolerance`` (a half-width in m, a mapping or a :class:`GeometryTolerance`, as
    :func:`geometry_tolerance`), uniformly or (``corner``) by exactly +- the half-width, a corner of the
    tolerance box.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    tolerance : float, mapping or GeometryTolerance
    rng : numpy.random.Generator
    corner : bool

    Returns
    -------
    Manipulator or RPRManipulator
        Of the same kind, named ``<model.name>-as-built``.
    """
    tol = geometry_tolerance(model, tolerance, "tolerance")
    d = model.to_dict()
    for key, w in tol.widths.items():
        a = np.asarray(d[key], float)
        d[key] = (a + w * (rng.choice([-1.0, 1.0], a.shape) if corner else rng.uniform(-1.0, 1.0, a.shape))).tolist()
    d["name"] = f"{model.name}-as-built"
    return type(model).from_dict(d)


def elbow_margin(model, X_lo, X_hi, q_lo, q_hi) -> np.ndarray:
    """A lower bound of ``l1_i |sin alpha_i|`` (m) over a box of poses and joints (3-RRR).

    Parameters
    ----------
    model : Manipulator
    X_lo, X_hi : array_like, shape (3,)
        The pose box, m, m, rad.
    q_lo, q_hi : array_like, shape (3,)
        The joint box, rad.

    Returns
    -------
    ndarray, shape (3,)
        Per leg, m; 0 where the box may hold a straight elbow (a serial singularity).
    """
    out = np.empty(3)
    _gw.elbow_margins(model.motors, model.l1, model.platform, model.platform_radius, *_boxes(X_lo, X_hi, q_lo, q_hi),
                      out)
    return out


def _boxes(*arrays):
    return [np.ascontiguousarray(a, dtype=float).reshape(3) for a in arrays]


def joint_equivalent(model, tolerance: GeometryTolerance, X_lo, X_hi, q_lo, q_hi, iterations: int = 5) -> float:
    """The joint half-width (rad for the 3-RRR, m for the 3-RPR) that covers the robot as built over a box.

    Every built robot within ``tolerance`` whose pose lies in ``[X_lo, X_hi]`` and joints in ``[q_lo,
    q_hi]`` is at a pose of the model with joints within the returned width of its own (module
    docstring). The 3-RRR's width is the fixed point of ``eps = e / m(q box widened by eps)``
    (:mod:`solver._kernels.geometry_width`).

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    tolerance : GeometryTolerance
    X_lo, X_hi : array_like, shape (3,)
        m, m, rad.
    q_lo, q_hi : array_like, shape (3,)
        rad (3-RRR) or m (3-RPR).

    Returns
    -------
    float
        ``max_i eps_i``; 0.0 for a zero tolerance; ``inf`` where an elbow may be straight in the box.
    """
    if tolerance.zero:
        return 0.0
    e = tolerance.offset_bound()
    if model.kind == "3-RPR":
        return float(np.max(e))
    return float(_gw.joint_width(model.motors, model.l1, model.platform, model.platform_radius, e,
                                 *_boxes(X_lo, X_hi, q_lo, q_hi), int(iterations)))
