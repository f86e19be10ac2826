"""The plant and controller FMUs: validation, reference runs, readmes, refusals."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import dynamics  # noqa: F401  (host packages first: the FMUs use them)
import solver
from cosim.fmus import references
from cosim.fmus.builds import build_slave
from cosim.fmus.checks import validate
from cosim.simulation import StepRefusedError, input_table, simulate

ROOT = Path(__file__).resolve().parent.parent
NAMES = ("RRRPlant", "ComputedTorqueController")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("pc")
    return {n: build_slave(n, out) for n in NAMES}


def slave_class(name):
    spec = importlib.util.spec_from_file_location(f"_{name}_doc", ROOT / "fmu_src" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return getattr(mod, name)


@pytest.mark.parametrize("name", NAMES)
def test_validates_and_reproduces_its_reference(fmus, name):
    assert validate(fmus[name]) == []
    got = references.run(name, fmus[name])
    ref = references.read(name)
    assert got.dtype.names == ref.dtype.names and len(got) == len(ref) == references.N + 1
    for col in ref.dtype.names:
        np.testing.assert_allclose(got[col], ref[col], rtol=1e-12, atol=1e-12, err_msg=col)


@pytest.mark.parametrize("name", NAMES)
def test_readme_lists_the_variables_of_the_table(name):
    from cosim.fmus.interface_table import interface_table, replace_table

    text = (ROOT / "fmu_src" / f"{name}.md").read_text()
    assert replace_table(text, name, interface_table(slave_class(name))) == text     # generated, up to date


def test_plant_outputs_are_states_and_consistent():
    cls = slave_class("RRRPlant")
    assert all(v.depends_on == () for v in cls.VARIABLES if v.causality == "output")
    ref = references.read("RRRPlant")
    model = solver.Manipulator.paper()
    X = np.stack([ref["x_true"], ref["y_true"], ref["phi_true"]], axis=1)
    q = np.stack([ref["q1"], ref["q2"], ref["q3"]], axis=1)
    np.testing.assert_allclose(solver.wrap_angle(solver.ik(model, X, 1) - q), 0.0, atol=1e-12)
    assert np.ptp(ref["x_true"]) > 1e-3                      # the torques move the robot


def test_controller_on_its_reference_gives_the_inverse_dynamics():
    from dynamics import CircleTrajectory, DynamicParameters, inverse_dynamics

    ref = references.read("ComputedTorqueController")
    model = solver.Manipulator.paper()
    traj = CircleTrajectory()
    for k in (1, 100, 250, 499):                              # tau held from the sample at t_(k-1)
        t = ref["time"][k - 1]
        X, _, _ = traj.task(t)
        q, dq, ddq = traj.joint(model, t)
        tau = inverse_dynamics(DynamicParameters(), model, q, dq, ddq, X)
        np.testing.assert_allclose([ref[f"tau{i}"][k] for i in (1, 2, 3)], tau, rtol=1e-9, atol=1e-12)


def test_bad_torque_is_refused_and_named(fmus):
    t = np.arange(11) * 1e-3
    tau = np.zeros(11)
    tau[5] = np.nan
    with pytest.raises(StepRefusedError, match="tau2"):
        simulate(fmus["RRRPlant"], stop_time=0.01, step_size=1e-3,
                 inputs=input_table(t, tau1=np.zeros(11), tau2=tau, tau3=np.zeros(11)),
                 start_values=references.start_values())


def test_a_pose_outside_the_tool_space_is_refused(fmus):
    t = np.arange(6) * 1e-3
    far = np.full(6, 5.0)
    with pytest.raises(StepRefusedError, match="outside the tool space"):
        simulate(fmus["ComputedTorqueController"], stop_time=0.005, step_size=1e-3,
                 inputs=input_table(t, x=far, y=far))


@pytest.mark.parametrize("name", NAMES)
def test_bundles_only_what_the_slave_imports(fmus, name):
    import zipfile

    with zipfile.ZipFile(fmus[name]) as z:
        names = set(z.namelist())
    assert "resources/dynamics/steppers.py" in names and "resources/solver/tracker.py" in names
    assert not [n for n in names if n.startswith(("resources/cosim/", "resources/cosim/batch/"))]
    assert "resources/cosim/fmus/checks.py" not in names


def test_plant_outputs_hold_the_initial_state_in_initialization_mode(fmus):
    """A host reads the plant's outputs before fmi2ExitInitializationMode to hand q to the DK FMU: they
    are the initial state's, as soon as Initialization Mode is entered, and follow a parameter set there."""
    from cosim.unit import FMUUnit
    model = solver.Manipulator.paper()
    unit = FMUUnit(fmus["RRRPlant"], "plant")
    try:
        unit.fmu.setupExperiment(startTime=0.0)
        unit.fmu.enterInitializationMode()
        names = ["q1", "q2", "q3", "dq1", "x_true", "y_true", "phi_true"]
        got = unit.get_values(names)
        start = [float(unit.vars[n].start) for n in ("x0", "y0", "phi0")]
        np.testing.assert_allclose(got[4:], start, atol=1e-15)
        np.testing.assert_allclose(got[:3], solver.ik(model, np.array(start), 1), atol=1e-12)
        assert got[3] == 0.0
        unit.set_values({"x0": start[0] + 0.02})                    # a parameter changed in Initialization Mode
        moved = unit.get_values(names)
        assert moved[4] == pytest.approx(start[0] + 0.02, abs=1e-15)
        np.testing.assert_allclose(moved[:3], solver.ik(model, np.array([start[0] + 0.02, *start[1:]]), 1),
                                   atol=1e-12)
        unit.fmu.exitInitializationMode()
        assert unit.get_values(names) == moved                      # the same values after it
    finally:
        unit.close()
