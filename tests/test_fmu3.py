"""The FMI 3.0 DK FMU (``python build_fmu.py --fmi 3``): validation, arrays, identity with the FMI 2.0 FMU,
FMU state, bad input and the statuses of the FMI 3.0 loader (a C host without Python:
tests/test_c_host3.py; forbidden and refused calls, random call sequences: tests/test_fmi3_states.py).

Both FMUs are built into a temporary folder with the coarse reference map (40 mm / 6 deg, as
tests/dk_fmu_support.py); the FMI 3.0 one runs through fmpy's ``FMU3Slave`` and ``simulate_fmu``,
the FMI 2.0 one through ``FMU2Slave``.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

from cosim.fmus import builds, fmi3_build, fmi3_reference, references
from experiments.suite import default_suite
from solver import HOME_POSE, Manipulator

from dk_fmu_support import H, Q, X0, hygiene, tmp  # noqa: F401 (fixtures)

POSE = ("x", "y", "phi")


@pytest.fixture(scope="module")
def built(tmp):
    """The FMI 2.0 DK FMU of the same configuration (the same map)."""
    return builds.build_dk(tmp / "fmu", postures=(1,), resolution=references.REFERENCE["resolution"],
                           cache_dir=tmp / "maps", log=lambda m: None)


@pytest.fixture(scope="module")
def built3(tmp):
    return fmi3_build.build_dk3(tmp / "fmu3", postures=(1,), resolution=references.REFERENCE["resolution"],
                                cache_dir=tmp / "maps", log=lambda m: None)


@pytest.fixture(scope="module")
def md3(built3):
    return read_model_description(str(built3.fmu))


@pytest.fixture(scope="module")
def dir3(built3, tmp):
    return extract(str(built3.fmu), unzipdir=str(tmp / "unzipped3"))


@pytest.fixture(scope="module")
def dir2(built, tmp):
    return extract(str(built.fmu), unzipdir=str(tmp / "unzipped2"))


class Dk3:
    """The FMI 3.0 FMU through fmpy's FMU3Slave: q in as an array, pose out as an array."""

    def __init__(self, md, unzipdir, name="dk3", pose0=X0, q0=Q[0], posture=1):
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages = []
        self.fmu = FMU3Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=name)
        self.fmu.instantiate(loggingOn=True, logMessage=self._log)
        self.fmu.setFloat64([self.vr["pose0"]], [float(v) for v in pose0])
        if posture is not None:
            self.fmu.setInt32([self.vr["posture"]], [posture])
        self.fmu.setFloat64([self.vr["q"]], [float(v) for v in q0])
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def _log(self, env, status, category, message):
        self.messages.append((int(status), message.decode() if message else ""))

    def step(self, q):
        self.fmu.setFloat64([self.vr["q"]], [float(v) for v in q])
        self.fmu.doStep(self.t, H)
        self.t += H
        return tuple(self.fmu.getFloat64([self.vr["pose"]], nValues=3))

    def get(self, name, kind="Float64", n=1):
        return getattr(self.fmu, "get" + kind)([self.vr[name]], nValues=n)

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def _dk2_poses(md, unzipdir, q, X_start, name="dk2"):
    """The poses of the FMI 2.0 FMU along ``q`` (FMU2Slave), from ``X_start``."""
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([vr[n] for n in ("x0", "y0", "phi0", "q1", "q2", "q3")], [*map(float, X_start), *map(float, q[0])])
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    out, t = [tuple(fmu.getReal([vr[n] for n in POSE]))], 0.0
    for qk in q:
        fmu.setReal([vr[n] for n in ("q1", "q2", "q3")], [float(v) for v in qk])
        fmu.doStep(t, H)
        t += H
        out.append(tuple(fmu.getReal([vr[n] for n in POSE])))
    fmu.terminate()
    fmu.freeInstance()
    return out


def _dk3_poses(md, unzipdir, q, X_start, name="dk3"):
    m = Dk3(md, unzipdir, name, pose0=X_start, q0=q[0])
    out = [tuple(m.get("pose", n=3))] + [m.step(qk) for qk in q]
    m.close()
    return out


# ---------------------------------------------------------------------- the archive and its description
def test_validation_reports_nothing(built3):
    assert built3.problems == []
    assert validate_fmu(str(built3.fmu)) == []


