"""The compiled dynamics kernels (dynamics/_kernel.py) against the numpy reference (dynamics/model.py).

Every public dynamics function runs the kernel; its numpy implementation is
kept as ``_reference_<name>``.  Here the two are compared on many random
configurations in all eight postures (away from singularities, where both are
accurate), with parameters that exercise every term; the single-configuration
path must equal the batch path to the last bit (it is a batch of one), the
compiled RK4 loop the generic one, and the errors the reference's.
"""
import numpy as np
import pytest

from solver import SolverInputError, ik, singularity_measures
from dynamics import _kernel
from dynamics import model as dm
from dynamics.control import (ComputedTorqueGains, _computed_torque, _reference__computed_torque,
                              _reference_computed_torque, computed_torque, wrap)
from dynamics.integrate import NearestPoseDK, joint_space_rhs, rk4, rk4_step, task_space_rhs

#: kernel vs reference, relative to the largest entry of each result
REL = 1e-12
#: configurations kept: both singularity measures above this (0 singular, 1 far)
REGULAR = 0.05
N_PER_POSTURE = 60

TASK = ["mass_matrix_task", "coriolis_task", "gravity_task", "friction_task", "generalized_force_task",
        "forward_dynamics_task", "inverse_dynamics_task"]
JOINT = ["mass_matrix", "coriolis", "gravity", "friction", "forward_dynamics", "inverse_dynamics"]


def _params(kind):
    if kind == "default+gravity":
        return dm.DynamicParameters(gravity=(0.7, -9.81), com_platform=(0.012, -0.02))
    rng = np.random.default_rng(7)          # every per-leg field different
    return dm.DynamicParameters(
        mass_proximal=rng.uniform(0.1, 1.0, 3), inertia_proximal=rng.uniform(1e-3, 2e-2, 3),
        com_proximal=rng.uniform(-0.1, 0.6, 3), mass_distal=rng.uniform(0.1, 1.0, 3),
        inertia_distal=rng.uniform(1e-3, 2e-2, 3), com_distal=rng.uniform(-0.1, 0.6, 3),
        mass_platform=1.3, inertia_platform=7e-3, com_platform=(-0.03, 0.05),
        rotor_inertia=rng.uniform(0.0, 5e-3, 3), friction_active=rng.uniform(0.0, 0.05, 3),
        friction_elbow=rng.uniform(0.0, 0.01, 3), friction_platform=rng.uniform(0.0, 0.01, 3),
        gravity=(-2.0, -9.81))


@pytest.fixture(scope="module", params=["default+gravity", "random-per-leg"])
def params(request):
    return _params(request.param)


@pytest.fixture(scope="module")
def configs(model):
    """Per posture: regular configurations X, q with rates, accelerations and torques."""
    rng = np.random.default_rng(20261122)
    out = {}
    for posture in range(1, 9):
        X = np.column_stack([rng.uniform(-0.2, 1.2, 60000), rng.uniform(-0.3, 1.1, 60000),
                             rng.uniform(-np.pi, np.pi, 60000)])
        q = ik(model, X, posture)
        ok = ~np.isnan(q[:, 0])
        X, q = X[ok], q[ok]
        sm = singularity_measures(model, X, q)
        keep = (sm.type1 > REGULAR) & (sm.type2 > REGULAR)
        X, q = X[keep][:N_PER_POSTURE], q[keep][:N_PER_POSTURE]
        assert len(X) == N_PER_POSTURE, posture
        n = len(X)
        dX = rng.normal(size=(n, 3)) * [0.4, 0.4, 1.5]
        dq = np.einsum("...ij,...j->...i", dm.joint_velocity_jacobian(model, X, q), dX)
        out[posture] = dict(X=X, q=q, dX=dX, dq=dq, ddX=rng.normal(size=(n, 3)) * 3.0,
                            ddq=rng.normal(size=(n, 3)) * 10.0, tau=rng.normal(size=(n, 3)))
    return out


def _rel(a, b):
    """Largest |a - b| relative to the largest |b|, per configuration."""
    a, b = np.asarray(a), np.asarray(b)
    a, b = a.reshape(len(a), -1), b.reshape(len(b), -1)
    return np.max(np.abs(a - b), axis=1) / np.max(np.abs(b), axis=1)


def _task_args(name, c):
    return {"mass_matrix_task": (c["X"],), "gravity_task": (c["X"],), "coriolis_task": (c["X"], c["dX"]),
            "friction_task": (c["X"], c["dX"]), "generalized_force_task": (c["X"], c["dX"], c["tau"]),
            "forward_dynamics_task": (c["X"], c["dX"], c["tau"]),
            "inverse_dynamics_task": (c["X"], c["dX"], c["ddX"])}[name]


