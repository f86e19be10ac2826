"""Joints on an encoder grid: readings, not exact joints.

A tracker left at ``joint_tolerance = 0`` vouches for the branch along the joints it is given.  When
those joints are readings of an encoder (integer multiples of ``2 pi / 2**B``), the robot's joints
are anywhere within half a step of them, and near a fold a proof about the readings vouches for a
branch the robot is not on.  :class:`solver.Tracker` therefore checks the joints of a :meth:`reset`
and, after a reset at joints off any grid, the first few readings (:data:`solver.tracker.GRID_WATCH`):
joints on a grid make it take half a step as its tolerance (:func:`grid_tolerance`) and say so
(:func:`encoder_note`).  Measured in ``docs/sensors.md``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MIN_ENCODER_BITS", "MAX_ENCODER_BITS", "encoder_bits", "grid_tolerance", "encoder_note"]

#: Encoders of MIN_ENCODER_BITS to MAX_ENCODER_BITS bits per turn are recognised from their readings
#: (:func:`encoder_bits`).
MIN_ENCODER_BITS, MAX_ENCODER_BITS = 8, 24


def encoder_bits(q) -> int | None:
    """The bits per turn of the encoder grid the joints ``q`` (3,) (rad) lie on, or None.

    Readings of a ``B``-bit encoder are integer multiples of ``2 pi / 2**B``; joints that are all
    such multiples for some ``B <= MAX_ENCODER_BITS`` (the smallest is returned, at least
    ``MIN_ENCODER_BITS``: joints on a coarser grid, such as 0 or pi / 2, are set by hand) are taken
    as encoder readings.  Joints computed in floating point (inverse kinematics, a simulation) land
    on such a grid with a probability of about ``1e-8``.
    """
    q = np.asarray(q, dtype=float)
    for bits in range(1, MAX_ENCODER_BITS + 1):
        k = q * (2.0 ** bits / (2.0 * np.pi))
        if np.all(np.abs(k - np.round(k)) <= 1e-9 * np.maximum(1.0, np.abs(k))):
            # joints on a grid coarser than MIN_ENCODER_BITS (0, pi / 2, ...) are set by hand, not read
            return bits if bits >= MIN_ENCODER_BITS else None
    return None


def encoder_note(what: str, bits: int, tol: float, speed_bound) -> str:
    """What a tracker with ``joint_tolerance = 0`` says when ``what`` (joints) lies on a ``bits``-bit
    encoder grid and it takes ``tol`` (rad, half a step) as its tolerance: why, and what to set."""
    note = (f"{what} lies on a {bits}-bit encoder grid (2 pi / 2**{bits} rad): readings, not exact joints; "
            f"joint_tolerance = 0 would vouch for the branch along the readings, so the tracker takes half "
            f"a step, joint_tolerance = {tol:.3g} rad (pass joint_tolerance, e.g. Sensor.tolerance(), to choose)")
    if speed_bound is None:
        note += ("; with readings and no speed_bound, certainty lost near a singularity seldom comes back "
                 "(re-acquisition would have to rule out every other pose of the tool space): pass "
                 "speed_bound=(m/s, rad/s), a bound on the platform's speed (solver.sensors.speed_bound of the "
                 "planned motion gives one)")
    return note


def grid_tolerance(bits: int) -> float:
    """Half a step of a ``bits``-bit encoder (rad), rounded up by a relative 1e-9 so that a reading's
    own rounding stays inside it."""
    return float(np.pi / 2.0 ** bits) * (1.0 + 1e-9)