def test_arrays_units_and_capabilities(md3):
    assert md3.fmiVersion == "3.0" and md3.coSimulation.modelIdentifier == "RRRDirectKinematics3"
    assert md3.coSimulation.canGetAndSetFMUstate and md3.coSimulation.canSerializeFMUstate
    v = {x.name: x for x in md3.modelVariables}
    assert v["time"].causality == "independent"
    for name, causality in (("q", "input"), ("pose", "output"), ("pose0", "parameter"), ("pose_bound", "output")):
        assert v[name].type == "Float64" and v[name].causality == causality
        assert [d.start for d in v[name].dimensions] == [3]
    assert v["q"].unit == "rad" and v["uncertain_since"].unit == "s" and v["joint_tolerance"].unit == "rad"
    assert [float(s) for s in v["pose0"].start.split()] == [float(v) for v in HOME_POSE]
    for name in ("region", "status", "trust", "posture", "mode", "stuck_after", "n_real"):
        assert v[name].type == "Int32"
    for name in ("certain", "near_border", "ambiguous"):
        assert v[name].type == "Boolean"
    outputs = {u.variable.name: [d.name for d in u.dependencies] for u in md3.outputs}
    assert outputs["pose"] == ["q"] and set(outputs) >= {"pose", "certain", "uncertain_since", "status", "region",
                                                          "pose_bound", "trust"}


def test_the_build_is_deterministic(built3, tmp):
    again = fmi3_build.build_dk3(tmp / "again3", postures=(1,), resolution=references.REFERENCE["resolution"],
                                 cache_dir=tmp / "maps", log=lambda m: None)
    assert again.fmu.read_bytes() == built3.fmu.read_bytes()


def test_posture_and_mode_start_values(tmp):
    """--posture 2 1 --mode paper: the start values of posture, mode and q (the joints of pose0 in
    posture 2) in the description and in the instance."""
    from solver import ik

    multi = fmi3_build.build_dk3(tmp / "multi3", postures=(2, 1), resolution=references.REFERENCE["resolution"],
                                 mode="paper", cache_dir=tmp / "maps", log=lambda m: None, kernels=False)
    assert multi.problems == []
    md = read_model_description(str(multi.fmu))
    v = {x.name: x for x in md.modelVariables}
    assert (v["posture"].start, v["mode"].start) == ("2", "1")
    q2 = ik(Manipulator.paper(), np.array(HOME_POSE, dtype=float), 2)
    assert [float(x) for x in v["q"].start.split()] == [float(x) for x in q2]
    # in a child process: pythonfmu3's wrapper keeps the first FMI 3.0 slave module a process imported (its
    # start values), and other test files load the posture-1 build into this one
    code = ("import json, sys; sys.path.insert(0, sys.argv[3]); import numpy as np; from fmpy import extract, "
            "read_model_description; from test_fmu3 import Dk3; md = read_model_description(sys.argv[1]); "
            "m = Dk3(md, extract(sys.argv[1], unzipdir=sys.argv[2]), 'multi', pose0=json.loads(sys.argv[4]), "
            "q0=json.loads(sys.argv[5]), posture=None); "
            "print('GOT', json.dumps([m.get(n, 'Int32') for n in ('posture', 'mode', 'status')]), flush=True); "
            "import os; os._exit(0)")
    proc = subprocess.run([sys.executable, "-c", code, str(multi.fmu), str(tmp / "multi3-x"),
                           str(Path(__file__).parent), json.dumps(list(HOME_POSE)), json.dumps([float(x) for x in q2])],
                          capture_output=True, text=True, timeout=600, cwd=tmp)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("GOT ")), None)
    assert line is not None, proc.stderr[-3000:]
    assert json.loads(line[4:]) == [[2], [1], [0]]


# ---------------------------------------------------------------------- identical to the FMI 2.0 FMU
def test_simulate_fmu_with_an_input_array_gives_the_fmi2_reference(built3):
    """fmpy.simulate_fmu with ``q`` an array column: the FMI 2.0 reference CSV, bit for bit."""
    result = fmi3_reference.run_circle3(built3.fmu)
    ref = references.read_reference_csv()[1]
    np.testing.assert_array_equal(result["pose"], np.stack([ref[n] for n in POSE], axis=1))
    for name in fmi3_reference.SCALARS:
        np.testing.assert_array_equal(result[name].astype(ref[name].dtype), ref[name])
    kept = references.read_csv(references.REFERENCE_DIR / "RRRDirectKinematics3.csv",
                               references.INT_COLUMNS["RRRDirectKinematics"])[1]
    np.testing.assert_array_equal(kept["pose[1]"], ref["x"])
    np.testing.assert_array_equal(kept["pose[3]"], ref["phi"])


def test_fmu3slave_reference_path_is_bit_identical_to_the_fmi2_fmu(built, md3, dir3, dir2):
    md2 = read_model_description(str(built.fmu))
    assert _dk3_poses(md3, dir3, Q, X0) == _dk2_poses(md2, dir2, Q, X0)


