"""The honest start says when it is not proved (solver.start.UncertainStartWarning)."""
from __future__ import annotations

import numpy as np
import pytest

from solver import Manipulator, Tracker, cached_map, ik

PAPER = Manipulator.paper()


def ellipse(n=10, centre=(0.5, 0.2887), a=0.1, b=0.08, phi=0.2):
    t = np.linspace(0, 2 * np.pi, n)
    return np.stack([centre[0] + a * np.cos(t), centre[1] + b * np.sin(t), phi * np.sin(2 * t)], -1)


def test_an_unproved_start_warns_with_the_reason_and_a_proved_one_does_not():
    """A start tolerance holding several DK solutions is not proved and
    warns (UncertainStartWarning, a UserWarning) with StartInfo.reason; warn=False only records it."""
    import warnings

    from solver import UncertainStartWarning

    mt = cached_map(PAPER, 1)
    X = ellipse(10)
    q = ik(PAPER, X, 1)
    wide = Tracker(PAPER, mt, start_tolerance=(0.5, 0.5, 3.0))
    with pytest.warns(UncertainStartWarning) as caught:
        start = wide.reset(X[0], q[0])
    assert not start.certain and start.reason and start.reason in str(caught[0].message)
    assert issubclass(UncertainStartWarning, UserWarning)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not wide.reset(X[0], q[0], warn=False).certain
        assert Tracker(PAPER, mt, start_tolerance=(1e-3, 1e-3, 5e-3)).reset(X[0], q[0]).certain
