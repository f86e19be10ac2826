"""The DK FMU's fast lane (fmu_src/fast_lane.py, fmu_src/dk_lane.py, fmu_src/loader/fast_lane.c): the
loader answers fmi2SetReal of the joints, fmi2DoStep and fmi2Get* on the slave's arrays with the
compiled step, without the interpreter, and gives what the Python path gives, bit for bit.

The reference is the same FMU with the lane off (``RRR_DK_FAST_LANE=0``), stepped side by side in
one process; the slaves are found in the process (they are Python objects of this interpreter) to
read how many calls the lane answered.
"""
from __future__ import annotations

import gc
import math

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from cosim import Scenario
from cosim_support import fmus, loop  # noqa: F401 (fixtures)
from dk_fmu_support import BOUND, BUDGET, CERTAINTY, H, OUTPUTS, Q, circle_start, tracker_rows
from dk_fmu_support import built, fmu, hygiene, make, map1, tmp, unzipdir  # noqa: F401 (fixtures)

ALL = (*OUTPUTS, *CERTAINTY, *BOUND, *BUDGET)


def _slave(name, model="RRRDirectKinematics"):
    """The live slave of class ``model`` and instance ``name`` in this process (freed ones collected first)."""
    gc.collect()
    found = [o for o in gc.get_objects()
             if type(o).__name__ == model and getattr(o, "instance_name", None) == name]
    assert len(found) == 1, found
    return found[0]


def _excursion():
    """The circle with q2 driven out of the joint space and back (an unreachable episode: two status
    changes the Python path logs) from sample 100."""
    ramp = np.concatenate([np.arange(16), np.arange(14, -1, -1)]) * 0.05
    excursion = np.repeat(Q[100][None], len(ramp), axis=0)
    excursion[:, 1] += ramp
    return np.concatenate([Q[:100], excursion, Q[101:260]])


def _run(m, stream, probe_every=0):
    """Every output after each doStep; with ``probe_every``, also the outputs read between setting the
    joints and the doStep (direct feedthrough: a tentative step) every so many samples."""
    rows = []
    for k, q in enumerate(stream):
        m.set_q(q)
        if probe_every and k % probe_every == 0:
            rows.append(tuple(m.get_values(ALL)))
        m.fmu.doStep(m.t, H)
        m.t += H
        rows.append(tuple(m.get_values(ALL)))
    return rows


def _pair(make, monkeypatch, **start):
    fast = make("fast", **circle_start(), **start)
    monkeypatch.setenv("RRR_DK_FAST_LANE", "0")
    slow = make("slow", **circle_start(), **start)
    monkeypatch.delenv("RRR_DK_FAST_LANE")
    return fast, slow


def test_the_lane_takes_the_routine_steps_and_gives_the_python_paths_results(make, map1, monkeypatch):
    stream = _excursion()
    fast, slow = _pair(make, monkeypatch)         # both live: each master reads its own instance's log
    rows = _run(fast, stream, probe_every=7)
    assert rows == _run(slow, stream, probe_every=7)
    assert rows[-1][:len(OUTPUTS)] == tracker_rows(map1, stream)[-1]
    steps, calls = _slave("fast").lane_counts
    assert _slave("slow").lane_counts == (0, 0)
    # every step but the two that change the episode (logged by Python) and the first after them
    assert len(stream) - 6 <= steps < len(stream)
    assert calls > 3 * steps                     # the joints' sets and the gets of each step
    # the episode is logged once each way, as on the Python path, to each instance's own logger (the
    # two units once shared fmpy's one logger proxy: the first instance's log went to the second's)
    for m in (fast, slow):
        texts = [msg for _, msg in m.messages]
        assert sum("no real direct-kinematics solution" in t for t in texts) == 1
        assert sum("ok again" in t for t in texts) == 1


def test_a_state_saved_after_lane_steps_restores_them(make, monkeypatch):
    fast, slow = _pair(make, monkeypatch)
    _run(fast, Q[:150])
    _run(slow, Q[:150])
    state = fast.fmu.getFMUstate()                # the slave reads the lane's steps first
    first = _run(fast, Q[150:260])
    fast.fmu.setFMUstate(state)
    fast.fmu.freeFMUstate(state)
    fast.t = 150 * H
    again = _run(fast, Q[150:260])
    assert again == first == _run(slow, Q[150:260])
    assert _slave("fast").lane_counts[0] >= 2 * 110 + 140


