"""The kinematics core's explicit data and its one-of-each helpers: the identity cache of the kernel
packs (nothing written onto frozen models), the leg rows behind J, K and J_q, the nearest-solution
rule, the one type check and the one wrap."""
import gc

import numpy as np
import pytest

import dynamics as dm
from dynamics._packs import arm_pack, bodies_pack, circle_pack, gains_pack
from dynamics.geometry import geometry
from dynamics.parameters import row_constants
from solver import Manipulator, SolverInputError, dk_all, ik, jacobians, wrap_angle
from solver.checks import check_instance
from solver.direct_kinematics import kernel_constants, nearest_solution
from solver.identity_cache import by_identity


# ------------------------------------------------------------------ explicit data, cached by identity
def test_by_identity_builds_once_per_object_and_forgets_collected_objects():
    built = []

    class Frozen:
        pass

    get = by_identity(lambda obj: built.append(obj) or object())
    a, b = Frozen(), Frozen()
    da = get(a)
    assert get(a) is da and len(built) == 1
    assert get(b) is not da and len(built) == 2
    assert get.cache_size() == 2
    del a, built[:]
    gc.collect()
    assert get.cache_size() == 1
    assert get(b) is get(b)


def test_packs_are_built_once_and_nothing_is_set_on_the_frozen_objects():
    model, params = Manipulator.symmetric(1.0, 0.6, 0.6, 0.3), dm.DynamicParameters(gravity=(0.0, -1.0))
    gains, traj = dm.ComputedTorqueGains.design(), dm.CircleTrajectory()
    before = [dict(vars(o)) for o in (model, params, gains, traj)]
    dk_all(model, [0.1, 0.2, 0.3])
    dm.mass_matrix_task(params, model, [0.45, 0.3, -0.7])
    dm.ControllerStepper(params, model, gains, traj)
    traj.joint(model, 0.2)
    assert [dict(vars(o)) for o in (model, params, gains, traj)] == before
    assert kernel_constants(model) is kernel_constants(model)
    for pack, obj in ((arm_pack, model), (bodies_pack, params), (gains_pack, gains), (circle_pack, traj)):
        assert pack(obj) is pack(obj)
    # an equal but distinct object gets its own (equal) data
    twin = dm.DynamicParameters(gravity=(0.0, -1.0))
    assert twin == params and bodies_pack(twin) is not bodies_pack(params)
    np.testing.assert_array_equal(bodies_pack(twin), bodies_pack(params))


def test_kernel_constants_and_row_constants_are_read_only(model):
    k = kernel_constants(model)
    with pytest.raises(TypeError):
        k["pack"] = None
    w = row_constants(dm.DynamicParameters())["w"]
    with pytest.raises(ValueError):
        w[0] = 1.0


# ------------------------------------------------------------------ one leg row: J, K and J_q agree
def test_leg_rows_give_J_K_and_the_dynamics_J_q(model, rng):
    X = np.column_stack([rng.uniform(0.2, 0.8, 400), rng.uniform(0.1, 0.6, 400), rng.uniform(-1.0, 1.0, 400)])
    q = ik(model, X, 1)
    X, q = X[~np.isnan(q[:, 0])], q[~np.isnan(q[:, 0])]
    assert len(X) > 100
    J, K = jacobians(model, X, q)
    g = geometry(model, (0.0, 0.0), X, q)
    # K_ii = -2 den_i exactly (the same leg row), and J_q = -K^-1 J
    np.testing.assert_array_equal(np.diagonal(K, axis1=-2, axis2=-1), -2.0 * g.den)
    np.testing.assert_allclose(g.Jq, -np.linalg.solve(K, J), rtol=1e-12, atol=1e-12)
    # and J_q maps pose rates to motor rates: finite differences of the IK
    dX = np.array([1e-7, -2e-7, 3e-7])
    dq = wrap_angle(ik(model, X + dX, 1) - ik(model, X - dX, 1)) / 2.0
    np.testing.assert_allclose(np.einsum("nij,j->ni", g.Jq, dX), dq, rtol=0, atol=1e-11)


# ------------------------------------------------------------------ one nearest-solution rule
def test_nearest_solution_is_the_eq19_nearest_real_solution(model, rng):
    w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])
    checked = 0
    for q in rng.uniform(-np.pi, np.pi, (300, 3)):
        sol = dk_all(model, q)
        X_ref = np.array([rng.uniform(0, 1), rng.uniform(0, 0.8), rng.uniform(-np.pi, np.pi)])
        got = nearest_solution(model, q, X_ref, w)
        if not sol.real.any():
            assert np.all(np.isnan(got))
            continue
        cand = sol.poses.real[sol.real]
        d = cand - X_ref
        d[:, 2] = wrap_angle(d[:, 2])
        np.testing.assert_array_equal(got, cand[np.argmin(w[0] * d[:, 0] ** 2 + w[1] * d[:, 1] ** 2
                                                          + w[2] * d[:, 2] ** 2)])
        checked += 1
    assert checked > 50


def test_nearest_pose_dk_follows_the_assembly_mode(model, rng):
    X = np.array([0.45, 0.30, -0.7])
    dk = dm.NearestPoseDK(model, X)
    for k in range(20):                                  # a small motion: the same branch throughout
        Xk = X + k * np.array([1e-3, -5e-4, 2e-3])
        np.testing.assert_allclose(dk(ik(model, Xk, 1)), Xk, atol=1e-9)
    unreachable = next(q for q in rng.uniform(-np.pi, np.pi, (1000, 3)) if not dk_all(model, q).real.any())
    with pytest.raises(SolverInputError, match="real DK solution"):
        dk(unreachable)


# ------------------------------------------------------------------ one type check, one wrap
@pytest.mark.parametrize("call, text", [
    (lambda m: ik("paper", [0.5, 0.3, 0.0]), "model: expected a Manipulator, got str"),
    (lambda m: dk_all(3, [0.1, 0.2, 0.3]), "model: expected a Manipulator or an RPRManipulator"),
    (lambda m: dm.mass_matrix_task(None, m, [0.5, 0.3, 0.0]), "params: expected a DynamicParameters, got NoneType"),
    (lambda m: dm.mass_matrix_task(dm.DynamicParameters(), "m", [0.5, 0.3, 0.0]), "model: expected a Manipulator"),
])
def test_type_checks_name_the_argument(model, call, text):
    with pytest.raises(SolverInputError, match=text):
        call(model)


def test_check_instance_returns_the_value():
    assert check_instance("x", 3, int, "an int") == 3
    with pytest.raises(SolverInputError, match="x: expected an int, got float"):
        check_instance("x", 3.0, int, "an int")


def test_one_wrap_on_both_sides(rng):
    from solver._kernels.linalg import wrap
    a = np.concatenate([rng.uniform(-50, 50, 2000), [np.pi, -np.pi, 0.0, 3 * np.pi, -3 * np.pi]])
    w = wrap_angle(a)
    assert np.all((w > -np.pi) & (w <= np.pi))
    np.testing.assert_array_equal(w, [wrap(x) for x in a])
    assert dm.wrap is wrap_angle
