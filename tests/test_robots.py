"""Robot descriptions (solver.robot): the shipped files, every refusal naming its field, the DK FMU of
an irregular robot built from its file and driven by fmpy, and scaled robots tracked without error."""
from __future__ import annotations

import copy
import json
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu
from hypothesis import given, settings
from hypothesis import strategies as st

from cosim.fmus import builds, map_report
from host_support import run_python
from cosim.fmus.robot_build import robot_circle
from solver import Manipulator, MapTensor, Tracker, default_bounds, ik
from solver.geometry_tolerance import built_robot
from solver.robot import Robot, RobotDescriptionError, load_robot, robot_from_dict, start_pose

ROOT = Path(__file__).resolve().parents[1]
IRREGULAR = ROOT / "robots" / "irregular-3rrr.toml"
COARSE = (0.04, float(np.deg2rad(6.0)))


def _irregular() -> dict:
    return tomllib.loads(IRREGULAR.read_text())


def test_the_paper_robot_file_is_the_paper_robot():
    robot = Robot.paper()
    assert robot.model.digest() == Manipulator.paper().digest()
    assert robot.home_pose == (0.5, float(np.sqrt(3.0) / 6.0), 0.0) and robot.home_posture == 1
    assert np.allclose(robot.home_joints, ik(robot.model, np.array(robot.home_pose), 1), atol=0, rtol=0)
    assert robot.resolution == builds.DEFAULT_RESOLUTION


def test_the_example_robot_is_irregular():
    m = load_robot(IRREGULAR).model
    assert len(set(m.l1.tolist())) == 3 and not np.allclose(m.l1, m.l2)
    sides = np.linalg.norm(m.motors - np.roll(m.motors, 1, axis=0), axis=1)
    assert np.ptp(sides) > 0.05                                    # not equilateral
    assert np.linalg.norm(m.platform.mean(axis=0)) > 0.01          # the tool point off the joints' centre


def _edit(path: str, value):
    def apply(d):
        *keys, last = path.split(".")
        target = d
        for k in keys:
            target = target[k]
        if value is KeyError:
            target.pop(last)
        else:
            target[last] = value
    return apply


BAD = [
    ("geometry.l1", [-0.6, 0.6, 0.6], "geometry.l1", "positive lengths"),
    ("geometry.l2", [0.6, 0.0, 0.6], "geometry.l2", "positive lengths"),
    ("geometry.l2", KeyError, "missing l2", "expected the keys"),
    ("geometry.l3", [1, 1, 1], "unknown key l3", "expected motors"),
    ("colour", "red", "unknown key colour", "expected name"),
    ("geometry.motors", [[0, 0], [1, 0]], "geometry.motors", "shape (3, 2)"),
    ("geometry.motors", [[0, 0], [1, 0], [2, 0]], "geometry.motors", "non-collinear"),
    ("geometry.platform", [[0, 0], [0.1, 0.1], [0.2, 0.2]], "geometry.platform", "non-collinear"),
    ("geometry.l1", ["a", 0.6, 0.6], "geometry.l1", "numbers"),
    ("geometry.l1", [float("nan"), 0.6, 0.6], "geometry.l1", "finite"),
    ("home.pose", [3.0, 3.0, 0.0], "home.pose", "a pose the robot reaches in posture 1"),
    ("home.posture", 9, "home.posture", "1..8"),
    ("home.posture", True, "home.posture", "1..8"),
    ("kind", "6-UPS", "kind", "one of 3-RRR, 3-RPR"),
    ("name", "", "name", "non-empty string"),
    ("home", KeyError, "missing home", "needs name, kind"),
    ("map.resolution", [0.0, 2.0], "map.resolution", "m > 0"),
    ("map.resolution", [1e-7, 1e-5], "map.resolution", "at most"),
    ("kind", ["3-RRR"], "kind", "one of 3-RRR"),
    ("geometry.l1", [True, 0.6, 0.6], "geometry.l1", "numbers"),
    ("home.pose", ["0.5", "0.3", "0"], "home.pose", "numbers"),
    ("geometry.l1", [1e200, 1e200, 1e200], "[geometry] or [home]", "real robot"),
    ("dynamics.mass_platform", __import__("datetime").date(2020, 1, 1), "dynamics.mass_platform", "no date"),
    ("tolerance", {"length": -5e-5}, "[tolerance] length", "a finite number >= 0"),
    ("tolerance", {"length": float("nan")}, "[tolerance] length", "a finite number >= 0"),
    ("tolerance", {"l1": 0.2}, "[tolerance] l1", "at most a tenth of the shortest link"),
    ("tolerance", {"lenght": 5e-5}, "[tolerance]: unknown key lenght", "expected length"),
    ("tolerance", 5e-5, "[tolerance]", "a table"),
]


