"""Joint encoders: how far a measured joint can be from the true one, and when a reading is stuck.

A :class:`Sensor` is an encoder model for the three joints: ``bits`` per turn (the reading
is on a grid of ``2 pi / 2**bits`` rad) and white noise of standard deviation ``noise``
(rad) before quantization.  It answers two of the numbers the tracker needs on measured joints;
:func:`speed_bound` gives the third from the planned motion::

    from solver.sensors import Sensor, speed_bound
    enc = Sensor("12-bit", bits=12, noise=1e-3)
    tracker = Tracker(model, cached_map(model, 1), joint_tolerance=enc.tolerance(3.0),
                      speed_bound=speed_bound(X_planned, 1e-3), stuck_after=enc.stuck_after())

Streams of such readings with glitches (outliers, stuck joints, dropouts) and the truth to
score them against are experiments: ``experiments.sensors``.  Nothing in the tracker imports
this module.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .angles import wrap_angle
from .checks import SolverInputError, as_array
from .stuck import stuck_samples

__all__ = ["Sensor", "quantize", "speed_bound"]


def speed_bound(X, dt: float, margin: float = 1.25, min_linear: float = 0.01,
                min_angular: float = 0.5) -> tuple[float, float]:
    """A bound on the platform's speed from its planned motion: the tracker's ``speed_bound``.

    The tracker's set-membership paving and re-acquisition search the poses the platform can have
    reached since its last certain step, so the tighter the bound the sooner certainty comes back
    after an ill-conditioned stretch (``docs/sensors.md``); a bound the robot exceeds voids the
    proofs.  A controller that planned the motion knows its fastest speeds; ``margin`` covers the
    tracking error.

    Parameters
    ----------
    X : array_like, shape (n, 3)
        Planned poses (m, m, rad), ``n >= 2``, ``dt`` apart.
    dt : float
        Time between two poses, s (> 0).
    margin : float
        Factor on the fastest planned speeds (>= 1).
    min_linear : float
        Least linear bound, m/s (> 0): a plan that holds the platform still still moves it a little
        (the tracker needs both bounds > 0).
    min_angular : float
        Least angular bound, rad/s (> 0): a plan whose orientation is constant still turns a little.

    Returns
    -------
    (float, float)
        ``margin`` times the fastest linear speed (m/s, at least ``min_linear``) and angular speed
        (rad/s, at least ``min_angular``) between consecutive poses.
    """
    X = as_array("X", X, (3,))
    if X.ndim != 2 or len(X) < 2:
        raise SolverInputError(f"X: expected planned poses of shape (n, 3) with n >= 2, got shape {X.shape}")
    for name, val, least, strict in (("dt", dt, 0, True), ("margin", margin, 1, False),
                                     ("min_linear", min_linear, 0, True), ("min_angular", min_angular, 0, True)):
        if (isinstance(val, (bool, np.bool_)) or not isinstance(val, (int, float, np.integer, np.floating))
                or not np.isfinite(val) or (val <= least if strict else val < least)):
            raise SolverInputError(f"{name}: expected a number {'>' if strict else '>='} {least}, got {val!r}")
    d = np.diff(X, axis=0)
    v = float(np.max(np.hypot(d[:, 0], d[:, 1]))) / float(dt)
    w = float(np.max(np.abs(wrap_angle(d[:, 2])))) / float(dt)
    bound = (max(float(margin) * v, float(min_linear)), max(float(margin) * w, float(min_angular)))
    if not all(np.isfinite(bound)):
        raise SolverInputError(f"X, dt: the planned speeds are not finite (dt = {dt!r}), got {bound}")
    return bound


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