def test_a_refused_input_goes_to_python_and_keeps_the_state(make, monkeypatch):
    fast, slow = _pair(make, monkeypatch)
    for m in (fast, slow):
        _run(m, Q[:50])
        m.set_q((math.nan, Q[50][1], Q[50][2]))
        with pytest.raises(FMICallException):    # fmi2Discard: the Python path refuses it
            m.fmu.doStep(m.t, H)
    assert tuple(fast.get_values(ALL)) == tuple(slow.get_values(ALL))
    assert fast.get_values(["status"]) == [3]


def _raises(what):
    def hook(slave):
        raise RuntimeError(f"test: the {what} fails")
    return hook


def _forwarded(m):
    """A call the lane never answers (it serves the joints' sets, doStep and the gets): the loader pulls,
    forwards it to Python, pushes."""
    state = m.fmu.getFMUstate()
    m.fmu.freeFMUstate(state)


def test_a_push_that_raises_closes_the_lane_and_python_carries_on(make, monkeypatch):
    """The slave's push raises (after a call the loader forwarded to Python): the lane closes, says so
    in the log, and every later call goes through Python with the Python path's results, bit for bit."""
    fast, slow = _pair(make, monkeypatch)
    assert _run(fast, Q[:60]) == _run(slow, Q[:60])
    slave = _slave("fast")
    steps = slave.lane_counts[0]
    assert steps >= 55
    monkeypatch.setattr(type(slave), "_lane_before_steps", _raises("push"))     # the push's last act
    _forwarded(fast)                                    # the pull, the call, then the push raises
    assert _run(fast, Q[60:140]) == _run(slow, Q[60:140])
    assert slave.lane_counts[0] == steps                # no lane step since
    texts = [msg for _, msg in fast.messages]
    assert any("fast lane closed" in t and "the push fails" in t for t in texts), texts[-5:]


def test_a_pull_that_raises_makes_the_instance_refuse_its_steps_and_say_why(make, monkeypatch):
    """The slave's pull raises after lane steps (it could not read the state they left): the lane
    closes and the instance is unusable, as after a failed rollback: every doStep is refused (an FMI
    status, not a crash) with the reason in the log, until the host frees or resets it."""
    m = make("pulled", **circle_start())
    _run(m, Q[:30])
    slave = _slave("pulled")
    assert slave.lane_counts[0] >= 25
    monkeypatch.setattr(type(slave), "_lane_after_steps", _raises("pull"))    # reading the lane's steps
    _forwarded(m)                                       # its pull raises (the state is saved all the same)
    m.set_q(Q[30])
    with pytest.raises(FMICallException):
        m.fmu.doStep(m.t, H)
    steps = slave.lane_counts[0]
    with pytest.raises(FMICallException):
        m.fmu.doStep(m.t, H)                            # again (now in stepFailed): still refused
    assert slave.lane_counts[0] == steps
    texts = [msg for _, msg in m.messages]
    assert any("fast lane closed" in t and "the pull fails" in t for t in texts), texts[-5:]
    assert any("instance unusable" in t and "could not read the lane's state" in t for t in texts), texts[-5:]


def test_an_outlier_the_gate_refuses_after_the_lane_fell_back_is_the_python_paths(make, monkeypatch):
    """Measured joints with one finite outlier: the lane's step sees a status other than the episode's
    (rejected), undoes itself and falls back; Python takes the same step, refuses the sample (pose
    held, doStep ok, status 3, logged) and the lane takes the steps after it: bit for bit the Python path."""
    sensors = dict(joint_tolerance=1e-4, speed_bound_linear=1.0, speed_bound_angular=3.0)
    fast, slow = _pair(make, monkeypatch, **sensors)
    stream = Q[:120].copy()
    stream[60, 0] += 0.3                                # one sample 0.3 rad off: finite, refused
    rows = _run(fast, stream)
    assert rows == _run(slow, stream)
    status = [r[ALL.index("status")] for r in rows]
    assert status[60] == 3 and status[59] == 0 and status[62:] == [0] * (len(stream) - 62), status[55:65]
    assert len(stream) - 6 <= _slave("fast").lane_counts[0] < len(stream)


