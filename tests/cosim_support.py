"""Shared by the tests that run the closed loop (test_cosim.py, test_fmu_speed_paths.py, test_fast_lane.py,
test_shared_kernels.py): the session's three FMUs (coarse map, 40 mm / 6 deg; built once per session by
:func:`host_support.session_fmus`, which the hosts' tests share) and a ClosedLoop on them; a test module
imports the fixtures by name."""
from __future__ import annotations

import pytest

from cosim import ClosedLoop
from cosim.unit import import_hygiene
from host_support import session_fmus


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def loop(fmus):
    with import_hygiene(), ClosedLoop(fmus) as cl:
        yield cl
