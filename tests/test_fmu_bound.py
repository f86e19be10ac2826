"""The DK FMU's pose bound, trust and honest start (x_bound, y_bound, phi_bound, trust,
start_tolerance_linear/angular): equal to the in-process ``solver.Tracker`` with the same options on a
noisy encoder stream, kept by the FMU state, and the start tolerance checked like the other parameters.

Uses the DK FMU built by the fixtures of dk_fmu_support (reference configuration, 40 mm / 6 deg map).
"""
from __future__ import annotations

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Error

from experiments.sensors import Sensor
from fmu_src.dk_variables import NO_BOUND
from solver import Tracker

from dk_fmu_support import BOUND, H, MODEL, OUTPUTS, X0, Q
from dk_fmu_support import built, fmu, hygiene, make, map1, tmp, unzipdir  # noqa: F401 (fixtures)

SENSOR = Sensor("16", bits=16, noise=1e-4)
TOL = SENSOR.tolerance(3.0)
STREAM = SENSOR.measure(Q[:300], seed=1).q
NAMES = ("x", "y", "phi", "certain", "uncertain_since", *BOUND, "status")


def _start(stream=STREAM, **extra):
    return {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "q1": stream[0, 0], "q2": stream[0, 1], "q3": stream[0, 2],
            "joint_tolerance": TOL, **extra}


def _expected(tracker, X, certain, bound, trust, since, status):
    b = bound.tolist() if certain else [NO_BOUND] * 3
    return [*X.tolist(), bool(certain), since, *b, int(trust), int(status)]


def _tracker_run(map1, stream, start_tolerance=(0.01, 0.01, 0.05)):
    """The in-process tracker's values of NAMES at the start and after each sample (dt = H)."""
    tr = Tracker(MODEL, map1, joint_tolerance=TOL, start_tolerance=start_tolerance)
    start = tr.reset(X0, stream[0])
    since = None if start.certain else 0.0
    rows = [_expected(tr, tr.state.X, start.certain, start.pose_bound, 2 if start.certain else 0,
                      -1.0 if since is None else since, 0)]
    episode = None if start.certain else (0, 0.0)
    for k in range(1, len(stream)):
        X, info = tr.step(stream[k], dt=H)
        if info.certain:
            episode = None
        elif episode is None or episode[0] != info.uncertain_since:
            episode = (info.uncertain_since, k * H)
        rows.append(_expected(tr, X, info.certain, info.pose_bound, info.trust,
                              -1.0 if episode is None else episode[1], info.status))
    return start, rows


def _fmu_run(m, stream):
    rows = [m.get_values(NAMES)]
    for k in range(1, len(stream)):
        m.set_q(stream[k])
        m.fmu.doStep(m.t, H)
        m.t += H
        rows.append(m.get_values(NAMES))
    return rows


def test_bound_and_trust_equal_the_tracker_on_a_noisy_stream(make, map1):
    start, expected = _tracker_run(map1, STREAM)
    m = make(**_start())
    assert m.errors(least=1) == []
    # the inputs at t0 are noisy, not the joints of X0: the start is their DK solution near X0, proved
    assert start.certain and any("proved the robot's" in msg for _, msg in m.messages)
    rows = _fmu_run(m, STREAM)
    assert rows == expected
    certain = np.array([r[NAMES.index("certain")] for r in rows], dtype=bool)
    bounds = np.array([r[NAMES.index("x_bound"):NAMES.index("phi_bound") + 1] for r in rows])
    assert certain.mean() > 0.5                                 # mostly certain: a meaningful comparison
    assert np.all(bounds[certain] > 0) and np.all(bounds[certain] < 0.01)
    assert np.all(bounds[~certain] == NO_BOUND)
    trust = np.array([r[NAMES.index("trust")] for r in rows])
    assert np.all((trust == 2) == certain)


def test_an_uncertain_start_says_so(make, map1):
    # a start region so large that several DK solutions of q0 lie in it: not certain, no bound, trust lost
    # (the joints at t0 those of X0: the FMU starts at its inputs, as the tracker does)
    tol = (1.0, 1.0, 3.0)
    stream = np.concatenate([Q[:1], STREAM[1:60]])
    start, expected = _tracker_run(map1, stream, tol)
    assert not start.certain and "start_tolerance" in start.reason
    m = make(**_start(stream, start_tolerance_linear=1.0, start_tolerance_angular=3.0))
    assert any("the start is not certain" in msg for msg in m.errors(least=1))
    rows = _fmu_run(m, stream)
    assert rows[0][NAMES.index("certain"):NAMES.index("trust") + 1] == [False, 0.0, NO_BOUND, NO_BOUND, NO_BOUND, 0]
    assert rows == expected


def test_a_restored_state_gives_the_same_next_step_bound(make, map1):
    m = make(**_start())
    _fmu_run(m, STREAM[:120])
    state = m.fmu.getFMUstate()
    blob = m.fmu.serializeFMUstate(state)
    after = _fmu_run_from(m, STREAM[120:140])
    assert any(r[NAMES.index("certain")] for r in after)
    m.fmu.setFMUstate(state)
    m.t -= 20 * H
    assert _fmu_run_from(m, STREAM[120:140]) == after
    # in another instance, through serialize/deserialize
    other = make("other", **_start())
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(blob))
    other.t = 119 * H
    assert _fmu_run_from(other, STREAM[120:140]) == after
    m.fmu.freeFMUstate(state)


def _fmu_run_from(m, stream):
    rows = []
    for q in stream:
        m.set_q(q)
        m.fmu.doStep(m.t, H)
        m.t += H
        rows.append(m.get_values(NAMES))
    return rows


@pytest.mark.parametrize("name, value", [("start_tolerance_linear", 0.0), ("start_tolerance_linear", -0.01),
                                         ("start_tolerance_angular", 0.0), ("start_tolerance_angular", -1.0)])
def test_a_bad_start_tolerance_is_refused(fmu, unzipdir, name, value):
    """fmi2ExitInitializationMode returns fmi2Error with the reason; a doStep in state error too."""
    from cosim.unit import FMUUnit
    m = FMUUnit(fmu, "dk-bad-tolerance", unzip_dir=unzipdir, logging_on=True)
    try:
        with pytest.raises(FMICallException) as init:
            m.initialize(0.0, _start(**{name: value}))
        assert init.value.status == fmi2Error
        assert any(f"parameter {name!r} = {value!r}: expected a finite number > 0" in msg for msg in m.errors())
        assert m.get_values(["status"]) == [3]
        with pytest.raises(FMICallException) as info:
            m.fmu.doStep(0.0, H)
        assert info.value.status == fmi2Error
    finally:
        m.close()


def test_outputs_list_bound_and_trust():
    assert set(BOUND).isdisjoint(OUTPUTS)                        # the reference CSV's columns are unchanged
