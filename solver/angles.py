"""The angle wrap of the numpy side (the compiled kernels' twin is :func:`solver._kernels.linalg.wrap`)."""
from __future__ import annotations

import numpy as np

__all__ = ["wrap_angle"]


def wrap_angle(a):
    """Angles wrapped to (-pi, pi], elementwise.

    Parameters
    ----------
    a : float or array_like
        Angles, rad.

    Returns
    -------
    float or ndarray
        ``pi - mod(pi - a, 2 pi)`` (numpy's ``mod``, the sign of the divisor), rad, the shape of ``a``.
    """
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)