def test_it_ships_the_kernels_of_the_fmi2_fmu_of_the_same_code(built, built3):
    """pythonfmu3 holds no kernel: the FMI 3.0 DK FMU's kernel key is the FMI 2.0 one's (the same solver), which
    lets its store folder be seeded from the FMI 2.0 FMU's (cosim.fmus.kernels.seed, tested in
    test_early_compile.py); both ship the C entry point."""
    def shipped(fmu):
        with zipfile.ZipFile(fmu) as z:
            return (json.loads(z.read("resources/kernels/manifest.json"))["key"],
                    {n for n in z.namelist() if n.startswith("resources/kernels/") and n.endswith(".nbi")})

    key2, files2 = shipped(built.fmu)
    key3, files3 = shipped(built3.fmu)
    assert key3 == key2
    entry = {n for n in files2 if "/solver/_kernels/c_entry." in n}
    assert entry and entry <= files3


def test_tracker_suite_posture_1_paths_are_identical(built, md3, dir3, dir2):
    md2 = read_model_description(str(built.fmu))
    paths = [p for p in default_suite(Manipulator.paper()) if p.posture == 1]
    assert len(paths) == 16
    for k, p in enumerate(paths):
        assert _dk3_poses(md3, dir3, p.q, p.X[0], f"s3-{k}") == _dk2_poses(md2, dir2, p.q, p.X[0], f"s2-{k}"), p.name


def test_time_reads_the_last_communication_point(md3, dir3):
    m = Dk3(md3, dir3, "time")
    pose = [m.step(qk) for qk in Q[1:4]][-1]
    both = m.fmu.getFloat64([m.vr["time"], m.vr["pose"]], nValues=4)
    assert both[0] == pytest.approx(3 * H, abs=1e-15) and tuple(both[1:]) == pose
    m.close()


# ---------------------------------------------------------------------- FMU state, bad input
def test_fmu_state_round_trip(md3, dir3):
    m = Dk3(md3, dir3, "state")
    for qk in Q[:20]:
        m.step(qk)
    state = m.fmu.getFMUState()
    blob = m.fmu.serializeFMUState(state)
    t = m.t
    ahead = [m.step(qk) for qk in Q[20:40]]
    m.fmu.setFMUState(state)
    m.t = t
    assert [m.step(qk) for qk in Q[20:40]] == ahead
    other = Dk3(md3, dir3, "other")
    other.fmu.setFMUState(other.fmu.deserializeFMUState(blob))
    other.t = t
    assert [other.step(qk) for qk in Q[20:40]] == ahead
    m.fmu.freeFMUState(state)
    m.close()
    other.close()


def test_nan_input_is_discarded_with_status_3(md3, dir3):
    """fmi3Discard, the state kept; FMI 3.0 leaves the FMU in StepMode after a discarded step: a valid
    input steps again from the same point, and gives the pose an undisturbed instance gives."""
    m = Dk3(md3, dir3, "nan")
    for qk in Q[:5]:
        m.step(qk)
    held = m.get("pose", n=3)
    m.fmu.setFloat64([m.vr["q"]], [float(Q[5][0]), math.nan, float(Q[5][2])])
    with pytest.raises(FMICallException) as info:
        m.fmu.doStep(m.t, H)
    assert info.value.status == 2
    assert m.get("status", "Int32") == [3] and m.get("pose", n=3) == held
    assert any(s >= 2 and "'q2' = nan" in text and "(fmi3Discard," in text and "still in StepMode" in text
               for s, text in m.messages)
    again = m.step(Q[5])                                  # StepMode: set a valid input, step again
    twin = Dk3(md3, dir3, "nan-twin")
    assert [twin.step(qk) for qk in Q[:6]][-1] == again and m.get("status", "Int32") == [0]
    twin.close()
    m.close()


def test_wrong_q_length_is_refused_not_a_crash(md3, dir3):
    m = Dk3(md3, dir3, "short")
    m.step(Q[1])
    before = m.get("q", n=3)
    with pytest.raises(FMICallException) as info:        # fmi3SetFloat64 with 2 values for Float64[3]
        m.fmu.setFloat64([m.vr["q"]], [0.1, 0.2])
    assert info.value.status == 3                         # fmi3Error (the loader; pythonfmu3 alone: fmi3OK)
    assert m.get("q", n=3) == before
    assert any(s == 3 and "nothing done" in text for s, text in m.messages)
    pose = m.step(Q[2])                                   # the next valid step goes on
    assert m.get("status", "Int32") == [0] and all(map(math.isfinite, pose))
    m.close()


