"""The stuck-joint detector: a reading a noisy encoder repeats too often is not a measurement.

An encoder with white noise rarely reads exactly the same value twice in a row,
and almost never ``n`` times: a joint at rest repeats its reading with the
probability :func:`repeat_probability` (per sample).  A joint whose reading
repeats ``stuck_after - 1`` times in a row (``stuck_after`` identical readings)
is stuck, and so were the readings since the first repeat: the tracker rolls
back to its state before that reading (:attr:`TrackerState.clean`), refuses the
samples while the joint stays stuck (status ``rejected``, the pose held) and
takes the first reading that moves again as one step from the clean state, over
the whole time since (``skipped``).  The poses it gave out during the first
``stuck_after - 1`` repeated readings were computed from the stuck joint; the
state no longer depends on them.

The detector is off (``stuck_after = 0``) for exact joints: an exact joint at
rest repeats its value.  :meth:`solver.sensors.Sensor.stuck_after` chooses
``stuck_after`` for a sensor from its noise and resolution.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .tracker_state import TrackerState

__all__ = ["repeat_probability", "stuck_samples", "repeat_counts", "stuck_refusal", "reading_fields"]


_ERF = np.vectorize(math.erf, otypes=[float])


def _normal_cdf(x: np.ndarray) -> np.ndarray:
    """The standard normal distribution function (no scipy: the DK FMU carries this module)."""
    return 0.5 * (1.0 + _ERF(x / math.sqrt(2.0)))


def repeat_probability(noise: float, step: float) -> float:
    """Probability that two successive readings of a joint at rest are equal.

    Parameters
    ----------
    noise : float
        Standard deviation of the white noise, rad (> 0).
    step : float
        Encoder resolution, rad (0: none, readings are real numbers and never repeat).

    Returns
    -------
    float
        ``sum_k P(bin k)^2``, averaged over where the joint sits within its bin.
    """
    if step <= 0.0:
        return 0.0
    u = (np.arange(64) + 0.5) / 64.0 * step                     # the joint's offset within its bin
    k = np.arange(-int(np.ceil(8 * noise / step)) - 1, int(np.ceil(8 * noise / step)) + 2)
    edges = ((k[None, :] + 0.5) * step - u[:, None]) / noise
    p_bin = _normal_cdf(edges) - _normal_cdf(edges - step / noise)
    return float(np.mean(np.sum(p_bin ** 2, axis=1)))


def stuck_samples(noise: float, step: float, p_false: float = 1e-6) -> int:
    """Identical readings in a row that mark a joint stuck: a joint at rest gives as many with a
    probability at most ``p_false`` per sample.  0 (off) for exact joints (``noise == 0``)."""
    if noise <= 0.0:
        return 0
    p = repeat_probability(noise, step)
    if p <= 0.0:
        return 2
    return 1 + int(np.ceil(np.log(p_false) / np.log(p)))


_NO_REPEATS = np.zeros(3, dtype=np.int64)
_NO_REPEATS.setflags(write=False)


def repeat_counts(state: TrackerState, q: np.ndarray) -> np.ndarray:
    """Readings in a row each joint of ``q`` (3,) repeats, counting this one: (3,) ints."""
    if state.reading is None:
        return _NO_REPEATS
    same = q == state.reading
    if not same.any():
        return _NO_REPEATS
    return np.where(same, state.repeats + 1, 0)


def _later(seconds: float, dt: float | None) -> float:
    """``seconds`` plus a sample's ``dt`` (NaN when the sample came without one)."""
    return seconds + dt if dt is not None else float("nan")


def stuck_refusal(state: TrackerState, q: np.ndarray, repeats: np.ndarray, stuck_after: int,
                  dt: float | None = None) -> TrackerState | None:
    """The state after refusing ``q``, read ``dt`` seconds after the last reading (None: unknown), as
    a stuck reading, or None when no joint is stuck.

    The state is the clean one (before the first repeated reading), with the samples since
    counted as skipped (and their seconds), so that the next accepted sample is one step over the
    whole time.
    """
    if stuck_after <= 0 or repeats is _NO_REPEATS or int(repeats.max()) < stuck_after - 1:
        return None
    base = state.clean if state.clean is not None else state
    lag = state.clean_lag + 1 if state.clean is not None else 1
    lag_s = _later(state.clean_time if state.clean is not None else 0.0, dt)
    return replace(base, skipped=base.skipped + lag, skipped_time=base.skipped_time + lag_s, reading=q.copy(),
                   repeats=repeats, clean=base, clean_lag=lag, clean_time=lag_s)


def reading_fields(before: TrackerState, q: np.ndarray, repeats: np.ndarray, dt: float | None = None) -> dict:
    """The detector's fields of the state a step makes from ``before`` on reading ``q``, ``dt`` seconds
    after the last reading (``reading``, ``repeats``, ``clean``, ``clean_lag``, ``clean_time``:
    :class:`TrackerState`)."""
    if repeats is _NO_REPEATS:
        return {"reading": q.copy(), "repeats": repeats, "clean": None, "clean_lag": 0, "clean_time": 0.0}
    if before.clean is None or int(repeats.max()) == 1:
        # a run starts here (and every run still going started here): clean is the state before it.
        # A run that started earlier while another one ended keeps the older clean (a rollback then
        # goes a sample or two further back than needed)
        # (without the walk of an unfinished proof: a saved state's clean has none either)
        return {"reading": q.copy(), "repeats": repeats, "clean": replace(before, clean=None, walk=None),
                "clean_lag": 1, "clean_time": _later(0.0, dt)}
    return {"reading": q.copy(), "repeats": repeats, "clean": before.clean, "clean_lag": before.clean_lag + 1,
            "clean_time": _later(before.clean_time, dt)}
