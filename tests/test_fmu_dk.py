"""The direct-kinematics FMU (fmu_src/RRRDirectKinematics.py, built by build_fmu.py).

Built once per module into a temporary folder with a coarse map (40 mm / 6 deg, the reference
configuration of ``build_fmu.REFERENCE``) and run for real: fmpy.simulate_fmu, fmpy's FMU2Slave,
libcosim (libcosimpy), all in this process, compared with the in-process ``solver.Tracker``.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import sys
import zipfile
from ctypes import byref
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import solver  # noqa: E402  (before any FMU: the FMUs then use this copy, no numba recompilation)
import fmpy  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,  # noqa: E402
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Discard, fmi2Fatal,
                       fmi2LastSuccessfulTime, fmi2Terminated)

import build_fmu  # noqa: E402
from fmu_src.fmi_build import (LibcosimError, StepRefusedError, _fmu_hygiene, input_table, run_libcosim,  # noqa: E402
                               simulate, smoke_check, validate)
from solver import Manipulator, circle_path, dk_all, ik, singularity_measures  # noqa: E402
from solver.__main__ import HOME_POSE  # noqa: E402
from solver.maptensor import MapTensor  # noqa: E402
from solver.tracker import STATUS, Tracker  # noqa: E402

H = build_fmu.REFERENCE["h"]
N = build_fmu.REFERENCE["n"]
RES = build_fmu.REFERENCE["resolution"]
OUTPUTS = build_fmu.OUTPUTS
REAL_OUT = ("x", "y", "phi", "cond")
INT_OUT = ("region", "n_real", "status")
BOOL_OUT = ("near_border", "ambiguous")
MODEL = Manipulator.paper()
PATH = circle_path(N)
Q = ik(MODEL, PATH, 1)
X0 = PATH[0]


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(autouse=True)
def hygiene():
    """Undo what pythonfmu's C wrapper does to sys.path / sys.modules (see fmu_src.fmi_build)."""
    with _fmu_hygiene():
        yield


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("dk")


@pytest.fixture(scope="module")
def built(tmp):
    """The reference configuration: posture 1, default mode, 40 mm / 6 deg map."""
    logs = []
    result = build_fmu.build(tmp / "fmu", postures=(1,), resolution=RES, cache_dir=tmp / "maps", log=logs.append)
    assert any("built" in m for m in logs)
    return result


@pytest.fixture(scope="module")
def fmu(built):
    return built.fmu


@pytest.fixture(scope="module")
def map1(built):
    return MapTensor.load(built.maps[1])


@pytest.fixture(scope="module")
def md(fmu):
    return read_model_description(str(fmu))


@pytest.fixture(scope="module")
def unzipdir(fmu, tmp):
    return extract(str(fmu), unzipdir=str(tmp / "unzipped"))


@pytest.fixture(scope="module")
def built_multi(tmp):
    """Postures 2 and 1 embedded, posture 2 and paper mode as start values (--posture 2 1 --mode paper)."""
    return build_fmu.build(tmp / "multi", postures=(2, 1), resolution=RES, mode="paper", cache_dir=tmp / "maps",
                           log=lambda m: None)