def test_the_lane_stays_closed_with_the_stuck_joint_detector(make):
    m = make("stuck", stuck_after=5, joint_tolerance=1e-4, **circle_start())
    _run(m, Q[:40])
    assert _slave("stuck").lane_counts[0] == 0     # the detector runs in Python: every step there


def test_the_lane_layout_is_the_loaders():
    """fmu_src/fast_lane.py mirrors fmu_src/loader/fast_lane.h: the struct's fields in order and their
    sizes, the version, the category, the flag bits and the step's command."""
    import ctypes
    import re
    from pathlib import Path

    from fmu_src import fast_lane
    from solver._kernels.c_entry import CMD_PUBLISH, PUBLISHED

    header = (Path(__file__).resolve().parents[1] / "fmu_src" / "loader" / "fast_lane.h").read_text()
    body = re.search(r"typedef struct \{(.*?)\} Lane;", header, re.S).group(1)
    fields = re.findall(r"^\s*[\w\s\*\(\)]*?\(?\*?(\w+)\)?(?:\([^)]*\))?;", body, re.M)
    assert fields == [name for name, _ in fast_lane.LaneStruct._fields_]
    assert all(ctypes.sizeof(t) == 8 for _, t in fast_lane.LaneStruct._fields_)     # int64 and pointers
    defines = dict(re.findall(r"#define (LANE_\w+) (\S+)", header))
    assert int(defines["LANE_VERSION"]) == fast_lane.VERSION
    assert defines["LANE_CATEGORY"] == f'"{fast_lane.LANE_CATEGORY}"'
    assert int(defines["LANE_CMD_PUBLISH"]) == CMD_PUBLISH and int(defines["LANE_PUBLISHED"]) == PUBLISHED
    for name in ("REAL", "INTEGER", "BOOLEAN", "SET", "OUTPUT", "DIRTIES"):
        assert int(defines[f"LANE_{name}"].rstrip("u")) == getattr(fast_lane, name)


def test_the_closed_loop_through_the_lanes_is_the_python_paths(loop, monkeypatch):
    """Plant, controller and DK each behind their lane (fmu_src.table_lane; the plant's and the
    controller's compiled steps dynamics._kernels.c_entry) give the closed loop of the Python path
    bit for bit, and the lanes take every step."""
    from dynamics._kernels.c_entry import CONTROLLER_SLOTS, PLANT_SLOTS
    from fmu_src.ComputedTorqueController import ComputedTorqueController
    from fmu_src.RRRPlant import RRRPlant

    assert RRRPlant.LANE_SLOTS == PLANT_SLOTS and ComputedTorqueController.LANE_SLOTS == CONTROLLER_SLOTS
    sc = Scenario(t_end=0.4)
    fast = loop.run(sc)
    n = len(fast.t) - 1
    gc.collect()
    slaves = [o for o in gc.get_objects()
              if type(o).__name__ in ("RRRPlant", "ComputedTorqueController", "RRRDirectKinematics")
              and hasattr(o, "instance_name")]
    steps = {type(o).__name__: o.lane_counts[0] for o in slaves if o.lane_counts[0]}
    assert set(steps) == {"RRRPlant", "ComputedTorqueController", "RRRDirectKinematics"}, steps
    assert all(k >= n - 3 for k in steps.values()), (steps, n)
    monkeypatch.setenv("RRR_DK_FAST_LANE", "0")
    slow = loop.run(sc)
    assert set(fast.columns) == set(slow.columns)
    for name, column in fast.columns.items():
        assert np.array_equal(column, slow.columns[name], equal_nan=True), name


