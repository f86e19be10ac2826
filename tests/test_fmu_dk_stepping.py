"""The direct-kinematics FMU stepped through fmpy's FMU2Slave (the shared driver cosim.unit.FMUUnit):
independent instances, FMU state, reset, direct feedthrough, initialization, bad input, certainty.

Built once per module like test_fmu_dk.py (tests/dk_fmu_support.py) and compared with the in-process
``solver.Tracker``.
"""
from __future__ import annotations

import logging
import math

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error, fmi2Fatal, fmi2LastSuccessfulTime, fmi2Terminated

from cosim.simulation import StepRefusedError, input_table, simulate
from solver import STATUS, Tracker, ik

from dk_fmu_support import CERTAINTY, H, MODEL, OUTPUTS, PATH, X0, Q, circle_start, tracker_rows
from dk_fmu_support import built, fmu, hygiene, make, map1, tmp, unzipdir  # noqa: F401 (fixtures)


# ---------------------------------------------------------------------- FMU2Slave semantics
def test_two_instances_in_one_process_are_independent(make, map1):
    reverse = Q[::-1]
    a = make("a", **circle_start())
    b = make("b", x0=PATH[-1][0], y0=PATH[-1][1], phi0=PATH[-1][2], q1=reverse[0][0], q2=reverse[0][1],
             q3=reverse[0][2], mode=1)
    rows_a, rows_b = [], []
    for k in range(400):
        rows_a.append(a.step(Q[k]))
        rows_b.append(b.step(reverse[k]))
    assert rows_a == tracker_rows(map1, Q[:400])
    assert rows_b == tracker_rows(map1, reverse[:400], X_start=PATH[-1], mode="paper")


def test_state_round_trip_is_bit_for_bit(make, map1):
    m = make(**circle_start())
    for k in range(300):
        m.step(Q[k])
    state = m.fmu.getFMUstate()
    blob = m.fmu.serializeFMUstate(state)
    first = [m.step(Q[k]) for k in range(300, 700)]
    m.fmu.setFMUstate(state)
    m.t = 300 * H
    assert [m.step(Q[k]) for k in range(300, 700)] == first
    m.fmu.freeFMUstate(state)
    # a serialized state continues identically in another instance (of other parameters)
    other = make("other", mode=1)
    restored = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(restored)
    other.fmu.freeFMUstate(restored)
    other.t = 300 * H
    assert [other.step(Q[k]) for k in range(300, 700)] == first
    assert first == tracker_rows(map1, Q[:700])[300:]


def test_a_saved_state_keeps_the_unfinished_proof(make, map1):
    """step_budget_share tiny: the first steps have no time for a proof (out_of_budget, not certain) and
    leave the walk unfinished.  The FMU state saved then, restored into another instance, goes on: given
    time (a longer communication step: the budget is the share of it), both close the proof at the same
    step, certain, with the same outputs, and the pose is the unbudgeted tracker's."""
    start = dict(circle_start(), step_budget_share=1e-4)             # 100 ns at h = 1 ms
    a = make("a", **start)
    for k in range(3):
        a.step(Q[k])
        assert a.get_values(["certain", "out_of_budget"]) == [False, True]
    state = a.fmu.getFMUstate()
    blob = a.fmu.serializeFMUstate(state)
    a.fmu.freeFMUstate(state)
    b = make("b", **start)
    restored = b.fmu.deSerializeFMUstate(blob)
    b.fmu.setFMUstate(restored)
    b.fmu.freeFMUstate(restored)
    rows = []
    for m in (a, b):
        m.set_q(Q[3])
        m.fmu.doStep(a.t, 10.0)                                       # a budget of 1 ms
        rows.append((m.outputs(), m.get_values(["certain", "out_of_budget"])))
    assert rows[0] == rows[1] and rows[0][1] == [True, False]
    assert rows[0][0][:3] == tracker_rows(map1, Q[:4])[3][:3]


def test_reset_returns_to_the_initial_pose(make, map1):
    m = make(**circle_start())
    initial = m.outputs()
    first = [m.step(q) for q in Q[:200]]
    m.fmu.reset()
    m.initialize(**circle_start())
    # the honest start's pose: the DK solution of q[0] near X0 (X0 within rounding)
    assert m.outputs() == initial and initial[:3] == tuple(Tracker(MODEL, map1).reset(X0, Q[0]).X)
    assert [m.step(q) for q in Q[:200]] == first