class Master:
    """A minimal FMU2Slave master: value references looked up once, the FMU's log kept."""

    def __init__(self, md, unzipdir, name="dk", **start):
        self.md = md
        self.messages: list[tuple[int, str]] = []

        def logger(_c, _name, status, _category, message):
            self.messages.append((int(status), message.decode("utf-8", "replace")))

        self._cb = fmi2CallbackFunctions()
        self._cb.logger = fmi2CallbackLoggerTYPE(logger)
        self._cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        self._cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        from fmpy.logging import addLoggerProxy
        addLoggerProxy(byref(self._cb))
        self.var = {v.name: v for v in md.modelVariables}
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self._cb, loggingOn=True)
        self.initialize(**start)

    def initialize(self, **start):
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(**start)
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def set(self, **values):
        for name, value in values.items():
            v = self.var[name]
            if v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            else:
                self.fmu.setReal([v.valueReference], [float(value)])

    def set_q(self, q):
        self.set(q1=q[0], q2=q[1], q3=q[2])

    def step(self, q):
        self.set_q(q)
        self.fmu.doStep(self.t, H)
        self.t += H
        return self.outputs()

    def outputs(self):
        vals = dict(zip(REAL_OUT, self.fmu.getReal([self.var[n].valueReference for n in REAL_OUT])))
        vals.update(zip(INT_OUT, self.fmu.getInteger([self.var[n].valueReference for n in INT_OUT])))
        vals.update(zip(BOOL_OUT, self.fmu.getBoolean([self.var[n].valueReference for n in BOOL_OUT])))
        return tuple(vals[n] for n in OUTPUTS)

    def errors(self, least=fmi2Discard):
        return [m for s, m in self.messages if s >= least]

    def free(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.fixture
def make(md, unzipdir):
    made = []

    def factory(name="dk", md_=None, dir_=None, **start):
        made.append(Master(md_ or md, dir_ or unzipdir, name, **start))
        return made[-1]

    yield factory
    for m in made:
        m.free()


def circle_start():
    return {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "q1": Q[0, 0], "q2": Q[0, 1], "q3": Q[0, 2]}


def tracker_rows(mt, stream, X_start=X0, q_start=None, mode="default"):
    """What the FMU must output after each doStep: an in-process Tracker fed the same joints."""
    tr = Tracker(MODEL, mt, mode=mode)
    tr.reset(X_start, stream[0] if q_start is None else q_start)
    rows = []
    for q in stream:
        X, info = tr.step(q)
        rows.append((float(X[0]), float(X[1]), float(X[2]), info.label, info.near_border, info.n_real,
                     info.ambiguous, info.status, info.cond))
    return rows


def result_rows(result):
    return [tuple(r[n].item() for n in OUTPUTS) for r in result]


# ---------------------------------------------------------------------- build and model description
def test_fmu_validates(built, fmu):
    assert built.problems == []
    assert validate(fmu) == []
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
    assert {"resources/maps/posture1.npz", "resources/maps/manifest.json", "resources/solver/tracker.py",
            "resources/RRRDirectKinematics.py", "documentation/_main.html", "documentation/index.md"} <= names


def test_model_description(md, map1):
    v = {x.name: x for x in md.modelVariables}
    expected = {"q1": ("input", "continuous", "rad"), "q2": ("input", "continuous", "rad"),
                "q3": ("input", "continuous", "rad"),
                "x0": ("parameter", "fixed", "m"), "y0": ("parameter", "fixed", "m"),
                "phi0": ("parameter", "fixed", "rad"), "posture": ("parameter", "fixed", None),
                "mode": ("parameter", "fixed", None),
                "x": ("output", "continuous", "m"), "y": ("output", "continuous", "m"),
                "phi": ("output", "continuous", "rad"), "cond": ("output", "continuous", "1"),
                "region": ("output", "discrete", None), "near_border": ("output", "discrete", None),
                "n_real": ("output", "discrete", None), "ambiguous": ("output", "discrete", None),
                "status": ("output", "discrete", None)}
    assert {n: (x.causality, x.variability, x.unit) for n, x in v.items()} == expected
    assert {n: v[n].type for n in ("posture", "mode", "region", "n_real", "status")} == dict.fromkeys(
        ("posture", "mode", "region", "n_real", "status"), "Integer")
    assert v["near_border"].type == v["ambiguous"].type == "Boolean"
    # every output depends on exactly q1..q3; InitialUnknowns list every output
    assert {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs} == \
        {n: ["q1", "q2", "q3"] for n in OUTPUTS}
    assert {u.variable.name for u in md.initialUnknowns} == set(OUTPUTS)
    assert {u.name for u in md.unitDefinitions} == {"1", "m", "rad"}
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    # start values: the home pose and its joints in posture 1; posture 1 (1..8), default mode
    assert [float(v[n].start) for n in ("x0", "y0", "phi0")] == list(HOME_POSE)
    q_home = ik(MODEL, np.array(HOME_POSE), 1)
    assert [float(v[n].start) for n in ("q1", "q2", "q3")] == q_home.tolist()
    assert (int(v["posture"].start), int(v["posture"].min), int(v["posture"].max)) == (1, 1, 8)
    assert int(v["mode"].start) == 0


def test_home_pose_is_inside_and_far_from_singularities(map1, make):
    X = np.array(HOME_POSE)
    q = ik(MODEL, X, 1)
    sm = singularity_measures(MODEL, X, q)
    assert np.all(np.isfinite(q))
    assert sm.type1 > 0.5 and sm.type2 > 0.5          # 0.75 and 0.63: well away from both singularities
    assert map1.near_labels(X)[0] == 0 and map1.label_at(X) != 0          # inside the tool space, no border
    # the FMU with its start values: outputs = the home pose, status ok, one region, no warning
    m = make()
    x, y, phi, region, near_border, n_real, ambiguous, status, cond = m.outputs()
    assert (x, y, phi) == HOME_POSE and status == 0 and not ambiguous and not near_border
    assert region == map1.label_at(X) and n_real == dk_all(MODEL, q).n_real and cond > 0.4
    assert m.errors(least=1) == []


def test_build_is_deterministic_and_reuses_the_map(built, tmp):
    logs = []
    again = build_fmu.build(tmp / "again", postures=(1,), resolution=RES, cache_dir=tmp / "maps", log=logs.append)
    assert any("reused" in m for m in logs) and not any("built " in m for m in logs)
    assert again.fmu.read_bytes() == built.fmu.read_bytes()


def test_command_line(built, tmp, capsys):
    out = tmp / "cli"
    (out / "maps").mkdir(parents=True)
    cached = build_fmu.map_cache_path(tmp / "maps", 1, RES, build_fmu.DEFAULT_RULE, MODEL)
    (out / "maps" / cached.name).write_bytes(cached.read_bytes())       # the CLI's cache: reused, not rebuilt
    assert build_fmu.main(["--out", str(out), "--resolution", "40mm,6deg"]) == 0
    text = capsys.readouterr().out
    assert "reused" in text and "validation: OK" in text and "MB" in text
    assert (out / "RRRDirectKinematics.fmu").read_bytes() == built.fmu.read_bytes()
    assert build_fmu.main(["--out", str(out), "--map", str(cached), "--posture", "1"]) == 0
    assert build_fmu.main(["--out", str(out), "--resolution", "40 furlongs"]) == 2


@pytest.mark.parametrize("text, expected", [
    ("10mm,2deg", (0.01, np.deg2rad(2))), ("40 6", (0.04, np.deg2rad(6))), (["40", "6"], (0.04, np.deg2rad(6))),
    ("0.04m 6deg", (0.04, np.deg2rad(6))), ("1cm,0.05rad", (0.01, 0.05)), ("2.5mm;1.5deg", (0.0025, np.deg2rad(1.5))),
])
def test_parse_resolution(text, expected):
    assert build_fmu.parse_resolution(text) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("text", ["10mm", "10kg,2deg", "0mm,2deg", "a,b", "1 2 3"])
def test_parse_resolution_rejects(text):
    with pytest.raises(ValueError, match="resolution"):
        build_fmu.parse_resolution(text)


# ---------------------------------------------------------------------- the paper's circle
def test_circle_in_fmpy_matches_tracker_and_reference(fmu, map1):
    result = build_fmu.run_circle(fmu)                              # fmpy.simulate_fmu, raises on refusals
    assert len(result) == N + 1
    np.testing.assert_array_equal(result["time"], np.arange(N + 1) * H)
    rows = result_rows(result)
    # row 0: the initial pose before any doStep; row k+1: the pose for q[k], exactly the in-process tracker's
    assert rows[0][:3] == tuple(X0) and rows[0][OUTPUTS.index("status")] == 0
    assert rows[1:] == tracker_rows(map1, Q)
    # the tracker follows the circle (the true solution, not another assembly mode)
    pose = np.column_stack([result["x"], result["y"], result["phi"]])
    assert np.abs(pose[1:] - PATH).max() < 1e-9
    assert set(result["status"]) == {0} and 0 not in set(result["region"])
    # ... and matches the stored reference run (fmu_src/reference/RRRDirectKinematics.csv): first what does
    # not depend on the map's numbering of the solutions, then the numbering-dependent columns
    header, ref = build_fmu.read_reference_csv()
    assert len(ref) == len(result)
    for name in ("time", "q1", "q2", "q3", "x", "y", "phi", "cond"):
        np.testing.assert_allclose(result[name], ref[name], rtol=0, atol=1e-12, err_msg=name)
    for name in ("n_real", "status"):
        np.testing.assert_array_equal(result[name].astype(int), ref[name], err_msg=name)
    assert any(f"labels_sha256 {map1.checksum()}" in h for h in header), \
        "the reference was made with another map (labels): python build_fmu.py --write-reference"
    for name in ("region", "near_border", "ambiguous"):
        np.testing.assert_array_equal(result[name].astype(int), ref[name], err_msg=name)


def test_paper_mode_parameter(fmu, map1):
    table = input_table(np.arange(N) * H, q1=Q[:, 0], q2=Q[:, 1], q3=Q[:, 2])
    result = simulate(fmu, stop_time=N * H, step_size=H, inputs=table, outputs=list(OUTPUTS),
                      start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2], "mode": 1})
    assert result_rows(result)[1:] == tracker_rows(map1, Q, mode="paper")