def _joint_args(name, c):
    return {"mass_matrix": (c["q"], c["X"]), "gravity": (c["q"], c["X"]), "coriolis": (c["q"], c["dq"], c["X"]),
            "friction": (c["q"], c["dq"], c["X"]), "forward_dynamics": (c["q"], c["dq"], c["X"], c["tau"]),
            "inverse_dynamics": (c["q"], c["dq"], c["ddq"], c["X"])}[name]


# ---------------------------------------------------------------------------- kernel == reference
@pytest.mark.parametrize("posture", range(1, 9))
def test_task_space_kernels_equal_reference(model, params, configs, posture):
    c = configs[posture]
    worst = {}
    for name in TASK:
        args = _task_args(name, c)
        fast = getattr(dm, name)(params, model, *args, posture=posture)
        ref = getattr(dm, f"_reference_{name}")(params, model, *args, posture=posture)
        assert fast.shape == ref.shape
        worst[name] = _rel(fast, ref).max()
        # a single configuration is a batch of one: the same numbers to the last bit
        for k in range(0, len(c["X"]), 7):
            single = getattr(dm, name)(params, model, *(a[k] for a in args), posture=posture)
            np.testing.assert_array_equal(single, fast[k])
    print(f"\n[kernel vs reference, task space, posture {posture}] " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    assert max(worst.values()) <= REL, worst


@pytest.mark.parametrize("posture", range(1, 9))
def test_joint_space_kernels_equal_reference(model, params, configs, posture):
    c = configs[posture]
    worst = {}
    for name in JOINT:
        args = _joint_args(name, c)
        fast = getattr(dm, name)(params, model, *args)
        ref = getattr(dm, f"_reference_{name}")(params, model, *args)
        assert fast.shape == ref.shape
        worst[name] = _rel(fast, ref).max()
        for k in range(0, len(c["X"]), 7):
            np.testing.assert_array_equal(getattr(dm, name)(params, model, *(a[k] for a in args)), fast[k])
    print(f"\n[kernel vs reference, joint space, posture {posture}] " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    assert max(worst.values()) <= REL, worst


@pytest.mark.parametrize("posture", [1, 4, 8])
def test_computed_torque_kernel_equals_reference(model, params, configs, posture):
    c = configs[posture]
    gains = ComputedTorqueGains.design(40.0, 0.9)
    rng = np.random.default_rng(posture)
    # desired angles far enough to wrap: q_d - q up to +-4 rad
    q_d = c["q"] + rng.uniform(-4.0, 4.0, c["q"].shape)
    args = (c["q"], c["dq"], c["X"], q_d, c["dq"] + 0.1, c["ddq"])
    fast = computed_torque(params, model, gains, *args)
    assert _rel(fast, _reference_computed_torque(params, model, gains, *args)).max() <= REL
    assert _rel(_computed_torque(params, model, gains, *args),
                _reference__computed_torque(params, model, gains, *args)).max() <= REL
    for k in range(0, len(q_d), 5):
        np.testing.assert_array_equal(computed_torque(params, model, gains, *(a[k] for a in args)), fast[k])
    # the law itself: tau = inverse dynamics of ddq_d + Kd de + Kp wrap(e)
    v = args[5] + gains.kd * (args[4] - args[1]) + gains.kp * wrap(q_d - c["q"])
    np.testing.assert_allclose(fast, dm.inverse_dynamics(params, model, c["q"], c["dq"], v, c["X"]),
                               rtol=1e-13, atol=1e-13)


def test_right_hand_sides_equal_reference(model, params, configs):
    for posture in (1, 6):
        c = configs[posture]
        f = task_space_rhs(params, model, posture, c["tau"][0])
        for k in range(0, len(c["X"]), 3):
            x = np.concatenate([c["X"][k], c["dX"][k]])
            ref = dm._reference_forward_task(params, model, c["X"][k], c["q"][k], c["dX"][k], c["tau"][0])
            d = f(0.0, x)
            np.testing.assert_array_equal(d[:3], c["dX"][k])
            assert _rel(d[None, 3:], ref[None]).max() <= REL
        # batch states go through the checked numpy route and the batch kernel
        xb = np.concatenate([c["X"], c["dX"]], axis=1)
        db = f(0.0, xb)
        np.testing.assert_array_equal(db[5], f(0.0, xb[5]))
        # joint space with the pose supplied
        poses = iter(c["X"])
        g = joint_space_rhs(params, model, lambda q: next(poses), lambda t, x: c["tau"][1])
        for k in range(len(c["X"])):
            d = g(0.0, np.concatenate([c["q"][k], c["dq"][k]]))
            ref = dm._reference_forward_joint(params, model, c["q"][k], c["dq"][k], c["X"][k], c["tau"][1])
            np.testing.assert_array_equal(d[:3], c["dq"][k])
            assert _rel(d[None, 3:], ref[None]).max() <= REL


def test_kernel_ik_equals_solver_ik(model):
    """Same reach test and angles; rounding is amplified by arccos near a stretched or folded leg."""
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.2, 1.2, 4000), rng.uniform(-0.3, 1.1, 4000), rng.uniform(-np.pi, np.pi, 4000)])
    G = dm._kernel_model(model)
    q = np.empty(3)
    for posture in range(1, 9):
        ref = ik(model, X, posture)
        for k in range(len(X)):
            ok = _kernel.ik_row(G, X[k, 0], X[k, 1], X[k, 2], posture - 1, q)
            assert ok == (not np.isnan(ref[k, 0]))
            if ok:
                np.testing.assert_allclose(wrap(q - ref[k]), 0.0, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- integrators
def test_compiled_rk4_equals_the_generic_loop(model):
    p = dm.DynamicParameters(gravity=(0.0, -0.5), com_platform=(0.01, 0.0))
    x0 = np.array([0.45, 0.20, np.deg2rad(-45.0), -0.10, 0.35, 0.2])
    f = task_space_rhs(p, model, 1, [0.02, -0.01, 0.005])

    def generic(t, x):              # the same right-hand side, not recognised by rk4
        return f(t, x)
    t, xs = rk4(f, 0.25, x0, 1e-3, 500)
    t2, xg = rk4(generic, 0.25, x0, 1e-3, 500)
    np.testing.assert_array_equal(t, t2)
    np.testing.assert_array_equal(t, 0.25 + 1e-3 * np.arange(501))
    np.testing.assert_array_equal(xs, xg)
    np.testing.assert_array_equal(rk4_step(f, 0.25, x0, 1e-3), xg[1])
    assert np.ptp(xs[:, 1]) > 0.05
    # zero steps, and a time-dependent torque (generic loop with the compiled right-hand side)
    t, xs = rk4(f, 0.0, x0, 1e-3, 0)
    assert xs.shape == (1, 6) and np.all(xs[0] == x0)
    ft = task_space_rhs(p, model, 1, lambda t, x: np.array([0.02 * t, 0.0, 0.0]))
    _, xt = rk4(ft, 0.0, x0, 1e-3, 50)
    _, xr = rk4(lambda t, x: np.concatenate([x[3:], dm._reference_forward_dynamics_task(
        p, model, x[:3], x[3:], np.array([0.02 * t, 0.0, 0.0]))]), 0.0, x0, 1e-3, 50)
    np.testing.assert_allclose(xt, xr, rtol=0, atol=1e-13)


def test_compiled_rk4_leaving_the_tool_space_raises_like_the_generic_loop(model):
    p = dm.DynamicParameters()
    x0 = np.array([0.45, 0.30, -0.7, 3.0, 0.0, 0.0])         # 3 m/s towards the border
    f = task_space_rhs(p, model, 1)
    with pytest.raises(SolverInputError, match="tool space of posture 1") as fast:
        rk4(f, 0.0, x0, 1e-2, 100)
    with pytest.raises(SolverInputError) as generic:
        rk4(lambda t, x: f(t, x), 0.0, x0, 1e-2, 100)
    assert str(fast.value) == str(generic.value)


def test_joint_space_rk4_with_nearest_dk(model):
    p = dm.DynamicParameters(gravity=(0.0, -0.5))
    X0 = np.array([0.45, 0.3, -0.7])
    q0 = ik(model, X0, 1)
    dq0 = dm.joint_velocity_jacobian(model, X0, q0) @ np.array([0.2, -0.1, 0.4])
    x0 = np.concatenate([q0, dq0])
    f = joint_space_rhs(p, model, NearestPoseDK(model, X0), np.array([0.1, 0.0, -0.1]))

    def ref(t, x, dk=NearestPoseDK(model, X0)):
        return np.concatenate([x[3:], dm._reference_forward_dynamics(p, model, x[:3], x[3:], dk(x[:3]),
                                                                     np.array([0.1, 0.0, -0.1]))])
    _, xs = rk4(f, 0.0, x0, 1e-3, 50)
    _, xr = rk4(ref, 0.0, x0, 1e-3, 50)
    np.testing.assert_allclose(xs, xr, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- input handling
def _same_error(fast, ref):
    with pytest.raises(Exception) as e1:
        fast()
    with pytest.raises(Exception) as e2:
        ref()
    assert type(e1.value) is type(e2.value) and str(e1.value) == str(e2.value)
    return e1.value


def test_fast_path_errors_are_the_reference_errors(model):
    p = dm.DynamicParameters()
    X = np.array([0.45, 0.3, -0.7])
    q = ik(model, X, 1)
    z = np.zeros(3)
    nan = np.array([0.0, np.nan, 0.0])
    cases = [
        ("forward_dynamics", (q, nan, X, z)), ("forward_dynamics", (q, z, X, np.array([np.inf, 0, 0]))),
        ("forward_dynamics", (q, z, X + [0.01, 0.0, 0.0], z)), ("mass_matrix", (nan, X)),
        ("inverse_dynamics", (q, z, z, X + [0.0, 0.0, 0.01])), ("coriolis", (q, np.zeros(4), X)),
        ("gravity", (q.astype(np.float32)[:2], X)), ("friction", (q, [0.0, np.nan, 0.0], X)),
        ("mass_matrix_task", (np.array([3.0, 3.0, 0.0]),)), ("coriolis_task", (X, nan)),
        ("forward_dynamics_task", (np.array([3.0, 3.0, 0.0]), z, z)),
        ("inverse_dynamics_task", (nan, z, z)), ("generalized_force_task", (X, z, [1.0, 2.0])),
    ]
    for name, args in cases:
        err = _same_error(lambda: getattr(dm, name)(p, model, *args),
                          lambda: getattr(dm, f"_reference_{name}")(p, model, *args))
        assert isinstance(err, SolverInputError), (name, err)
    for posture in (0, 9, 2.5, True, "1"):
        _same_error(lambda: dm.gravity_task(p, model, X, posture),
                    lambda: dm._reference_gravity_task(p, model, X, posture))
    gains = ComputedTorqueGains.design()
    _same_error(lambda: computed_torque(p, model, gains, q, z, X, nan, z, z),
                lambda: _reference_computed_torque(p, model, gains, q, z, X, nan, z, z))
    _same_error(lambda: computed_torque(p, model, gains, q, z, X + 0.01, q, z, z),
                lambda: _reference_computed_torque(p, model, gains, q, z, X + 0.01, q, z, z))
    # the right-hand side of a pose outside the tool space
    rhs = task_space_rhs(p, model, 1, tau=np.zeros(3))
    with pytest.raises(SolverInputError, match="tool space"):
        rhs(0.0, np.array([3.0, 3.0, 0.0, 0.0, 0.0, 0.0]))


def test_other_input_forms_take_the_checked_route(model):
    p = _params("random-per-leg")
    rng = np.random.default_rng(5)
    X = np.array([[0.45, 0.3, -0.7], [0.5, 0.35, -0.4]])
    q = ik(model, X, 1)
    dX = rng.normal(size=(2, 3))
    tau = rng.normal(size=3)
    ref = dm._reference_forward_dynamics_task(p, model, X, dX, tau)
    # lists, integer postures as numpy ints and arrays, read-only and strided arrays, broadcasting
    assert _rel(dm.forward_dynamics_task(p, model, X.tolist(), dX, tau.tolist()), ref).max() <= REL
    assert _rel(dm.forward_dynamics_task(p, model, X, dX, tau, np.int64(1)), ref).max() <= REL
    assert _rel(dm.forward_dynamics_task(p, model, X, dX, tau, np.array([1, 1])), ref).max() <= REL
    ro = X[0].copy()
    ro.setflags(write=False)
    strided = np.column_stack([dX[0], dX[0]]).ravel()[::2]
    np.testing.assert_array_equal(dm.forward_dynamics_task(p, model, ro, strided, tau),
                                  dm.forward_dynamics_task(p, model, X[0], dX[0].copy(), tau))
    out = dm.mass_matrix_task(p, model, np.broadcast_to(X[0], (2, 4, 3)))
    assert out.shape == (2, 4, 3, 3) and np.all(out == out[0, 0])
    assert dm.mass_matrix_task(p, model, np.zeros((0, 3)) + X[0]).shape == (0, 3, 3)
    assert dm.forward_dynamics(p, model, np.zeros((0, 3)), np.zeros(3), X[0], tau).shape == (0, 3)
    dq = np.einsum("...ij,...j->...i", dm.joint_velocity_jacobian(model, X, q), dX)
    np.testing.assert_array_equal(dm.inverse_dynamics(p, model, q, dq, np.zeros(3), X),
                                  np.array([dm.inverse_dynamics(p, model, q[k], dq[k], np.zeros(3), X[k])
                                            for k in range(2)]))
    # a posture whose tool space does not hold the pose
    with pytest.raises(SolverInputError, match="tool space of posture"):
        dm.forward_dynamics_task(p, model, np.array([[0.45, 0.3, -0.7], [3.0, 3.0, 0.0]]), dX, tau)
