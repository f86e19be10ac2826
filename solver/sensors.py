"""Joint encoders: how far a measured joint can be from the true one, and when a reading is stuck.

A :class:`Sensor` is an encoder model for the three joints: ``bits`` per turn (the reading
is on a grid of ``2 pi / 2**bits`` rad) and white noise of standard deviation ``noise``
(rad) before quantization.  It answers the two numbers the tracker needs on measured joints::

    from solver.sensors import Sensor
    enc = Sensor("12-bit", bits=12, noise=1e-3)
    tracker = Tracker(model, cached_map(model, 1), joint_tolerance=enc.tolerance(3.0),
                      stuck_after=enc.stuck_after())

Streams of such readings with glitches (outliers, stuck joints, dropouts) and the truth to
score them against are experiments: ``experiments.sensors``.  Nothing in the tracker imports
this module.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import SolverInputError
from .stuck import stuck_samples

__all__ = ["Sensor", "quantize"]


def quantize(q, bits: int) -> np.ndarray:
    """Joints rounded to an encoder grid.

    Parameters
    ----------
    q : array_like, shape (..., 3)
        Joints, rad.
    bits : int
        Bits per turn, 1..52: the grid step is ``2 pi / 2**bits`` rad.

    Returns
    -------
    ndarray, shape of ``q``
        The nearest grid values, rad.
    """
    if not (isinstance(bits, (int, np.integer)) and 1 <= bits <= 52):
        raise SolverInputError(f"bits: expected an integer number of bits per turn in 1..52, got {bits!r}")
    res = 2.0 * np.pi / 2.0 ** int(bits)
    return np.round(np.asarray(q, dtype=float) / res) * res


@dataclass(frozen=True)
class Sensor:
    """An encoder model for the three joints.

    Parameters
    ----------
    name : str
    bits : int or None
        Bits per turn of the encoder; None for no quantization.
    noise : float
        Standard deviation of the white noise added before quantization (rad).
    """

    name: str
    bits: int | None = None
    noise: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.noise) and self.noise >= 0.0):
            raise SolverInputError(f"noise: expected a standard deviation >= 0 in rad, got {self.noise!r}")
        if self.bits is not None:
            quantize(0.0, self.bits)                                   # checks bits

    @property
    def resolution(self) -> float:
        """The encoder step, rad (0 without quantization)."""
        return 0.0 if self.bits is None else 2.0 * np.pi / 2.0 ** self.bits

    def tolerance(self, sigmas: float = 5.0) -> float:
        """A bound on this sensor's error (rad): ``sigmas`` standard deviations of its noise plus half
        an encoder step; what to pass as the tracker's ``joint_tolerance`` (0 for exact joints)."""
        return sigmas * self.noise + 0.5 * self.resolution

    def stuck_after(self, p_false: float = 1e-6) -> int:
        """Identical readings in a row after which a joint of this sensor is stuck: a joint at rest
        gives as many with a probability at most ``p_false`` per sample; 0 (off) for exact joints.
        What to pass as the tracker's ``stuck_after`` (:mod:`solver.stuck`)."""
        return stuck_samples(self.noise, self.resolution, p_false)