@pytest.mark.parametrize("path, value, field, expected", BAD, ids=[f"{b[0]}={b[1]!r}" for b in BAD])
def test_a_bad_description_is_refused_naming_the_file_the_field_and_what_was_expected(path, value, field, expected):
    data = _irregular()
    data.setdefault("map", {})
    _edit(path, value)(data)
    with pytest.raises(RobotDescriptionError) as info:
        robot_from_dict(data, source="my.toml")
    text = str(info.value)
    assert isinstance(info.value, ValueError) and text.startswith("my.toml: ") and field in text and expected in text


def test_a_singular_home_pose_is_refused():
    """A home pose on a serial singularity: leg 1 stretched straight towards its platform joint."""
    data = _irregular()
    m = load_robot(IRREGULAR).model
    # platform joint 1 at full reach from motor 1, phi 0: the tool point is that joint minus its offset
    direction = np.array([0.6, 0.8])
    joint = m.motors[0] + direction * (m.l1[0] + m.l2[0])
    data["home"]["pose"] = [*(joint - m.platform[0]).tolist(), 0.0]
    with pytest.raises(RobotDescriptionError, match=r"home\.pose.*(singular|reaches)"):
        robot_from_dict(data, source="my.toml")


def test_the_command_line_refuses_a_negative_l1_without_a_traceback(tmp_path):
    bad = tmp_path / "neg.toml"
    bad.write_text(IRREGULAR.read_text().replace("l1 = [0.62,", "l1 = [-0.62,"))
    proc = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--robot", str(bad), "--only",
                           "RRRDirectKinematics", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and f"{bad}: geometry.l1 = [-0.62" in proc.stderr
    assert not (tmp_path / "out").exists()                          # nothing built from a bad file


# ---------------------------------------------------------------------- the DK FMU of the example robot
#: argv: FMU, poses JSON file, joints JSON file; runs the robot's circle through fmpy and prints the poses
DRIVE = r"""
import json, sys
import numpy as np
from fmpy import simulate_fmu
X, q = np.array(json.load(open(sys.argv[2]))), np.array(json.load(open(sys.argv[3])))
h = 1e-3
table = np.array([(k * h, *q[k]) for k in range(len(q))], dtype=[("time", float), ("q1", float), ("q2", float),
                                                                   ("q3", float)])
res = simulate_fmu(sys.argv[1], stop_time=(len(q) - 1) * h, step_size=h, output_interval=h, input=table,
                   start_values={"x0": X[0, 0], "y0": X[0, 1], "phi0": X[0, 2], "posture": int(sys.argv[4])},
                   output=["x", "y", "phi", "certain", "status", "x_bound", "y_bound", "phi_bound"])
print("DRIVE " + json.dumps({k: res[k].tolist() for k in ("x", "y", "phi", "certain", "status", "x_bound", "y_bound",
                                                          "phi_bound")}))
"""


def _drive(script: str, marker: str, fmu, X, q, posture: int, tmp: Path):
    """Run the fmpy driver ``script`` on ``fmu`` along poses ``X`` / joints ``q`` in a child; its JSON output."""
    (tmp / "X.json").write_text(json.dumps(X.tolist()))
    (tmp / "q.json").write_text(json.dumps(q.tolist()))
    proc = subprocess.run([sys.executable, "-c", script, str(fmu), str(tmp / "X.json"), str(tmp / "q.json"),
                           str(posture)], capture_output=True, text=True, timeout=600, cwd=tmp)
    line = next((x for x in proc.stdout.splitlines() if x.startswith(marker + " ")), None)
    assert line is not None, proc.stderr[-3000:]
    return json.loads(line[len(marker) + 1:])


@pytest.fixture(scope="module")
def irregular_fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("robot-fmu")
    robot = load_robot(IRREGULAR)
    logs: list = []
    result = builds.build_dk(out, postures=(3,), resolution=COARSE, robot=robot, log=logs.append)
    return robot, result, logs