def test_libcosim_runs_the_circle(fmu, map1):
    n = 300
    result = run_libcosim(fmu, step_size=H, n_steps=n, inputs={"q1": Q[:n, 0], "q2": Q[:n, 1], "q3": Q[:n, 2]},
                          start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]})
    np.testing.assert_allclose(result.time, (np.arange(n) + 1) * H, rtol=1e-12)
    got = list(zip(*(result[name].tolist() for name in OUTPUTS)))
    # the tracker does not use the time step: libcosim's output is the tracker's, bit for bit
    assert got == tracker_rows(map1, Q[:n])
    # a bad input: libcosim's step fails ("Step not complete"); the helper raises with the slave's reason
    bad = Q[:20, 0].copy()
    bad[7] = math.nan
    with pytest.raises(LibcosimError, match="Step not complete") as info:
        run_libcosim(fmu, step_size=H, n_steps=20, inputs={"q1": bad, "q2": Q[:20, 1], "q3": Q[:20, 2]},
                     start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]})
    assert "'q1' = nan" in str(info.value) and len(info.value.partial.time) == 7


def test_smoke_check(fmu):
    q = Q[:40]
    assert smoke_check(fmu, n_steps=40, step_size=H, inputs={"q1": q[:, 0], "q2": q[:, 1], "q3": q[:, 2]},
                       start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]}) == []


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