def test_outputs_before_the_first_step_and_direct_feedthrough(make, map1):
    m = make(**circle_start())
    initial = m.outputs()
    # the initial pose before any doStep: the honest start's, the DK solution of q[0] near X0
    assert initial[:3] == tuple(Tracker(MODEL, map1).reset(X0, Q[0]).X)
    assert np.abs(np.array(initial[:3]) - X0).max() < 1e-12
    # setting q without doStep: the outputs are the pose for that q (declared dependencies on q1..q3) ...
    m.set_q(Q[5])
    ahead = m.outputs()
    tr = Tracker(MODEL, map1)
    tr.reset(X0, Q[0])
    X5, info5 = tr.step(Q[5])
    assert ahead[:3] == tuple(X5) and ahead[3] == info5.label
    # ... but the tracker state does not advance: back to q[0] gives the initial outputs again
    m.set_q(Q[0])
    assert m.outputs() == initial
    # doStep after such a get gives the same answer as without it
    m.set_q(Q[5])
    m.outputs()
    m.fmu.doStep(0.0, H)
    assert m.outputs() == ahead
    m.t = H
    assert [m.step(Q[k]) for k in range(6, 40)] == tracker_rows(map1, [Q[5], *Q[6:40]], q_start=Q[0])[1:]


def test_inconsistent_initial_joints_warn_and_start_from_the_ik(make, map1):
    # x0, y0, phi0 of the circle's first point, q1..q3 left at their start values (the home pose's joints)
    m = make(x0=X0[0], y0=X0[1], phi0=X0[2])
    warnings = [msg for s, msg in m.messages if s == 1]
    assert len(warnings) == 1 and "not the joints of the initial pose" in warnings[0] and "q1" in warnings[0]
    # the tracker started from ik(X0); before the first step the outputs are the pose for the current q
    m.set_q(Q[0])
    assert m.outputs()[:3] == pytest.approx(tuple(X0), abs=1e-12)
    assert [m.step(q) for q in Q[:100]] == tracker_rows(map1, Q[:100], q_start=ik(MODEL, X0, 1))


# ---------------------------------------------------------------------- bad input
def _refused_initialization(fmu, unzipdir, **start):
    """An instance whose fmi2ExitInitializationMode returned fmi2Error (state error), and its messages."""
    from cosim.unit import FMUUnit
    unit = FMUUnit(fmu, "dk-refused", unzip_dir=unzipdir, logging_on=True)
    with pytest.raises(FMICallException) as init:
        unit.initialize(0.0, start)
    assert init.value.status == fmi2Error
    return unit


def test_initial_pose_outside_the_tool_space(fmu, unzipdir):
    m = _refused_initialization(fmu, unzipdir, x0=5.0)
    try:
        assert any("outside the tool space of posture 1" in msg for msg in m.errors())
        assert m.get_values(OUTPUTS)[OUTPUTS.index("status")] == 3
        with pytest.raises(FMICallException) as info:
            m.fmu.doStep(0.0, H)
        assert info.value.status == fmi2Error and not [msg for s, msg in m.messages if s >= fmi2Fatal]
    finally:
        m.close()


@pytest.mark.parametrize("name, value", [("q1", math.nan), ("q2", math.inf), ("q3", -math.inf)])
def test_non_finite_input_refuses_the_step(make, map1, caplog, name, value):
    m = make(**circle_start())
    for k in range(50):
        m.step(Q[k])
    before = m.outputs()
    state = m.fmu.getFMUstate()
    bad = dict(zip(("q1", "q2", "q3"), Q[50])) | {name: value}
    m.set(**bad)
    with pytest.raises(FMICallException) as info:
        m.fmu.doStep(m.t, H)
    assert info.value.status == fmi2Discard                   # the step was not made (FMI 2.0), never fmi2Fatal
    text = f"'{name}' = {value!r}"
    assert any(text in msg and "refused" in msg for msg in m.errors())          # FMI logger
    assert any(text in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)   # Python logging
    assert not [msg for s, msg in m.messages if s >= fmi2Fatal]
    assert m.fmu.getBooleanStatus(fmi2Terminated) is True                       # pythonfmu: sticky flag
    assert m.fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(m.t)
    # the pose of the last good step is kept; status says the step was rejected
    after = m.outputs()
    assert after[:3] == before[:3] and after[OUTPUTS.index("status")] == 3 and STATUS[3] == "rejected"
    expected = tracker_rows(map1, Q[:120])
    # now in state stepFailed: FMI 2.0 forbids fmi2SetReal and fmi2DoStep there (refused by the FMU's
    # loader with fmi2Error, the call and the state named, nothing changed)
    with pytest.raises(FMICallException) as again:
        m.step(Q[50])
    assert again.value.status == fmi2Error
    assert any("fmi2SetReal refused in state stepFailed" in msg for msg in m.errors())
    with pytest.raises(FMICallException) as again:
        m.fmu.doStep(m.t, H)
    assert again.value.status == fmi2Error
    assert any("fmi2DoStep refused in state stepFailed" in msg for msg in m.errors())
    assert m.outputs()[:3] == before[:3]
    # roll back with setFMUstate and continue: as if the bad step never was
    m.fmu.setFMUstate(state)
    m.fmu.freeFMUstate(state)
    m.t = 50 * H
    assert m.outputs() == before
    assert [m.step(Q[k]) for k in range(50, 120)] == expected[50:]


