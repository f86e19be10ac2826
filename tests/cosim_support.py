"""Shared by the tests that run the closed loop (test_cosim.py, test_fmu_speed_paths.py): the three
FMUs built per test module with a coarse map (40 mm / 6 deg) and a ClosedLoop on them; a test module
imports the fixtures by name."""
from __future__ import annotations

import numpy as np
import pytest

from cosim import ClosedLoop, build_fmus
from cosim.unit import import_hygiene


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmus")
    return build_fmus(out, resolution=(0.04, float(np.deg2rad(6.0))), log=lambda *a: None)


@pytest.fixture(scope="module")
def loop(fmus):
    with import_hygiene(), ClosedLoop(fmus) as cl:
        yield cl
