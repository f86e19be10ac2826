"""One manipulator interface: what procedure 1, the DK and the tracker ask of a manipulator.

A manipulator is a frozen *model* (geometry only) of one of the types below; the
algorithms are plain functions of ``(model, inputs)`` that work for every type:
:func:`solver.ik`, :func:`solver.posture_of`, :func:`solver.constraints`,
:func:`solver.jacobians`, :func:`solver.singularity_measures`, :func:`solver.dk_all`,
:func:`solver.default_bounds`, :meth:`solver.MapTensor.build`.

Every model provides

* ``kind`` ("3-RRR", "3-RPR"), ``n_postures`` (IK branches: 8 for the 3-RRR, 1 for
  the 3-RPR, whose legs have one length per pose) and ``joint_unit`` ("rad", "m");
* ``platform`` (3, 2) and ``platform_radius`` (3,), m;
* ``circle_legs()``: every leg of these planar manipulators is a circle constraint
  ``|P + R(phi) b_i - D_i(q_i)|^2 = r_i(q_i)^2``.  The 3-RRR's joint moves the centre
  (``D_i = M_i + l1_i (cos q_i, sin q_i)``, ``r_i = l2_i``), the 3-RPR's the radius
  (``D_i = A_i``, ``r_i = q_i``); the compiled kernels (the sextic DK of
  :mod:`solver.direct_kinematics`, the numbering rules) are written once for circles;
* ``reach_discs()``: the discs the platform joints stay in (the tool-space bounds);
* ``to_dict()`` / ``digest()``: identity, recorded in every map tensor file.
"""
from __future__ import annotations

from .checks import GeometryError, check_instance
from .manipulator import Manipulator
from .rpr import RPRManipulator

__all__ = ["MANIPULATOR_TYPES", "check_manipulator", "manipulator_from_dict"]

#: The manipulator types by kind.
MANIPULATOR_TYPES = {"3-RRR": Manipulator, "3-RPR": RPRManipulator}
_TYPES = tuple(MANIPULATOR_TYPES.values())
_EXPECTED = "a " + " or an ".join(t.__name__ for t in _TYPES) + " (the manipulator interface)"


def check_manipulator(model):
    """``model`` if it implements the manipulator interface, else :class:`solver.SolverInputError`."""
    return check_instance("model", model, _TYPES, _EXPECTED)


def manipulator_from_dict(data: dict):
    """The model of a :meth:`to_dict` description, whichever its type (3-RPR: it has ``base``)."""
    if not isinstance(data, dict):
        raise GeometryError(f"geometry: expected a dict, got {type(data).__name__}")
    return (RPRManipulator if "base" in data else Manipulator).from_dict(data)