def test_array_set_does_not_use_pythonfmu3s_reshape(md3, dir3):
    """pythonfmu3 0.3.4's own array setter calls np.reshape(v, newshape=...), which numpy 2.4 removed: the
    FMU sets q without it (this fails, fmi3Fatal, if the FMU falls back to that setter)."""
    from pythonfmu3 import Float64, Fmi3Slave
    from pythonfmu3.enums import Fmi3Causality, Fmi3Variability
    from pythonfmu3.variables import Dimension

    class Probe(Fmi3Slave):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.u = np.zeros(3)
            self.register_variable(Float64("u", causality=Fmi3Causality.input, variability=Fmi3Variability.continuous,
                                           start=np.zeros(3), dimensions=[Dimension(start="3")]))

        def do_step(self, t, dt):
            return True

    probe = Probe(instance_name="probe")
    try:
        probe.set_float64([0], [1.0, 2.0, 3.0])
        default_setter_works = True
    except TypeError:
        default_setter_works = False
    assert default_setter_works == (tuple(int(x) for x in np.__version__.split(".")[:2]) < (2, 4))
    m = Dk3(md3, dir3, "array-set")
    m.fmu.setFloat64([m.vr["q"]], [float(v) for v in Q[3]])
    assert m.get("q", n=3) == [float(v) for v in Q[3]]
    m.close()


def test_a_refused_initialization_makes_every_step_an_error(md3, dir3):
    """fmi3ExitInitializationMode with a posture the FMU has no map of: fmi3Error with the reason; the
    instance is in Terminated after an fmi3Error (FMI 3.0), where a doStep is refused with the reason
    and get reads; fmi3Reset makes it usable again."""
    with pytest.raises(FMICallException) as info:
        Dk3(md3, dir3, "no-map", posture=2)              # this FMU embeds the map of posture 1 only
    assert info.value.status == 3 and "fmi3ExitInitializationMode" in str(info.value)
    fmu = FMU3Slave(guid=md3.guid, unzipDirectory=dir3, modelIdentifier="RRRDirectKinematics3", instanceName="no-map")
    messages = []
    fmu.instantiate(loggingOn=True, logMessage=lambda env, s, c, m: messages.append((int(s), m.decode())))
    vr = {v.name: v.valueReference for v in md3.modelVariables}
    fmu.setInt32([vr["posture"]], [2])
    fmu.enterInitializationMode()
    with pytest.raises(FMICallException) as info:
        fmu.exitInitializationMode()
    assert info.value.status == 3
    assert any(s >= 3 and "posture" in text and "initialization failed" in text for s, text in messages)
    with pytest.raises(FMICallException) as info:
        fmu.doStep(0.0, H)
    assert info.value.status == 3
    assert "fmi3DoStep refused in state Terminated after an fmi3Error" in messages[-1][1] and "posture" in messages[-1][1]
    assert fmu.getInt32([vr["status"]]) == [3]
    fmu.reset()
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(0.0, H)
    fmu.freeInstance()


# ---------------------------------------------------------------------- other hosts' processes
TWO_FMUS = """
    import json, sys
    import numpy as np
    import fmpy
    from fmpy import extract

    fmi2, fmi3, q, X0 = sys.argv[1], sys.argv[2], np.array(json.loads(sys.argv[3])), json.loads(sys.argv[4])
    d2, d3 = str(extract(fmi2)), str(extract(fmi3))
    t = np.arange(len(q)) * 1e-3
    table2 = np.array(list(zip(t, *q.T)), dtype=[("time", float), ("q1", float), ("q2", float), ("q3", float)])
    r2 = fmpy.simulate_fmu(d2, stop_time=len(q) * 1e-3, step_size=1e-3, output_interval=1e-3, input=table2,
                           start_values=dict(zip(("x0", "y0", "phi0"), X0)), output=["x", "y", "phi"])
    where = sys.modules["fmu_src"].__file__
    table3 = np.zeros(len(q), dtype=[("time", float), ("q", float, (3,))])
    table3["time"], table3["q"] = t, q
    r3 = fmpy.simulate_fmu(d3, stop_time=len(q) * 1e-3, step_size=1e-3, output_interval=1e-3, input=table3,
                           start_values={"pose0": X0}, output=["pose"])
    same = bool(np.array_equal(r3["pose"], np.stack([r2[n] for n in ("x", "y", "phi")], axis=1)))
    print(json.dumps({"fmu_src": where, "d2": d2, "rows": len(r3), "same": same}))
"""


