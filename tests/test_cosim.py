"""Co-simulation through fmpy: the paper's Figs 2 and 3 with the three FMUs."""
import numpy as np
import pytest

from cosim import Scenario, simulate_fig3, write_osp_system
from dynamics import (DynamicParameters, joint_velocity_jacobian, pose_velocity_jacobian, rk4, task_space_rhs,
                      total_energy)
from solver import Manipulator, ik, wrap_angle

from cosim_support import fmus, loop  # noqa: F401 (fixtures)




def pose_diff(a, b):
    d = np.abs(np.asarray(a) - np.asarray(b))
    d[..., 2] = np.abs(wrap_angle(np.asarray(a)[..., 2] - np.asarray(b)[..., 2]))
    return d


# ------------------------------------------------------------------ Fig. 2: the closed loop
def test_closed_loop_tracks_the_circle_with_the_exact_model(loop):
    res = loop.run(Scenario())                                      # 2.5 s at 1 ms, Gauss-Seidel
    assert len(res.t) == 2500
    np.testing.assert_array_equal(res.t, np.arange(2500) * 1e-3)    # t0 + k h
    assert res.rms_joint_error(0.5) <= 1e-4
    assert res.max_dk_error() <= 1e-9                                # DK pose == true pose, every step
    assert np.all(res["dk_status"] == 0)
    # the robot starts from rest on the circle and is on the reference afterwards
    ref = np.stack([res["x_ref"], res["y_ref"], res["phi_ref"]], axis=1)
    pose = np.stack([res["x"], res["y"], res["phi"]], axis=1)
    assert np.max(pose_diff(pose[500:], ref[500:])) < 1e-4


def test_closed_loop_with_wrong_masses_stays_stable(loop):
    errors = {}
    for scale in (0.8, 1.2):
        res = loop.run(Scenario(t_end=2.0, plant_mass_scale=scale))
        errors[scale] = res.rms_joint_error(0.5)
        assert res.max_dk_error() <= 1e-9
        e = np.abs(res.joint_error())
        assert np.max(e[-500:]) <= 1.5 * np.max(e[500:1000]) + 1e-6    # no growth: stable
    print(f"RMS joint error after 0.5 s with plant masses x0.8: {errors[0.8]:.3e} rad, "
          f"x1.2: {errors[1.2]:.3e} rad")
    assert all(1e-5 < e < 1e-2 for e in errors.values())


def test_gauss_seidel_beats_jacobi_and_small_steps_beat_large(loop):
    gs = loop.run(Scenario(t_end=1.5))
    jac = loop.run(Scenario(t_end=1.5, order="jacobi"))
    coarse = loop.run(Scenario(t_end=1.5, h=4e-3))
    assert gs.rms_joint_error(0.5) < jac.rms_joint_error(0.5)
    assert gs.rms_joint_error(0.5) < coarse.rms_joint_error(0.5)
    assert jac.max_dk_error() <= 1e-9 and coarse.max_dk_error() <= 1e-9


def test_runs_are_reproducible_after_reset(loop):
    a = loop.run(Scenario(t_end=0.3))
    loop.run(Scenario(t_end=0.2, plant_mass_scale=1.2))
    b = loop.run(Scenario(t_end=0.3))
    for key in ("q1", "tau2", "x", "phi_true"):
        np.testing.assert_array_equal(a[key], b[key])


def test_libcosim_runs_the_same_loop(fmus, loop, tmp_path):
    """The OSP system structure run by DNV libcosim equals our master's Jacobi scheme."""
    from cosim.hosts.libcosim import run_osp_system

    sc = Scenario(t_end=0.4)
    osp = write_osp_system(fmus, tmp_path, sc)
    mine = loop.run(replace_order(sc, "jacobi"))
    res = run_osp_system(osp, n_steps=sc.n_steps, observe=["plant.q1", "plant.q2", "plant.q3", "dk.x",
                                                            "controller.tau1"])
    # libcosim samples after each step: row k is time (k + 1) h; ours: row k is t_k before the step
    for name, ours in (("plant.q1", mine["q1"]), ("plant.q3", mine["q3"]), ("controller.tau1", mine["tau1"])):
        theirs = np.asarray(res[name])
        n = min(len(theirs), len(ours) - 1)
        lag = 1 if name.startswith("plant") else 0
        np.testing.assert_allclose(theirs[:n - 1], ours[lag:n - 1 + lag], rtol=0, atol=1e-9, err_msg=name)


def replace_order(sc, order):
    from dataclasses import replace
    return replace(sc, order=order)


def test_bad_scenarios_are_refused():
    with pytest.raises(ValueError, match="order"):
        Scenario(order="random")
    with pytest.raises(ValueError, match="h"):
        Scenario(h=-1e-3)
    with pytest.raises(ValueError, match="tracker_mode"):
        Scenario(tracker_mode="magic")


# ------------------------------------------------------------------ Fig. 3: dynamics simulation
def _start(model):
    X0 = np.array([0.5, 0.3, 0.1])
    q0 = ik(model, X0, 1)
    dX0 = np.array([0.15, -0.1, 0.3])
    return X0, dX0, q0, joint_velocity_jacobian(model, X0, q0) @ dX0


def test_fig3_with_the_dk_fmu_matches_the_task_space_reference(fmus):
    model = Manipulator.paper()
    params = DynamicParameters()
    X0, dX0, q0, dq0 = _start(model)
    torque = lambda t: np.array([0.05 * np.sin(3 * t), -0.04 * np.cos(2 * t), 0.03 * np.sin(5 * t)])
    t, Q, DQ, XX = simulate_fig3(fmus["RRRDirectKinematics"], params, q0, dq0, 2.0, 1e-3,
                                 tau=lambda t, q, dq: torque(t), X0=X0)
    rhs = task_space_rhs(params, model, 1, tau=lambda t, x: torque(t))
    tt, x = rk4(rhs, 0.0, np.concatenate([X0, dX0]), 1e-3, 2000)
    np.testing.assert_array_equal(t, tt)
    assert np.max(pose_diff(XX, x[:, :3])) <= 1e-6
    assert np.max(np.abs(wrap_angle(Q - ik(model, x[:, :3], 1)))) <= 1e-6


@pytest.mark.parametrize("gravity, start", [((0.0, 0.0), (0.45, 0.30, -np.pi / 4, 0.10, 0.0, 0.5)),
                                            ((0.0, -0.513), (0.45, 0.20, -np.pi / 4, -0.10, 0.35, 0.0))],
                         ids=["g=0", "table-tilted-3deg"])
def test_fig3_passive_motion_conserves_energy(fmus, gravity, start):
    """tau = 0, no friction: RK4 at 1 ms with the DK FMU at every stage keeps the energy to 1e-6."""
    model = Manipulator.paper()
    params = DynamicParameters(friction_active=0.0, friction_elbow=0.0, friction_platform=0.0,
                               gravity=gravity)
    X0, dX0 = np.array(start[:3]), np.array(start[3:])
    q0 = ik(model, X0, 1)
    dq0 = joint_velocity_jacobian(model, X0, q0) @ dX0
    t, Q, DQ, XX = simulate_fig3(fmus["RRRDirectKinematics"], params, q0, dq0, 2.0, 1e-3, X0=X0)
    dX = np.einsum("nij,nj->ni", pose_velocity_jacobian(model, XX, Q), DQ)
    E = total_energy(params, model, XX, dX)
    assert np.max(np.abs(E - E[0])) <= 1e-6 * abs(E[0])