def test_zero_and_uneven_step_sizes_through_the_lane(make, monkeypatch):
    """doStep with h = 0 (the joints read again, no time passes) and uneven h: the lane's steps are the
    Python path's, bit for bit (dt = h, or unknown for h = 0, as the slave's step passes it)."""
    fast, slow = _pair(make, monkeypatch)
    sizes = [H, H, 0.0, 2 * H, H / 2, 0.0, H] * 6
    rows = {}
    for name, m in (("fast", fast), ("slow", slow)):
        out, t = [], 0.0
        for k, h in enumerate(sizes):
            m.set_q(Q[k])
            m.fmu.doStep(t, h)
            t += h
            out.append(tuple(m.get_values(ALL)))
        rows[name] = out
    assert rows["fast"] == rows["slow"]
    status = [r[ALL.index("status")] for r in rows["fast"]]
    changes = sum(a != b for a, b in zip([0, *status], status))      # each taken by Python (it logs them)
    from solver.tracker import GRID_WATCH      # the first readings after an exact start: the encoder-grid watch

    assert _slave("fast").lane_counts[0] == len(sizes) - changes - GRID_WATCH


def test_two_instances_step_on_two_threads_at_once(make, monkeypatch):
    """FMI lets a host call two instances from two threads at once: their lanes step them concurrently
    (the compiled step runs without the interpreter; the slave's pull and push take the GIL from the
    host's thread), and each gives the Python path's results, bit for bit, episodes logged included."""
    import threading

    a, b = make("a", **circle_start()), make("b", **circle_start())
    monkeypatch.setenv("RRR_DK_FAST_LANE", "0")
    slow = make("slow", **circle_start())
    monkeypatch.delenv("RRR_DK_FAST_LANE")
    stream = _excursion()
    rows, errors, barrier = {}, [], threading.Barrier(2)

    def run(name, m):
        try:
            barrier.wait()
            rows[name] = _run(m, stream, probe_every=5)
        except BaseException as e:          # noqa: BLE001 (the main thread reports it)
            errors.append(e)

    threads = [threading.Thread(target=run, args=(n, m)) for n, m in (("a", a), ("b", b))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    reference = _run(slow, stream, probe_every=5)
    assert rows["a"] == reference and rows["b"] == reference
    for name in ("a", "b"):
        assert _slave(name).lane_counts[0] >= len(stream) - 6


def test_a_step_budget_through_the_lane(make, monkeypatch):
    """With a budget of 100 ns a step (step_budget_share 1e-4 at h = 1 ms) every search does its least
    and stops: the lane's steps are the Python path's, bit for bit, out of budget and not certain;
    given time (h = 1000 s: 100 ms, far more than the proof needs on a loaded machine), both close the
    proof at the same step."""
    fast, slow = _pair(make, monkeypatch, step_budget_share=1e-4)
    rows = [_run(m, Q[:20]) for m in (fast, slow)]
    assert rows[0] == rows[1]
    flags = [(r[ALL.index("certain")], r[ALL.index("out_of_budget")]) for r in rows[0]]
    assert flags[:3] == [(False, True)] * 3
    assert _slave("fast").lane_counts[0] >= 17
    for m in (fast, slow):
        m.set_q(Q[20])
        m.fmu.doStep(m.t, 1000.0)
    assert tuple(fast.get_values(ALL)) == tuple(slow.get_values(ALL))
    assert fast.get_values(["certain", "out_of_budget"]) == [True, False]


def test_the_plants_state_saved_after_lane_steps_restores_them(fmus):
    """The plant FMU behind its lane (its RK4 substeps compiled, called by the loader): an FMU state saved
    after lane steps holds them (the slave pulls the lane's state first), and restored, the same torques
    give the same trajectory, bit for bit."""
    from cosim.unit import FMUUnit

    unit = FMUUnit(fmus["RRRPlant"], "plant-lane")
    try:
        unit.initialize(0.0, {})
        names = ["q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true"]

        def run(k0, n):
            out = []
            for k in range(k0, k0 + n):
                unit.set_values({"tau1": 0.2 * math.sin(k / 20), "tau2": -0.1, "tau3": 0.05 * math.cos(k / 15)})
                unit.fmu.doStep(k * H, H)
                out.append(tuple(unit.get_values(names)))
            return out

        run(0, 50)
        state = unit.fmu.getFMUstate()
        first = run(50, 40)
        unit.fmu.setFMUstate(state)
        unit.fmu.freeFMUstate(state)
        assert run(50, 40) == first
        assert first[-1] != first[0]                                   # the plant moved
        assert _slave("plant-lane", "RRRPlant").lane_counts[0] >= 120
    finally:
        unit.close()
