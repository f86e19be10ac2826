"""Joint sensors as a controller gets them: quantized, noisy and glitching joint streams.

:class:`Sensor` is the library's encoder model (:class:`solver.sensors.Sensor`: bits per
turn, noise, the tracker's tolerance and stuck threshold) that also reads streams: it turns
the exact joints of a suite path into what encoders deliver, deterministically from a seed:

* white noise of standard deviation ``noise`` (rad) on every joint, then
  quantization to ``bits`` bits per turn (the reading is always on the
  encoder's grid, ``2 pi / 2**bits`` rad);
* glitches on top of that, ``n_glitches`` per stream at seeded positions:
  ``"outlier"`` (one joint jumps by ``outlier`` rad for one sample),
  ``"stuck"`` (one joint repeats its value for ``stuck`` samples) or
  ``"dropout"`` (one sample of NaN on one joint).

:func:`sensor_truth` says what the right answer is on such a stream: the real
DK solution of the *measured* joints nearest to the noise-free pose, counted
only where it is clearly nearest (the second nearest at least ``factor`` times
farther, eq. 19 distance) and the sample is not a glitch.  The grades of the
benchmark (``bench/bench_sensors.py``) are :data:`SENSOR_GRADES`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver import sensors as encoder
from solver.checks import SolverInputError, as_array
from solver.direct_kinematics import dk_all
from solver.kinematics import wrap_angle
from solver.manipulator import Manipulator
from solver.sensors import quantize

__all__ = ["Sensor", "SensorStream", "SENSOR_GRADES", "GLITCHES", "sensor_truth", "TRUTH_FACTOR"]

GLITCHES = ("outlier", "stuck", "dropout")
#: The second nearest real solution must be this many times farther than the nearest for a step to count.
TRUTH_FACTOR = 3.0


@dataclass(frozen=True)
class SensorStream:
    """A measured joint stream.

    Attributes
    ----------
    q : ndarray, shape (n, 3)
        Measured joints (rad); NaN where a sample dropped out.
    glitch : ndarray of bool, shape (n,)
        Samples that a glitch made (the outlier sample, the repeated samples of a
        stuck joint, the dropout); they are not measurements of the robot.
    """

    q: np.ndarray
    glitch: np.ndarray


@dataclass(frozen=True)
class Sensor(encoder.Sensor):
    """The library's encoder model (:class:`solver.sensors.Sensor`) with glitches, and the streams it reads.

    Parameters
    ----------
    name, bits, noise
        As in :class:`solver.sensors.Sensor`.
    glitch : {None, "outlier", "stuck", "dropout"}
    n_glitches : int
        Glitches per stream, spread over it at seeded positions.
    outlier : float
        Size of an outlier's jump (rad).
    stuck : int
        Samples a stuck joint repeats its value.
    """

    glitch: str | None = None
    n_glitches: int = 5
    outlier: float = 0.1
    stuck: int = 20

    def __post_init__(self):
        if self.glitch is not None and self.glitch not in GLITCHES:
            raise SolverInputError(f"glitch: expected None or one of {GLITCHES}, got {self.glitch!r}")
        super().__post_init__()

    def measure(self, q, seed: int) -> SensorStream:
        """The stream this sensor reads from the exact joints ``q`` (n, 3), rad; deterministic in ``seed``."""
        q = as_array("q", q, (3,))
        if q.ndim != 2:
            raise SolverInputError(f"q: expected shape (n, 3), got {q.shape}")
        rng = np.random.default_rng(seed)
        n = len(q)
        m = q + self.noise * rng.standard_normal(q.shape) if self.noise > 0 else q.copy()
        if self.bits is not None:
            m = quantize(m, self.bits)
        glitch = np.zeros(n, dtype=bool)
        if self.glitch is not None:
            span = self.stuck if self.glitch == "stuck" else 1
            for k in self._positions(n, span, rng):
                j = int(rng.integers(3))
                if self.glitch == "outlier":
                    m[k, j] += self.outlier * (1.0 if rng.random() < 0.5 else -1.0)
                    glitch[k] = True
                elif self.glitch == "dropout":
                    m[k, j] = np.nan
                    glitch[k] = True
                else:
                    m[k + 1:k + span + 1, j] = m[k, j]
                    glitch[k + 1:k + span + 1] = True
        return SensorStream(m, glitch)

    def _positions(self, n, span, rng):
        """Start samples of the glitches: one per equal slice of the stream (after its first 3 samples)."""
        slots = min(self.n_glitches, (n - 3) // (span + 3))
        if slots <= 0:
            return []
        edges = np.linspace(3, n - span - 1, slots + 1).astype(int)
        return [int(rng.integers(edges[i], max(edges[i] + 1, edges[i + 1] - span - 2))) for i in range(slots)]


#: The grades of the benchmark: exact joints; realistic encoders (20 bits per turn with 2e-5 rad of
#: noise, 16 bits with 1e-4 rad, 16 and 12 bits without noise); harsh ones (16, 14 and 12 bits with
#: 1e-3 rad of noise); and each glitch on top of a 14-bit encoder with that noise.
SENSOR_GRADES = (
    Sensor("exact"),
    Sensor("20-bit-2e-5", bits=20, noise=2e-5),       # realistic industrial encoders
    Sensor("16-bit-1e-4", bits=16, noise=1e-4),
    Sensor("16-bit-exact", bits=16),                  # quantization only
    Sensor("12-bit-exact", bits=12),
    Sensor("16-bit", bits=16, noise=1e-3),            # harsh: 1 mrad of noise
    Sensor("14-bit", bits=14, noise=1e-3),
    Sensor("12-bit", bits=12, noise=1e-3),
    Sensor("outlier", bits=14, noise=1e-3, glitch="outlier"),
    Sensor("stuck", bits=14, noise=1e-3, glitch="stuck"),
    Sensor("dropout", bits=14, noise=1e-3, glitch="dropout"),
)


def sensor_truth(model: Manipulator, q_measured, X_true, glitch=None, factor: float = TRUTH_FACTOR):
    """The right pose on a measured stream, and where it is unmistakable.

    Parameters
    ----------
    model : Manipulator
    q_measured : array_like, shape (n, 3)
        Measured joints (rad); NaN samples are never counted.
    X_true : array_like, shape (n, 3)
        Noise-free poses (m, m, rad).
    glitch : array_like of bool, shape (n,), optional
        Samples not to count.
    factor : float
        The second nearest real solution must be ``factor`` times farther.

    Returns
    -------
    X : ndarray, shape (n, 3)
        The real DK solution of ``q_measured`` nearest to ``X_true`` (NaN where none).
    counted : ndarray of bool, shape (n,)
    """
    q = as_array("q_measured", q_measured, (3,), finite=False)
    X_true = as_array("X_true", X_true, (3,))
    if q.shape != X_true.shape or q.ndim != 2:
        raise SolverInputError(f"q_measured, X_true: expected two arrays (n, 3), got {q.shape} and {X_true.shape}")
    n = len(q)
    ok = np.isfinite(q).all(axis=1)
    X = np.full((n, 3), np.nan)
    counted = np.zeros(n, dtype=bool)
    if ok.any():
        sol = dk_all(model, q[ok])
        w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])
        d = sol.poses.real - X_true[ok][:, None, :]
        d[..., 2] = wrap_angle(d[..., 2])
        dist = np.where(sol.real, np.sqrt(np.sum(w * d * d, axis=-1)), np.inf)
        order = np.argsort(dist, axis=1)
        best, second = order[:, 0], order[:, 1]
        rows = np.arange(len(best))
        d1, d2 = dist[rows, best], dist[rows, second]
        X[ok] = np.where(np.isfinite(d1)[:, None], sol.poses.real[rows, best], np.nan)
        counted[ok] = np.isfinite(d1) & (d2 >= factor * d1)
    if glitch is not None:
        counted &= ~np.asarray(glitch, dtype=bool)
    return X, counted
