"""The explicit data of the dynamics kernels: the packs of a model, parameters, gains and a circle.

Each ``*_pack(obj)`` derives the flat float64 array a compiled kernel reads
(:mod:`dynamics._kernels.layout`) from one frozen object and is cached per object
(:func:`solver.identity_cache.by_identity`: built on first use, kept beside the object
while it lives, never stored on it).  The public functions look the packs up at every call
(a dictionary hit); the FMU steppers concatenate them once, at initialization.
"""
from __future__ import annotations

import numpy as np

from solver.identity_cache import by_identity

from ._kernels.layout import pack_arm, pack_bodies, pack_circle, pack_gains
from .parameters import row_constants

__all__ = ["arm_pack", "bodies_pack", "gains_pack", "circle_pack"]


@by_identity
def arm_pack(model) -> np.ndarray:
    """The ``arm`` pack (18,) of a :class:`solver.Manipulator`: motors, ``l1``, ``l2``, platform joints."""
    return pack_arm(model.motors, model.l1, model.l2, model.platform)


@by_identity
def bodies_pack(params) -> np.ndarray:
    """The ``bodies`` pack (40,) of a :class:`dynamics.DynamicParameters`."""
    c = row_constants(params)
    return pack_bodies(params.com_proximal, params.com_distal, c["w"], c["b"], params.gravity, params.com_platform)


@by_identity
def gains_pack(gains) -> np.ndarray:
    """The ``gains`` pack (6,) of a :class:`dynamics.ComputedTorqueGains`: ``kp`` then ``kd``."""
    return pack_gains(gains.kp, gains.kd)


@by_identity
def circle_pack(trajectory) -> np.ndarray:
    """The ``circle`` pack (7,) of a :class:`dynamics.CircleTrajectory`."""
    return pack_circle(trajectory.center, trajectory.radius, trajectory.phi, trajectory.angular_speed,
                       trajectory.ramp_time, trajectory.start)