def test_simulate_fmu_with_a_bad_input_table(fmu, caplog):
    n = 100
    q = Q[:n].copy()
    q[60, 1] = math.nan
    table = input_table(np.arange(n) * H, q1=q[:, 0], q2=q[:, 1], q3=q[:, 2])
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2]}
    # plain fmpy: fmi2Discard + fmi2Terminated is a normal early end -> a truncated result, no exception
    raw = fmpy.simulate_fmu(str(fmu), stop_time=n * H, output_interval=H, input=table, start_values=start)
    assert raw["time"][-1] == pytest.approx(60 * H) and len(raw) == 62
    # the last row repeats t = 60 h with the pose held and status 3 (rejected)
    assert raw["status"][-2] == 0 and raw["status"][-1] == 3
    assert (raw["x"][-1], raw["y"][-1], raw["phi"][-1]) == (raw["x"][-2], raw["y"][-2], raw["phi"][-2])
    assert any("'q2' = nan" in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)
    # the project's wrapper raises
    with pytest.raises(StepRefusedError, match="'q2' = nan") as info:
        simulate(fmu, stop_time=n * H, step_size=H, inputs=table, start_values=start)
    assert info.value.result["time"][-1] == pytest.approx(60 * H)


def test_unreachable_joints_hold_the_pose_and_tracking_resumes(make, map1):
    # from q[100], q2 moves out of the joint space (no real DK solution) in 0.05 rad steps and back
    ramp = np.concatenate([np.arange(16), np.arange(14, -1, -1)]) * 0.05
    excursion = np.repeat(Q[100][None], len(ramp), axis=0)
    excursion[:, 1] += ramp
    stream = np.concatenate([Q[:100], excursion, Q[101:200]])
    m = make(**circle_start())
    rows = [m.step(q) for q in stream]
    assert rows == tracker_rows(map1, stream)
    status = np.array([r[OUTPUTS.index("status")] for r in rows])
    held = np.flatnonzero(status == 1)
    assert len(held) > 5 and np.all(np.diff(held) == 1)
    first = held[0]
    assert all(rows[k][:3] == rows[first - 1][:3] for k in held)                # the last pose is held
    assert all(rows[k][OUTPUTS.index("n_real")] == 0 for k in held)
    # one warning at the start of the episode, with the joints; none per step
    warnings = [msg for s, msg in m.messages if s == 1]
    assert len(warnings) == 1 and "no real direct-kinematics solution" in warnings[0]
    assert any("ok again" in msg for s, msg in m.messages if s == 0)
    # back on the circle: the true pose again
    assert np.abs(np.array([r[:3] for r in rows[len(Q[:100]) + len(ramp):]]) - PATH[101:200]).max() < 1e-9
    assert status[-1] == 0