def test_reset_returns_to_the_initial_pose(make):
    m = make(**circle_start())
    initial = m.outputs()
    first = [m.step(q) for q in Q[:200]]
    m.fmu.reset()
    m.initialize(**circle_start())
    assert m.outputs() == initial and initial[:3] == tuple(X0)
    assert [m.step(q) for q in Q[:200]] == first


def test_outputs_before_the_first_step_and_direct_feedthrough(make, map1):
    m = make(**circle_start())
    initial = m.outputs()
    assert initial[:3] == tuple(X0)                   # the initial pose itself, before any doStep
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
def test_initial_pose_outside_the_tool_space(make):
    m = make(x0=5.0)
    assert any("outside the tool space of posture 1" in msg for msg in m.errors())
    assert m.outputs()[OUTPUTS.index("status")] == 3
    with pytest.raises(FMICallException) as info:
        m.step(Q[0])
    assert info.value.status == fmi2Discard and not [msg for s, msg in m.messages if s >= fmi2Fatal]


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
    assert info.value.status == fmi2Discard                   # pythonfmu 0.7: not fmi2Error, never fmi2Fatal
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
    # continue with the next valid input at the same communication point: as if the bad step never was
    assert [m.step(Q[k]) for k in range(50, 120)] == expected[50:]
    # or roll back with setFMUstate: same
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


