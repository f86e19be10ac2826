"""Where a tracker carries the robot as built: a slack in each leg's constraint, or a joint width.

:mod:`solver.geometry_tolerance` bounds how far a built leg's closure lies from the model's: at the
built robot's pose and joints, the model's platform joint ``B_i`` is within ``e_i`` (the leg's *offset
bound*, m) of the distance its leg closes at. A :class:`solver.Tracker` with a non-zero
``geometry_tolerance`` puts that bound into its certificates once, at construction:

* 3-RRR (revolute legs): as a **slack** of each leg's circle constraint. The model's
  ``F_i = |B_i - D_i(q_i)|^2 - l2_i^2`` lies within ``sigma_i = e_i (2 l2_i + e_i)`` of 0 there (the
  same triangle inequality), whatever the elbow angle. The tracker's model pack carries ``e_i``
  (:data:`solver._kernels.layout.MODEL_OFFSET`, :func:`as_built_pack`) and every certificate takes the
  constraint as ``F = s``, ``|s_i| <= sigma_i``: Krawczyk's and the tubes' constant term gains
  ``|Y| sigma``, the exclusion's and the eliminant's interval evaluations take ``l2_i^2 +- sigma_i``,
  and the exclusion's elbow sign gives way by ``asin(e_i / rho)`` (a built robot's elbow may be the
  model's other one where it is nearly straight). Proofs over ``(q, s)``: they hold for every robot
  within the tolerance, and with the joints' tolerance on top. No joint width, so no ``1 / sin alpha``
  near a straight elbow.
* 3-RPR (prismatic legs): as a **joint width**, exactly ``e_i`` (``|h'| = 1``: the model reaches the
  built robot's pose with each leg length within ``e_i`` of the built one's, :func:`joint_width`),
  added to ``joint_tolerance``.

A tracker with geometric tolerance is in the measured-joints regime even on exact joints (the model's DK
solutions of the readings are not the built robot's poses): certainty comes from the tube chain and
re-acquisition, which bound both. With 0 nothing changes, bit for bit.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ._kernels import layout as _lay
from .geometry_tolerance import GeometryTolerance

__all__ = ["as_built_pack", "joint_width", "reach_model"]


def as_built_pack(model, tolerance: GeometryTolerance, pack) -> np.ndarray:
    """The model pack ``pack`` (MODEL_SIZE,) of ``model`` with its legs' offset bounds (3-RRR; m) for the
    robot as built; ``pack`` itself (not copied) for a zero tolerance or a 3-RPR."""
    if tolerance.zero or model.kind == "3-RPR":
        return pack
    out = np.array(pack, dtype=float)
    out[_lay.MODEL_OFFSET:_lay.MODEL_OFFSET + 3] = tolerance.offset_bound()
    return out


def joint_width(model, tolerance: GeometryTolerance) -> float:
    """The joint half-width (m) a 3-RPR's tracker adds to ``joint_tolerance`` for the robot as built: the
    largest offset bound; 0.0 for a 3-RRR (its tolerance is a slack, :func:`as_built_pack`) or a zero
    tolerance."""
    if tolerance.zero or model.kind != "3-RPR":
        return 0.0
    return float(np.max(tolerance.offset_bound()))


def reach_model(model, tolerance: GeometryTolerance, joint_tolerance: float = 0.0):
    """The model whose tool space holds every pose a tracker of ``model`` may meet (the box
    re-acquisition searches, :func:`solver.grid.default_bounds`): a 3-RRR's distal links ``e_i`` longer
    (at the built robot's pose the model's platform joint ``B_i`` is within ``l2_i + e_i`` of its elbow,
    so within ``l1_i + l2_i + e_i`` of its motor: the reach discs of that model hold it, exactly); a
    3-RPR's legs ``joint_tolerance + e`` longer.  ``model`` itself for a 3-RRR with zero tolerance."""
    if model.kind == "3-RPR":
        return replace(model, rho_max=model.rho_max + float(joint_tolerance) + joint_width(model, tolerance))
    if tolerance.zero:
        return model
    return replace(model, l2=model.l2 + tolerance.offset_bound())