def test_the_dk_fmu_of_a_robot_file_carries_it_and_starts_at_its_home(irregular_fmu):
    robot, result, _ = irregular_fmu
    assert result.problems == [] and validate_fmu(str(result.fmu)) == []
    md = read_model_description(str(result.fmu))
    v = {x.name: x for x in md.modelVariables}
    X0 = start_pose(robot, 3)
    assert [float(v[n].start) for n in ("x0", "y0", "phi0")] == list(X0) and int(v["posture"].start) == 3
    assert np.allclose([float(v[n].start) for n in ("q1", "q2", "q3")], ik(robot.model, np.array(X0), 3), atol=1e-12)
    assert robot.digest in md.description and robot.name in md.description
    # [tolerance]: length 5e-5 m, l1 2e-5 m; the FMU takes one half-width, the largest
    assert float(v["geometry_tolerance"].start) == 5e-5 == max(robot.tolerance.widths.values())
    with zipfile.ZipFile(result.fmu) as z:
        assert json.loads(z.read("resources/robot.json")) == robot.description
        assert z.read("resources/robot.toml") == IRREGULAR.read_bytes()


def test_the_build_reports_the_border_volume_and_warns_when_the_map_is_coarse(irregular_fmu):
    """A 40 mm / 6 deg map of the example robot: most of its reachable nodes lie near a border (warned);
    the same robot at its default resolution (the loop's map, cached) stays under the bound."""
    logs = " | ".join(map(str, irregular_fmu[2]))
    share = float(logs.split("map posture 3: border volume ")[1].split(" %")[0])
    assert share > 100 * map_report.COARSE_BORDER and "warning: map posture 3 is coarse for 'irregular-3rrr'" in logs
    cells = int(re.search(r"map posture 3: border volume [^|]*?; (\d+) cusp cells", logs).group(1))
    assert cells > 0 and f"holds cusps of the singular surface (posture 3: {cells} cells" in logs
    from solver import cached_map

    robot = load_robot(IRREGULAR)
    fine = cached_map(robot.model, 1, step=(robot.resolution[0],) * 2 + (robot.resolution[1],))
    assert fine.border_fraction() < map_report.COARSE_BORDER


def test_the_dk_fmu_of_a_robot_file_tracks_that_robot(irregular_fmu, tmp_path):
    robot, result, _ = irregular_fmu
    X, q = robot_circle(robot, 3, 300)
    assert q is not None
    out = _drive(DRIVE, "DRIVE", result.fmu, X, q, 3, tmp_path)
    got = np.column_stack([out["x"], out["y"], out["phi"]])
    assert got.shape == X.shape
    # fmpy records the initial outputs, then after each doStep those of the input of its start: row k + 1
    # is the pose of q[k]
    assert float(np.max(np.abs(got[0] - X[0]))) <= 1e-9 and float(np.max(np.abs(got[1:] - X[:-1]))) <= 1e-9
    assert all(out["certain"]) and set(out["status"]) == {0}
    # bit for bit the in-process tracker on the map the FMU embeds, with the FMU's options
    with zipfile.ZipFile(result.fmu) as z:
        (tmp_path / "map.npz").write_bytes(z.read("resources/maps/posture3.npz"))
        md = read_model_description(str(result.fmu))
    start = {v.name: float(v.start) for v in md.modelVariables if v.name.startswith("start_tolerance")}
    tracker = Tracker(robot.model, MapTensor.load(tmp_path / "map.npz"), singular_tol=1e-4,
                      start_tolerance=(start["start_tolerance_linear"],) * 2 + (start["start_tolerance_angular"],),
                      geometry_tolerance=5e-5)
    tracker.reset(X[0], q[0])
    steps = [tracker.step(q[k], 1e-3) for k in range(1, len(q) - 1)]
    ours = np.array([x for x, _ in steps])
    assert np.array_equal(ours, got[2:]), float(np.max(np.abs(ours - got[2:])))
    # the bounds: the FMU's kernels are compiled for a generic CPU, ours natively: equal up to rounding (a
    # tube whose inflation ends a round earlier in one of them gives a slightly different bound)
    bounds = np.column_stack([out["x_bound"], out["y_bound"], out["phi_bound"]])[2:]
    ref = np.array([info.pose_bound for _, info in steps])
    same = np.all(np.isclose(bounds, ref, rtol=1e-9, atol=0.0), axis=1)
    assert np.allclose(bounds, ref, rtol=1e-2, atol=0.0) and same.mean() >= 0.9, same.mean()


