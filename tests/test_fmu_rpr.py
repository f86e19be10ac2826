"""The 3-RPR's DK FMU: build, validation, the reference run (a non-singular assembly-mode change), and
the same outputs as the in-process tracker."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from cosim.fmus.rpr_build import LOOP_H, LOOP_N, RPR_OUTPUTS, RPR_REFERENCE_RESOLUTION, build_rpr_dk, read_rpr_reference
from experiments.rpr_suite import cusp_loop_path
from solver import MapTensor, Tracker
from solver.rpr import RPR_HOME_POSE, RPRManipulator

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("rpr-fmu")
    return build_rpr_dk(out, resolution=RPR_REFERENCE_RESOLUTION, log=lambda *a: None)


@pytest.fixture(scope="module")
def loop_run(built, tmp_path_factory):
    """The reference run, simulated in a child process (an FMU loaded into this long pytest process
    would share its heap with every FMU the other test files loaded)."""
    out = tmp_path_factory.mktemp("rpr-run") / "run.npy"
    code = ("import sys, numpy as np; from cosim.fmus.rpr_build import run_rpr_loop; from cosim.unit import "
            "exit_process; np.save(sys.argv[2], run_rpr_loop(sys.argv[1])); exit_process(0)")
    proc = subprocess.run([sys.executable, "-c", code, str(built.fmu), str(out)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return np.load(out)


def test_the_fmu_validates_and_declares_leg_lengths(built):
    assert built.problems == [] and validate_fmu(str(built.fmu)) == []
    md = read_model_description(str(built.fmu))
    v = {x.name: x for x in md.modelVariables}
    assert [(n, v[n].causality, v[n].unit) for n in ("rho1", "rho2", "rho3")] == \
        [(n, "input", "m") for n in ("rho1", "rho2", "rho3")]
    assert "posture" not in v and "q1" not in v
    assert (float(v["x0"].start), float(v["y0"].start), float(v["phi0"].start)) == RPR_HOME_POSE
    assert {u.variable.name for u in md.outputs} >= {"x", "y", "phi", "certain", "status"}


def test_the_loop_ends_in_another_assembly_mode_certain_all_the_way(loop_run):
    r = loop_run
    start = np.array([r["x"][0], r["y"][0], r["phi"][0]])
    end = np.array([r["x"][-1], r["y"][-1], r["phi"][-1]])
    joints = np.stack([r["rho1"], r["rho2"], r["rho3"]], axis=1)
    np.testing.assert_array_equal(joints[-1], joints[0])                 # the legs are back
    assert np.linalg.norm(end[:2] - start[:2]) > 0.3                      # the platform is not
    assert r["certain"].all() and np.all(r["status"] == 0)
    np.testing.assert_allclose(start, RPR_HOME_POSE, atol=1e-12)


def test_the_loop_reproduces_the_kept_reference(loop_run):
    ref = read_rpr_reference()
    assert len(ref) == len(loop_run) == LOOP_N + 2
    np.testing.assert_allclose(ref["time"], loop_run["time"], atol=1e-12)
    for name in ("rho1", "rho2", "rho3", "x", "y", "phi"):
        np.testing.assert_allclose(loop_run[name], ref[name], atol=1e-9, err_msg=name)
    for name in RPR_OUTPUTS[3:]:
        np.testing.assert_array_equal(loop_run[name].astype(int), ref[name], err_msg=name)


def test_the_fmu_outputs_what_the_tracker_returns(built, loop_run):
    model = RPRManipulator.zein_wenger_chablat()
    path = cusp_loop_path(model, 1, LOOP_N)
    tr = Tracker(model, MapTensor.load(built.maps[1]))
    tr.reset(path.X[0], path.q[0])
    for k in range(LOOP_N + 1):
        X, info = tr.step(path.q[k], LOOP_H)
        row = loop_run[k + 1]
        np.testing.assert_allclose([row["x"], row["y"], row["phi"]], X, atol=1e-12)
        assert bool(row["certain"]) == info.certain and int(row["status"]) == info.status


#: argv: the FMU, an extraction folder; instantiates and frees it 5 times, collecting garbage each time
REPEATED = r"""
import gc, json, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
folder = extract(sys.argv[1], unzipdir=sys.argv[2])
counts, names = [], []
for k in range(5):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier="RPRDirectKinematics", instanceName=f"i{k}")
    fmu.instantiate()
    namespace = sys.modules["RPRDirectKinematics"].__dict__
    counts.append(sys.getrefcount(namespace))
    names.append("RPRDirectKinematics" in namespace and "instance_name" not in namespace)
    gc.collect()
    fmu.freeInstance()
print("REPEATED " + json.dumps({"counts": counts, "names": names}), flush=True)
"""


def test_repeated_instantiations_keep_the_slave_modules_namespace(built, tmp_path):
    """pythonfmu's wrapper releases a reference to the slave module's globals per instantiation that it
    never took; without fmu_src.wrapper_refs the 3-RPR's namespace was freed at the first one and the
    next garbage collection crashed the host.  Now its count stays level and the namespace intact."""
    proc = subprocess.run([sys.executable, "-c", REPEATED, str(built.fmu), str(tmp_path / "x")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"the host died ({proc.returncode}):\n{proc.stderr[-3000:]}"
    out = json.loads(next(x for x in proc.stdout.splitlines() if x.startswith("REPEATED "))[9:])
    assert all(out["names"]), out
    assert min(out["counts"]) >= out["counts"][0] >= 2, out