# ---------------------------------------------------------------------- certainty and the bundle
def test_certainty_outputs_follow_the_tracker(make, map1):
    """``certain`` is the tracker's StepInfo.certain; ``uncertain_since`` the time of the step that began
    the episode (t + h of its doStep), -1 while certain; both are part of the FMU state."""
    ramp = np.concatenate([np.arange(16), np.arange(14, -1, -1)]) * 0.05
    excursion = np.repeat(Q[100][None], len(ramp), axis=0)
    excursion[:, 1] += ramp
    stream = np.concatenate([Q[:100], excursion, Q[101:200]])
    tr = Tracker(MODEL, map1)
    tr.reset(X0, stream[0])
    expected, episode = [], None
    for k, q in enumerate(stream):
        _, info = tr.step(q)
        if info.certain:
            episode = None
        elif episode is None or episode[0] != info.uncertain_since:
            episode = (info.uncertain_since, (k + 1) * H)
        expected.append((info.certain, -1.0 if episode is None else episode[1]))
    m = make(**circle_start())
    assert tuple(m.get_values(CERTAINTY)) == (True, -1.0)
    assert _certainty(m, stream) == [(c, pytest.approx(s, abs=1e-12)) for c, s in expected]
    # a state taken mid-way reproduces them
    m2 = make("again", **circle_start())
    _certainty(m2, stream[:110])
    state = m2.fmu.getFMUstate()
    rest = _certainty(m2, stream[110:])
    m2.fmu.setFMUstate(state)
    m2.fmu.freeFMUstate(state)
    m2.t = 110 * H
    assert _certainty(m2, stream[110:]) == rest


def _certainty(m, stream):
    out = []
    for q in stream:
        m.step(q)
        out.append(tuple(m.get_values(CERTAINTY)))
    return out


def test_a_noisy_stream_with_an_outlier_and_a_stuck_joint_matches_the_tracker(make, map1):
    """Joints as a 12-bit encoder with 1e-3 rad of noise gives them, one outlier, one joint stuck for
    20 samples: with the sensor parameters the FMU outputs what the in-process tracker with the same
    options returns, step by step."""
    from experiments.sensors import Sensor
    sensor = Sensor("12-bit", bits=12, noise=1e-3)
    stream = sensor.measure(Q, seed=11).q
    stream[0] = Q[0]
    stream[150, 2] += 0.1                                     # an outlier the gate refuses
    stream[301:321, 0] = stream[300, 0]                       # a stuck joint
    tol, speed, stuck = sensor.tolerance(3.0), (2.0, 1.0), sensor.stuck_after()
    tr = Tracker(MODEL, map1, joint_tolerance=tol, speed_bound=speed, stuck_after=stuck)
    tr.reset(X0, stream[0])
    m = make(**circle_start(), joint_tolerance=tol, speed_bound_linear=speed[0], speed_bound_angular=speed[1],
             stuck_after=stuck)
    statuses = []
    for k in range(1, len(stream)):
        X, info = tr.step(stream[k], H)
        x, y, phi, status, certain = m.step(stream[k])[0:3] + tuple(m.get_values(("status", "certain")))
        assert (x, y, phi) == tuple(X.tolist()) and status == info.status and certain == info.certain, k
        statuses.append(status)
    rejected = [k for k, v in STATUS.items() if v == "rejected"][0]
    assert statuses[149] == rejected
    assert [k + 1 for k, s in enumerate(statuses) if s == rejected] == [150] + list(range(300 + stuck - 1, 321))


def test_sensor_parameters_are_checked_at_initialization(fmu, unzipdir):
    m = _refused_initialization(fmu, unzipdir, **circle_start(), speed_bound_linear=1.0)   # no angular bound
    try:
        assert any("'speed_bound_angular' = 0.0" in msg for msg in m.errors())
        assert m.get_values(OUTPUTS)[OUTPUTS.index("status")] == 3
        with pytest.raises(FMICallException) as info:
            m.fmu.doStep(0.0, H)
        assert info.value.status == fmi2Error
    finally:
        m.close()


def test_outputs_hold_the_initial_pose_in_initialization_mode(fmu, unzipdir, map1):
    from cosim.unit import FMUUnit
    unit = FMUUnit(fmu, "dk-init", unzip_dir=unzipdir)
    try:
        unit.fmu.setupExperiment(startTime=0.0)
        unit.fmu.enterInitializationMode()
        # the honest start of the start values (the home pose and its joints), then of the circle's start
        start = [float(unit.vars[n].start) for n in ("x0", "y0", "phi0")]
        assert unit.get_values(["x", "y", "phi"]) == pytest.approx(start, abs=1e-12)
        assert unit.get_values(["certain", "trust"]) == [True, 2]
        unit.set_values(circle_start())
        honest = Tracker(MODEL, map1).reset(X0, Q[0])
        expected = [*honest.X.tolist(), True, *honest.pose_bound.tolist()]
        names = ["x", "y", "phi", "certain", "x_bound", "y_bound", "phi_bound"]
        assert unit.get_values(names) == expected
        unit.fmu.exitInitializationMode()
        assert unit.get_values(names) == expected
    finally:
        unit.close()