# ---------------------------------------------------------------------- postures and build options
def test_several_postures_and_the_mode_build_option(built_multi, tmp, make):
    assert sorted(built_multi.maps) == [1, 2] and built_multi.problems == []
    md2 = read_model_description(str(built_multi.fmu))
    v = {x.name: x for x in md2.modelVariables}
    assert (int(v["posture"].start), int(v["mode"].start)) == (2, 1)
    assert [float(v[n].start) for n in ("q1", "q2", "q3")] == ik(MODEL, np.array(HOME_POSE), 2).tolist()
    dir2 = extract(str(built_multi.fmu), unzipdir=str(tmp / "multi_unzipped"))
    q2 = ik(MODEL, PATH, 2)
    map2 = MapTensor.load(built_multi.maps[2])
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2]}
    m = make("p2", md_=md2, dir_=dir2, **start, q1=q2[0, 0], q2=q2[0, 1], q3=q2[0, 2])
    assert [m.step(q) for q in q2[:150]] == tracker_rows(map2, q2[:150], mode="paper")
    m1 = make("p1", md_=md2, dir_=dir2, **circle_start(), posture=1, mode=0)
    assert [m1.step(q) for q in Q[:150]] == tracker_rows(MapTensor.load(built_multi.maps[1]), Q[:150])
    # a posture without an embedded map: initialization fails, every step is refused with the reason
    m3 = make("p3", md_=md2, dir_=dir2, posture=3)
    assert any("embeds maps of posture(s) [1, 2] only" in msg for msg in m3.errors())
    assert m3.outputs()[OUTPUTS.index("status")] == 3
    with pytest.raises(FMICallException) as info:
        m3.step(Q[0])
    assert info.value.status == fmi2Discard
    assert any("initialization failed" in msg and "refused" in msg for msg in m3.errors())


# ---------------------------------------------------------------------- damaged map resources
def _rewrite(src: Path, dest: Path, replace: dict[str, bytes | None]) -> Path:
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for info in z.infolist():
            if info.filename in replace:
                if replace[info.filename] is not None:
                    out.writestr(info, replace[info.filename])
            else:
                out.writestr(info, z.read(info))
    return dest


def _manifest_for(fmu: Path, data: bytes) -> bytes:
    with zipfile.ZipFile(fmu) as z:
        manifest = json.loads(z.read("resources/maps/manifest.json"))
    manifest["maps"][0].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    return json.dumps(manifest).encode()


def _altered_labels(path: Path) -> bytes:
    """The map file with one label changed and its metadata (recorded checksum) kept."""
    with np.load(path) as data:
        labels, meta = np.array(data["labels"]), data["metadata"]
    flat = labels.reshape(-1)
    flat[np.flatnonzero(flat)[0]] ^= 3
    buf = io.BytesIO()
    np.savez_compressed(buf, labels=labels, metadata=meta)
    return buf.getvalue()


@pytest.mark.parametrize("damage, message", [
    ("truncated", "is truncated or modified"),
    ("missing", "resources/maps/posture1.npz, is missing"),
    ("no manifest", "manifest.json is missing"),
    ("labels", "labels checksum"),
    ("foreign", "built for posture 2, expected 1"),
])
def test_damaged_map_fails_instantiation(fmu, built_multi, md, tmp, caplog, damage, message):
    with zipfile.ZipFile(fmu) as z:
        original = z.read("resources/maps/posture1.npz")
    if damage == "truncated":
        replace = {"resources/maps/posture1.npz": original[: len(original) // 2]}
    elif damage == "missing":
        replace = {"resources/maps/posture1.npz": None}
    elif damage == "no manifest":
        replace = {"resources/maps/manifest.json": None}
    else:
        # map bytes that pass the manifest check (updated with them): MapTensor.load must catch them
        data = (_altered_labels(Path(built_multi.maps[1])) if damage == "labels"
                else Path(built_multi.maps[2]).read_bytes())
        replace = {"resources/maps/posture1.npz": data, "resources/maps/manifest.json": _manifest_for(fmu, data)}
    bad = _rewrite(fmu, tmp / f"damaged_{damage.replace(' ', '_')}.fmu", replace)
    unzipped = extract(str(bad), unzipdir=str(tmp / f"damaged_{damage.replace(' ', '_')}"))
    messages = []

    def logger(_c, _n, status, _cat, msg):
        messages.append((int(status), msg.decode()))

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
    from fmpy.logging import addLoggerProxy
    addLoggerProxy(byref(cb))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="RRRDirectKinematics", instanceName="bad")
    with pytest.raises(Exception, match="Failed to instantiate"):
        slave.instantiate(callbacks=cb, loggingOn=True)
    assert any("MapTensorFileError" in m and message in m for _, m in messages), messages
    assert any(message in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)
    caplog.clear()
    with pytest.raises(Exception, match="Failed to instantiate"):          # what a user of fmpy sees ...
        fmpy.simulate_fmu(str(bad), stop_time=0.01)
    assert any(message in r.getMessage() for r in caplog.records)           # ... and the reason, on stderr