def test_the_dk_fmu_holds_for_the_robot_as_built(irregular_fmu, tmp_path):
    """The example robot's circle read from a robot at corners of its [tolerance] box (its own inverse
    kinematics): the FMU, at its default geometry_tolerance, stays certain and each bound holds the built
    robot's pose; at geometry_tolerance = 0 (the model alone) some certain bound misses it."""
    robot, result, _ = irregular_fmu
    X, _ = robot_circle(robot, 3, 300)
    rng = np.random.default_rng(5)
    q = ik(built_robot(robot.model, robot.tolerance, rng, corner=True), X, 3)
    misses = {}
    for value in (None, 0.0):
        script = DRIVE if value is None else DRIVE.replace('"posture": int(sys.argv[4])}',
                                                           '"posture": int(sys.argv[4]), "geometry_tolerance": 0.0}')
        out = _drive(script, "DRIVE", result.fmu, X, q, 3, tmp_path)
        got = np.column_stack([out["x"], out["y"], out["phi"]])[1:]
        bound = np.column_stack([out["x_bound"], out["y_bound"], out["phi_bound"]])[1:]
        certain = np.array(out["certain"][1:], bool)
        miss = certain & np.any(np.abs(got - X[:-1]) > bound, axis=1)
        misses[value] = int(miss.sum())
        if value is None:
            assert certain.all() and misses[value] == 0
    assert misses[0.0] > 0, misses


# ---------------------------------------------------------------------- any robot, any scale
def _random_robot(draw_seed: int, scale: float) -> dict:
    """An irregular 3-RRR about the unit robot, scaled: a perturbed base triangle, unequal legs, an
    off-centre platform; home at the base's centroid."""
    rng = np.random.default_rng(draw_seed)
    motors = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.866]]) + rng.uniform(-0.08, 0.08, (3, 2))
    l1, l2 = rng.uniform(0.5, 0.7, 3), rng.uniform(0.5, 0.7, 3)
    angles = np.deg2rad([210, 330, 90]) + rng.uniform(-0.2, 0.2, 3)
    platform = rng.uniform(0.13, 0.2, 3)[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    platform += rng.uniform(-0.03, 0.03, 2)
    home = [*(motors.mean(axis=0) * scale).tolist(), float(rng.uniform(-0.1, 0.1))]
    return {"name": f"random-{draw_seed}", "kind": "3-RRR",
            "geometry": {"motors": (motors * scale).tolist(), "l1": (l1 * scale).tolist(), "l2": (l2 * scale).tolist(),
                         "platform": (platform * scale).tolist()},
            "home": {"pose": home, "posture": 1}}


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.sampled_from([0.1, 1.0, 4.0]), posture=st.integers(1, 8))
def test_random_robots_at_several_scales_track_a_circle_without_error(seed, scale, posture):
    """IK and DK agree, a coarse map builds and the tracker follows a circle about the start pose of
    ``posture`` (away from singularities) with 0 errors, certain all the way."""
    robot = robot_from_dict(_random_robot(seed, scale))
    X, q = robot_circle(robot, posture, 200)
    if q is None:
        return                                        # the circle meets a singularity: not this property's case
    step = (robot.resolution[0] * 4,) * 2 + (float(np.deg2rad(6.0)),)
    b = default_bounds(robot.model, step)
    shape = tuple(int(round((b[i, 1] - b[i, 0]) / step[i])) + 1 for i in range(2)) + (60,)
    mt = MapTensor.build(robot.model, posture, bounds=b, shape=shape, rule="aspect")
    tracker = Tracker(robot.model, mt)
    tracker.reset(X[0], q[0])
    for k in range(1, len(q)):
        pose, info = tracker.step(q[k], 1e-3)
        assert np.max(np.abs(pose - X[k])) <= 1e-9 * max(scale, 1.0), (seed, scale, posture, k)
        assert info.certain, (seed, scale, posture, k)