def test_after_the_fmi2_fmu_in_a_fresh_process(built, built3, tmp_path):
    """A host that loaded the FMI 2.0 FMU first has its bundled fmu_src (no FMI 3.0 runtime in it):
    the FMI 3.0 FMU finds its own and gives the same poses."""
    from host_support import run_python

    proc = run_python(TWO_FMUS, built.fmu, built3.fmu, json.dumps(Q[:30].tolist()), json.dumps(list(map(float, X0))),
                      cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["fmu_src"].startswith(out["d2"]) and out["rows"] == 31 and out["same"]


def test_a_missing_package_is_named(built3, tmp_path):
    from host_support import run_python

    from fmu_src import requirements as req

    path = tmp_path / "RRRDirectKinematics.fmu"
    with zipfile.ZipFile(built3.fmu) as z, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        for info in z.infolist():
            data = z.read(info)
            if info.filename == f"resources/{req.FILE}":
                data += b"rrr-dk-absent>=1.0  # import rrr_dk_absent\n"
            out.writestr(info, data)
    proc = run_python("import sys, fmpy\ntry:\n    fmpy.simulate_fmu(sys.argv[1], stop_time=0.01, step_size=1e-3)\n"
                      "except Exception as exc:\n    print('fmpy:', exc)\n", path, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "fmpy:" in proc.stdout
    assert "No module named 'rrr_dk_absent' (the FMU needs rrr-dk-absent>=1.0)" in proc.stderr
    assert '-m pip install "rrr-dk-absent>=1.0"' in proc.stderr


# ---------------------------------------------------------------------- the fast lane behind the FMI 3.0 loader
def _core(name):
    """The live FMI 2.0 core (RRRDirectKinematics) of the FMI 3.0 instance ``name`` in this process."""
    import gc
    gc.collect()
    found = [o for o in gc.get_objects()
             if type(o).__name__ == "RRRDirectKinematics" and getattr(o, "instance_name", None) == name]
    assert len(found) == 1, found
    return found[0]


def test_the_fast_lane_serves_the_fmi3_calls_bit_for_bit(md3, dir3, monkeypatch):
    """Behind the FMI 3.0 loader the DK slave's fast lane answers fmi3SetFloat64(q), fmi3DoStep and the
    gets of the outputs (arrays included) without Python: the same outputs, doStep results and time as
    the Python path (RRR_DK_FAST_LANE=0), bit for bit, through an unreachable episode that Python logs
    once each way; a get of ``time`` with the pose goes to Python and reads the lane's steps."""
    outputs = [("pose", "Float64", 3), ("pose_bound", "Float64", 3), ("cond", "Float64", 1),
               ("uncertain_since", "Float64", 1), ("region", "Int32", 1), ("n_real", "Int32", 1),
               ("status", "Int32", 1), ("trust", "Int32", 1), ("near_border", "Boolean", 1),
               ("ambiguous", "Boolean", 1), ("certain", "Boolean", 1), ("out_of_budget", "Boolean", 1)]
    ramp = np.concatenate([np.arange(16), np.arange(14, -1, -1)]) * 0.05
    excursion = np.repeat(Q[100][None], len(ramp), axis=0)
    excursion[:, 1] += ramp
    stream = np.concatenate([Q[1:100], excursion, Q[101:260]])

    def run(m):
        rows = []
        for q in stream:
            m.fmu.setFloat64([m.vr["q"]], [float(v) for v in q])
            done = m.fmu.doStep(m.t, H)
            m.t += H
            rows.append((tuple(done), *(tuple(m.get(n, kind, k)) for n, kind, k in outputs)))
        rows.append(tuple(m.fmu.getFloat64([m.vr["time"], m.vr["pose"]], nValues=4)))
        return rows

    fast = Dk3(md3, dir3, "lane3")
    monkeypatch.setenv("RRR_DK_FAST_LANE", "0")
    slow = Dk3(md3, dir3, "nolane3")
    monkeypatch.delenv("RRR_DK_FAST_LANE")
    rows = run(fast)
    assert rows == run(slow)
    assert rows[-1][0] == pytest.approx(len(stream) * H, abs=1e-12)
    steps, calls = _core("lane3").lane_counts
    assert len(stream) - 6 <= steps < len(stream)          # the episode's changes go to Python (it logs them)
    assert calls > 3 * steps
    assert _core("nolane3").lane_counts == (0, 0)
    for m in (fast, slow):
        texts = [msg for _, msg in m.messages]
        assert sum("no real direct-kinematics solution" in t for t in texts) == 1
        assert sum("ok again" in t for t in texts) == 1
        m.close()
