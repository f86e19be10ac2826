"""Tool-space paths shared by the experiments, the FMU reference run and the dynamics.

The paper's circle (section 5, Fig. 16) is "a circular path in the tool space
discretised into 1000 points"; the paper gives no centre or radius.  We use a
circle of posture 1 at constant orientation that crosses basic-region borders
(the number of real DK solutions changes along it, so does the label of the
true solution) while staying clear of singularities: min type-1 measure 0.168,
min type-2 measure > 0.1 (chosen by a scan over centres, radii and phi; see the
README).
"""
from __future__ import annotations

import numpy as np

from .checks import SolverInputError

#: The circle of the experiments: centre (m), radius (m), constant phi (rad), posture.
PAPER_CIRCLE = {"center": (0.45, 0.30), "radius": 0.25, "phi": float(np.deg2rad(-45.0)), "posture": 1}


def circle_path(n: int = 1000, center=PAPER_CIRCLE["center"], radius: float = PAPER_CIRCLE["radius"],
                phi: float = PAPER_CIRCLE["phi"], start: float = 0.0) -> np.ndarray:
    """Points of a discretised circle in the tool space (paper Fig. 16).

    Parameters
    ----------
    n : int
        Number of points (the paper uses 1000); the circle is closed, the last
        point is one step before the first.
    center : (float, float)
        Centre, m.
    radius : float
        Radius, m.
    phi : float
        Constant platform orientation, rad.
    start : float
        Polar angle of the first point, rad (counter-clockwise from +x).

    Returns
    -------
    ndarray, shape (n, 3)
        Poses ``(x, y, phi)``, m, m, rad.
    """
    if not (isinstance(n, (int, np.integer)) and n >= 3):
        raise SolverInputError(f"n: expected an integer >= 3, got {n!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise SolverInputError(f"radius: expected a positive length in m, got {radius!r}")
    th = start + 2.0 * np.pi * np.arange(n) / n
    c = np.asarray(center, dtype=float)
    return np.column_stack([c[0] + radius * np.cos(th), c[1] + radius * np.sin(th), np.full(n, float(phi))])