# ---------------------------------------------------------------------- the closed loop of the example robot
@pytest.fixture(scope="module")
def robot_loop(tmp_path_factory):
    """``python -m cosim --robot robots/irregular-3rrr.toml``, its FMUs and results in a temporary folder."""
    tmp = tmp_path_factory.mktemp("robot-loop")
    proc = subprocess.run([sys.executable, "-m", "cosim", "--robot", str(IRREGULAR), "--build-dir", str(tmp / "build"),
                           "--out", str(tmp / "results"), "--no-plots"], capture_output=True, text=True, timeout=1800,
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return tmp, proc.stdout


def test_the_closed_loop_of_the_example_robot_tracks_its_circle(robot_loop):
    tmp, stdout = robot_loop
    rms = float(stdout.split("RMS joint tracking error after 0.5 s: ")[1].split()[0])
    pose = float(stdout.split("largest |DK pose - true pose|: ")[1].split(";")[0])
    assert rms <= 1e-4 and pose <= 1e-9, stdout
    from cosim.fmus.robot_build import fmu_robot

    robot = load_robot(IRREGULAR)
    for name in ("RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"):
        carried = fmu_robot(tmp / "build" / f"{name}.fmu")
        assert carried is not None and carried.digest == robot.digest, name
    header = (tmp / "results" / "closed_loop.csv").read_text().splitlines()[0]
    assert "x_true" in header


ECOS_RUN = r"""
import json, sys
import numpy as np
from ecospy import EcosSimulation
sim = EcosSimulation(ssp_path=sys.argv[1], step_size=1e-3)
sim.init(parameter_set="initial")
names = [f"dk::{v}" for v in ("x", "y", "phi")] + [f"plant::{v}" for v in ("x_true", "y_true", "phi_true")] + \
        [f"controller::{v}" for v in ("q1_ref",)] + [f"plant::q1"]
rows = []
for _ in range(int(sys.argv[2])):
    sim.step()
    rows.append([sim.get_real(v) for v in names])
sim.terminate()
sim.free()
print("ECOS " + json.dumps(rows), flush=True)
"""


def test_the_example_robots_ssp_runs_in_ecos(robot_loop):
    """The robot's SSP (its three FMUs, its start values) in Ecos: the DK pose is the true pose at every
    step and the plant follows the reference after the ramp."""
    tmp, _ = robot_loop
    probe = run_python("import ecospy", cwd=tmp)
    if probe.returncode != 0:
        pytest.skip("Ecos unavailable (pip install ecospy; apt-get install libtbb12): "
                    + probe.stderr.strip().splitlines()[-1])
    proc = run_python(ECOS_RUN, tmp / "build" / "RRRClosedLoop.ssp", 1000, cwd=tmp, timeout=900,
                      tmpdir=tmp)                             # Ecos extracts the SSP there (pytest cleans it)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("ECOS ")), None)
    assert line is not None, proc.stderr[-3000:]
    rows = np.array(json.loads(line[5:]))
    dk, true = rows[:, 0:3], rows[:, 3:6]
    assert np.all(np.isfinite(rows)) and float(np.max(np.abs(dk - true))) <= 1e-9
    assert float(np.max(np.abs(rows[600:, 6] - rows[600:, 7]))) <= 1e-3     # q1 follows its reference (2.5e-4)


def test_a_batch_runs_the_example_robot(robot_loop, tmp_path):
    """``python -m cosim.batch --robot FILE``: every run starts on the robot's circle (its base), sweeps as usual."""
    tmp, _ = robot_loop
    proc = subprocess.run([sys.executable, "-m", "cosim.batch", "--robot", str(IRREGULAR), "--fmu-dir",
                           str(tmp / "build"), "--serial", "--sweep", "bandwidth=30,60", "--t-end", "0.6", "--out",
                           str(tmp_path), "--no-plot", "--strict"], capture_output=True, text=True, timeout=900,
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2/2 runs ok" in proc.stdout
    meta = json.loads((tmp_path / "batch_meta.json").read_text())
    assert meta["robot"] == str(IRREGULAR) and meta["base"]["radius"] < 0.06       # the robot's circle, not 0.25 m
    bad = tmp_path / "neg.toml"
    bad.write_text(IRREGULAR.read_text().replace("mass_platform = 0.52", "mass_platform = -0.52"))
    proc = subprocess.run([sys.executable, "-m", "cosim.batch", "--robot", str(bad), "--serial", "--out",
                           str(tmp_path / "bad")], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 2 and "mass_platform" in proc.stderr and "Traceback" not in proc.stderr


def test_the_figures_of_the_example_robot(robot_loop, tmp_path):
    """``python -m experiments --robot FILE figures``: the cross-sections (Figs 13-15) and the robot's own
    circle tracked (Figs 16-18) from its map (the one the loop's DK FMU embeds, from the map cache)."""
    proc = subprocess.run([sys.executable, "-m", "experiments", "--robot", str(IRREGULAR), "figures", "--out",
                           str(tmp_path)], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    made = sorted(p.name for p in tmp_path.glob("*.png"))
    assert len(made) == 6 and {"fig16_circle.png", "fig17_all_branches.png", "fig18_tracked.png"} <= set(made), made


def test_the_build_constant_is_python_for_any_name():
    """BUILD_ROBOT is written into the slaves' source as Python: a name outside the BMP and quotes survive."""
    from cosim.fmus.robot_build import robot_constant, with_robot_constant

    data = _irregular()
    data["name"] = 'robot "\\ 😀'
    constant = robot_constant(robot_from_dict(data), 1, loop=True)
    text = with_robot_constant("x = 1\nBUILD_ROBOT = None\n", constant, "test")
    namespace: dict = {}
    exec(compile(text, "test", "exec"), namespace)
    assert namespace["BUILD_ROBOT"] == constant and namespace["BUILD_ROBOT"]["name"].encode("utf-8")


@pytest.mark.parametrize("key, value, expected", [
    ("mass_platform", -0.5, "mass_platform"), ("inertia_distal", [0.006, 0.0, 0.007], "inertia_distal"),
    ("mass_platform", True, "mass_platform"), ("gravity", [True, 0.0], "gravity"), ("mass_platform", "1.0", "mass_platform"),
    ("com_platform", [0.0], "com_platform"), ("colour", 1, "colour"), ("gravity", KeyError, "missing gravity")])
def test_bad_dynamics_are_refused_naming_the_key(key, value, expected):
    from dynamics import DynamicParameters

    data = _irregular()
    _edit(f"dynamics.{key}", value)(data)
    with pytest.raises(RobotDescriptionError) as info:
        DynamicParameters.from_robot(robot_from_dict(data, source="my.toml"))
    assert str(info.value).startswith("my.toml: [dynamics]") and expected in str(info.value)
    del data["dynamics"]
    with pytest.raises(RobotDescriptionError, match=r"\[dynamics\].*needs"):
        DynamicParameters.from_robot(robot_from_dict(data, source="my.toml"))


#: argv: FMI 3.0 FMU, poses JSON, joints JSON, posture; the pose after each step through FMU3Slave
DRIVE3 = r"""
import json, sys
import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi3 import FMU3Slave
md = read_model_description(sys.argv[1])
vr = {v.name: v.valueReference for v in md.modelVariables}
X, q = np.array(json.load(open(sys.argv[2]))), np.array(json.load(open(sys.argv[3])))
fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier="RRRDirectKinematics3",
                instanceName="robot3")
fmu.instantiate()
fmu.setFloat64([vr["pose0"]], [float(v) for v in X[0]])
fmu.setInt32([vr["posture"]], [int(sys.argv[4])])
fmu.setFloat64([vr["q"]], [float(v) for v in q[0]])
fmu.enterInitializationMode()
fmu.exitInitializationMode()
out = []
for k in range(1, len(q)):
    fmu.setFloat64([vr["q"]], [float(v) for v in q[k]])
    fmu.doStep((k - 1) * 1e-3, 1e-3)
    out.append(fmu.getFloat64([vr["pose"]], nValues=3))
print("DRIVE3 " + json.dumps(out), flush=True)
import os; os._exit(0)
"""


def test_the_fmi3_dk_fmu_of_a_robot_file(tmp_path):
    """``build_fmu.py --fmi 3 --robot``: the FMI 3.0 DK FMU of the example robot validates, starts at the
    robot's start pose and tracks its circle like the FMI 2.0 one."""
    from cosim.fmus import fmi3_build

    robot = load_robot(IRREGULAR)
    result = fmi3_build.build_dk3(tmp_path / "fmu3", postures=(3,), resolution=COARSE, robot=robot,
                                  log=lambda *a: None)
    assert result.problems == []
    md = read_model_description(str(result.fmu))
    v = {x.name: x for x in md.modelVariables}
    X0 = start_pose(robot, 3)
    assert [float(x) for x in v["pose0"].start.split()] == list(X0) and robot.digest in md.description
    assert np.allclose([float(x) for x in v["q"].start.split()], ik(robot.model, np.array(X0), 3), atol=1e-12)
    X, q = robot_circle(robot, 3, 200)
    assert float(np.max(np.abs(np.array(_drive(DRIVE3, "DRIVE3", result.fmu, X, q, 3, tmp_path)) - X[1:]))) <= 1e-9


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.sampled_from([0.1, 1.0, 4.0]), posture=st.integers(1, 8))
def test_the_dk_fmu_of_a_random_description_validates_and_equals_the_tracker(tmp_path_factory, seed, scale, posture):
    """A random irregular description, written as TOML and built like a user's: the DK FMU validates with no
    message and, along a circle of its robot, returns the in-process tracker's poses bit for bit."""
    data = _random_robot(seed, scale)
    robot = robot_from_dict(data)
    X, q = robot_circle(robot, posture, 120)
    if q is None:
        return                                        # the circle meets a singularity: not this property's case
    tmp = tmp_path_factory.mktemp("random-robot")
    result = builds.build_dk(tmp / "fmu", postures=(posture,), resolution=(robot.resolution[0] * 4, COARSE[1]),
                             robot=robot, log=lambda *a: None)
    assert result.problems == [] and validate_fmu(str(result.fmu)) == []
    out = _drive(DRIVE, "DRIVE", result.fmu, X, q, posture, tmp)
    got = np.column_stack([out["x"], out["y"], out["phi"]])
    with zipfile.ZipFile(result.fmu) as z:
        (tmp / "map.npz").write_bytes(z.read(f"resources/maps/posture{posture}.npz"))
    tracker = Tracker(robot.model, MapTensor.load(tmp / "map.npz"), singular_tol=1e-4)
    tracker.reset(X[0], q[0])
    ours = np.array([tracker.step(q[k], 1e-3)[0] for k in range(1, len(q) - 1)])
    assert np.array_equal(ours, got[2:]), (seed, scale, posture)
    assert float(np.max(np.abs(got[1:] - X[:-1]))) <= 1e-9 * max(scale, 1.0)


def test_a_3rpr_description_builds_its_dk_fmu(tmp_path):
    """``kind = "3-RPR"``: the description of the shipped 3-RPR, built with ``--robot`` like a user's (its map
    over its whole tool space, coarse here): the FMU validates, starts at the home pose, carries the
    description, and runs the cusp loop like the in-process tracker on its map, bit for bit."""
    from cosim.fmus.rpr_build import build_rpr_dk
    from experiments.rpr_suite import cusp_loop_path
    from solver.rpr import RPR_HOME_POSE, RPRManipulator

    shipped = RPRManipulator.zein_wenger_chablat().to_dict()
    path = tmp_path / "zwc.toml"
    geometry = "\n".join(f"{k} = {json.dumps(shipped[k])}" for k in ("base", "platform", "rho_min", "rho_max"))
    path.write_text(f'name = "my-3rpr"\nkind = "3-RPR"\n[geometry]\n{geometry}\n[home]\npose = '
                    f"{json.dumps(list(RPR_HOME_POSE))}\n")
    proc = subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--robot", str(path), "--resolution",
                           "100mm,6deg", "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=900,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    fmu = tmp_path / "out" / "RPRDirectKinematics.fmu"
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    v = {x.name: x for x in md.modelVariables}
    robot = load_robot(path)
    assert [float(v[n].start) for n in ("x0", "y0", "phi0")] == list(RPR_HOME_POSE) and robot.digest in md.description
    code = ("import sys, numpy as np; from cosim.fmus.rpr_build import run_rpr_loop; "
            "np.save(sys.argv[2], np.column_stack([run_rpr_loop(sys.argv[1])[k] for k in ('x', 'y', 'phi')])); "
            "import os; os._exit(0)")
    run = subprocess.run([sys.executable, "-c", code, str(fmu), str(tmp_path / "run.npy")], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert run.returncode == 0, run.stderr[-3000:]
    got = np.load(tmp_path / "run.npy")
    with zipfile.ZipFile(fmu) as z:
        (tmp_path / "map.npz").write_bytes(z.read("resources/maps/posture1.npz"))
    loop = cusp_loop_path(robot.model, 1, 100)
    tracker = Tracker(robot.model, MapTensor.load(tmp_path / "map.npz"), singular_tol=1e-4)
    tracker.reset(loop.X[0], loop.q[0])
    ours = np.array([tracker.step(loop.q[k], 1e-2)[0] for k in range(1, len(loop.q))])
    assert np.array_equal(ours, got[2:len(loop.q) + 1]), float(np.max(np.abs(ours - got[2:len(loop.q) + 1])))
