"""The compiled dynamics kernels (dynamics/_kernels/) against their numpy reference (tests/dynamics_reference.py).

Every public dynamics function runs a kernel; its numpy implementation is the
oracle ``dynamics_reference.<name>``.  Here the two are compared on many random
configurations in all eight postures (away from singularities, where both are
accurate), with parameters that exercise every term; the single-configuration
path must equal the batch path to the last bit (it is a batch of one), the
compiled RK4 loop the generic one, and the errors the reference's (a kernel's
refusal is a :class:`dynamics.DynamicsError` with the reference's message).  The
same for the compiled circle reference (:class:`dynamics.CircleTrajectory`
against ``circle_task`` / ``circle_joint``) and the steps of the plant and
controller FMU slaves (``fmu_src/RRRPlant.py``, ``fmu_src/ComputedTorqueController.py``,
run in process, through :class:`dynamics.PlantStepper` / :class:`dynamics.ControllerStepper`,
against the numpy ``plant_step`` / ``controller_step``).
"""
import re

import numpy as np
import pytest

import dynamics as dm
import dynamics_reference as oracle
from solver import SolverInputError, ik, singularity_measures
from dynamics import (CircleTrajectory, ComputedTorqueGains, ControllerStepper, DynamicsError, NearestPoseDK,
                      PlantStepper, computed_torque, joint_space_rhs, rk4, rk4_step, task_space_rhs, wrap)
from dynamics._kernels.layout import MASS, OUTSIDE, refusal
from dynamics._kernels.rows import task_batch
from dynamics._packs import arm_pack, bodies_pack

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
        ref = getattr(oracle, name)(params, model, *args, posture=posture)
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
        ref = getattr(oracle, name)(params, model, *args)
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
    assert _rel(fast, oracle.computed_torque(params, model, gains, *args)).max() <= REL
    assert _rel(fast, oracle.computed_torque_law(params, model, gains, *args)).max() <= REL
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
            ref = oracle.forward_task(params, model, c["X"][k], c["q"][k], c["dX"][k], c["tau"][0])
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
            ref = oracle.forward_joint(params, model, c["q"][k], c["dq"][k], c["X"][k], c["tau"][1])
            np.testing.assert_array_equal(d[:3], c["dq"][k])
            assert _rel(d[None, 3:], ref[None]).max() <= REL


def test_task_space_kernel_runs_the_solver_ik(model, params):
    """The task-space kernel's motor angles are solver.ik's to the last bit (one IK, the core's), and it
    refuses exactly the poses solver.ik cannot reach."""
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.2, 1.2, 4000), rng.uniform(-0.3, 1.1, 4000), rng.uniform(-np.pi, np.pi, 4000)])
    arm, bodies = arm_pack(model), bodies_pack(params)
    zero, q, out = np.zeros((1, 3)), np.empty((1, 3)), np.empty((1, 9))
    reached = 0
    for posture in range(1, 9):
        ref = ik(model, X, posture)
        for k in range(len(X)):
            status = refusal(task_batch(arm, bodies, X[k:k + 1], zero, zero, q, posture - 1, MASS, out))[0]
            if np.isnan(ref[k, 0]):
                assert status == OUTSIDE
            else:
                assert status != OUTSIDE
                np.testing.assert_array_equal(q[0], ref[k])
                reached += 1
    assert reached > 1000


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
    _, xr = rk4(lambda t, x: np.concatenate([x[3:], oracle.forward_dynamics_task(
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
        return np.concatenate([x[3:], oracle.forward_dynamics(p, model, x[:3], x[3:], dk(x[:3]),
                                                                     np.array([0.1, 0.0, -0.1]))])
    _, xs = rk4(f, 0.0, x0, 1e-3, 50)
    _, xr = rk4(ref, 0.0, x0, 1e-3, 50)
    np.testing.assert_allclose(xs, xr, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- input handling
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*(?:e[-+]?\d+)?|\bnan\b|\binf\b)")


def _same_error(fast, ref):
    """The runtime raises the reference's error: the same type, or a DynamicsError where a kernel
    refused what the reference refuses; the same message, numbers to 1e-12 (the reference computes
    the poses of a trajectory with numpy), except the runtime's "(first refused at index ...)"."""
    with pytest.raises(Exception) as e1:
        fast()
    with pytest.raises(Exception) as e2:
        ref()
    assert type(e1.value) is type(e2.value) or (type(e1.value) is DynamicsError
                                                and type(e2.value) is SolverInputError), (e1.value, e2.value)
    got, want = re.sub(r" \(first refused at index .*\)$", "", str(e1.value)), str(e2.value)
    assert _NUMBER.sub("#", got) == _NUMBER.sub("#", want), (got, want)
    np.testing.assert_allclose([float(v) for v in _NUMBER.findall(got)], [float(v) for v in _NUMBER.findall(want)],
                               rtol=1e-12, atol=1e-12)
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
                          lambda: getattr(oracle, name)(p, model, *args))
        assert isinstance(err, SolverInputError), (name, err)
        # a kernel refusal (a single configuration: the kernel checks it) is the one named exception
        if all(type(a) is np.ndarray and a.shape == (3,) and a.dtype == np.float64 for a in args):
            assert type(err) is DynamicsError and err.where is None, (name, err)
    for posture in (0, 9, 2.5, True, "1"):
        _same_error(lambda: dm.gravity_task(p, model, X, posture),
                    lambda: oracle.gravity_task(p, model, X, posture))
    gains = ComputedTorqueGains.design()
    _same_error(lambda: computed_torque(p, model, gains, q, z, X, nan, z, z),
                lambda: oracle.computed_torque(p, model, gains, q, z, X, nan, z, z))
    _same_error(lambda: computed_torque(p, model, gains, q, z, X + 0.01, q, z, z),
                lambda: oracle.computed_torque(p, model, gains, q, z, X + 0.01, q, z, z))
    # the right-hand side of a pose outside the tool space
    rhs = task_space_rhs(p, model, 1, tau=np.zeros(3))
    with pytest.raises(DynamicsError, match="tool space") as err:
        rhs(0.0, np.array([3.0, 3.0, 0.0, 0.0, 0.0, 0.0]))
    assert err.value.reason == "outside" and isinstance(err.value, ValueError)
    # in a batch, the error names the first configuration refused
    with pytest.raises(DynamicsError, match=r"loop residual .* \(first refused at index \(1,\)\)") as err:
        dm.forward_dynamics(p, model, np.stack([q, q]), z, np.stack([X, X + 0.01]), z)
    assert err.value.reason == "not-assembled" and err.value.where == (1,)


def test_other_input_forms_take_the_checked_route(model):
    p = _params("random-per-leg")
    rng = np.random.default_rng(5)
    X = np.array([[0.45, 0.3, -0.7], [0.5, 0.35, -0.4]])
    q = ik(model, X, 1)
    dX = rng.normal(size=(2, 3))
    tau = rng.normal(size=3)
    ref = oracle.forward_dynamics_task(p, model, X, dX, tau)
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


# ---------------------------------------------------------------------------- circle reference
#: compiled circle reference vs its numpy reference: absolute for poses and angles (m, rad),
#: relative to the largest entry for rates and accelerations
CIRCLE_TOL = 1e-12


def _circles(model):
    """The default circle, one without a ramp, and smaller circles in other postures, with a start
    angle and a different time law (every branch of the time law and of the kernel)."""
    out = [CircleTrajectory(), CircleTrajectory(ramp_time=0.0), CircleTrajectory(period=0.7, ramp_time=0.2, start=2.0)]
    for posture in range(2, 9):
        traj = CircleTrajectory(center=(0.5, 0.3), radius=0.05, phi=0.3, posture=posture, period=1.1,
                                ramp_time=0.3, start=-1.0)
        try:
            oracle.circle_joint(traj, model, np.linspace(0.0, 1.5, 16))
        except SolverInputError:
            continue                                    # the circle is not in this posture's tool space
        out.append(traj)
    assert len(out) >= 5
    return out


def _circle_diff(fast, ref):
    """(abs diff of X or q, rel diff of the rates and accelerations) of two (X|q, d, dd) triples;
    angles that differ by 2 pi turns are the same (not ``wrap``: it rounds tiny differences to 0)."""
    d = fast[0] - ref[0]
    a = float(np.max(np.abs(d - 2 * np.pi * np.round(d / (2 * np.pi)))))
    r = max(float(np.max(np.abs(f - g)) / max(np.max(np.abs(g)), 1e-300)) for f, g in zip(fast[1:], ref[1:]))
    return a, r


def test_circle_kernel_equals_reference(model):
    """CircleTrajectory.task/joint (compiled) against circle_task/circle_joint (numpy)."""
    t = np.concatenate([[-0.3, 0.0], np.linspace(1e-4, 3.0, 3001)])
    report = []
    for traj in _circles(model):
        fast_t, ref_t = traj.task(t), oracle.circle_task(traj, t)
        fast_j, ref_j = traj.joint(model, t), oracle.circle_joint(traj, model, t)
        for f, g in zip(fast_t + fast_j, ref_t + ref_j):
            assert f.shape == g.shape == t.shape + (3,) and f.dtype == g.dtype == np.float64
        dt, dj = _circle_diff(fast_t, ref_t), _circle_diff(fast_j, ref_j)
        report.append(f"posture {traj.posture} ramp {traj.ramp_time:g}: X {dt[0]:.1e}, dX/ddX {dt[1]:.1e} rel, "
                      f"q {dj[0]:.1e}, dq/ddq {dj[1]:.1e} rel")
        assert max(dt + dj) <= CIRCLE_TOL, report[-1]
        # the inverse kinematics is solver.ik's, operation for operation
        np.testing.assert_array_equal(fast_j[0], ik(model, fast_t[0], traj.posture))
        # scalars, 0-d and n-d times: the same numbers as the batch
        for k in (0, 1, 2, 700, 2999):
            for tk in (float(t[k]), np.float64(t[k]), np.array(t[k])):
                for f, g in zip(traj.task(tk) + traj.joint(model, tk), fast_t + fast_j):
                    assert f.shape == (3,)
                    np.testing.assert_array_equal(f, g[k])
        grid = traj.joint(model, t[:600].reshape(20, 30))
        np.testing.assert_array_equal(grid[2], fast_j[2][:600].reshape(20, 30, 3))
    print("\n[circle reference, compiled vs numpy] " + "; ".join(report))


def test_circle_kernel_refusals_are_the_reference_errors(model):
    traj = CircleTrajectory()
    for t in (np.nan, [0.1, np.inf]):
        _same_error(lambda: traj.task(t), lambda: oracle.circle_task(traj, t))
        _same_error(lambda: traj.joint(model, t), lambda: oracle.circle_joint(traj, model, t))
    big = CircleTrajectory(radius=0.8)                  # leaves the tool space of posture 1
    err = _same_error(lambda: big.joint(model, np.linspace(0, 2, 50)),
                      lambda: oracle.circle_joint(big, model, np.linspace(0, 2, 50)))
    assert isinstance(err, SolverInputError) and "tool space of posture 1" in str(err)
    _same_error(lambda: traj.joint("paper", 0.1), lambda: oracle.circle_joint(traj, "paper", 0.1))
    np.testing.assert_array_equal(traj.task([])[0], np.zeros((0, 3)))


# ---------------------------------------------------------------------------- the FMU slaves' steps
def _slave(cls, **values):
    """An initialized instance of a project FMU slave class, run in process (no FMU)."""
    import sys
    from pathlib import Path
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.insert(0, root)
    inst = cls(instance_name="test", resources=root)
    inst.setup_experiment(0.0)
    for k, v in values.items():
        setattr(inst, k, v)
    inst.exit_initialization_mode()
    assert inst._init_error is None
    return inst


OUT_PLANT = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true", "energy")


@pytest.mark.parametrize("case", ["default", "gravity+substeps", "no-friction+heavy"])
def test_plant_step_equals_the_numpy_step(model, case):
    """RRRPlant: the compiled step against the numpy one (oracle.plant_step), step by step."""
    from fmu_src.RRRPlant import RRRPlant
    X0 = np.array([0.45, 0.30, -0.7])
    params = {"default": {}, "gravity+substeps": dict(gravity_y=-0.5, gravity_x=0.2, substeps=3),
              "no-friction+heavy": dict(friction=False, mass_scale=1.3)}[case]
    fast = _slave(RRRPlant, x0=X0[0], y0=X0[1], phi0=X0[2], **params)
    ref = _slave(RRRPlant, x0=X0[0], y0=X0[1], phi0=X0[2], **params)
    oracle.plant_outputs(ref)
    rng = np.random.default_rng(11)
    for k in range(200):
        tau = (0.3 * np.sin(0.05 * k + np.arange(3)) + 0.02 * rng.normal(size=3)).tolist()
        for inst in (fast, ref):
            inst.tau1, inst.tau2, inst.tau3 = tau
        assert fast.do_step(k * 1e-3, 1e-3)
        oracle.plant_step(ref, k * 1e-3, 1e-3)
        # RK4 and the inverse kinematics: the same operations, the same bits
        np.testing.assert_array_equal(fast._x, ref._x)
        assert [getattr(fast, n) for n in OUT_PLANT[:3]] == [getattr(ref, n) for n in OUT_PLANT[:3]]
        got = np.array([getattr(fast, n) for n in OUT_PLANT])
        want = np.array([getattr(ref, n) for n in OUT_PLANT])
        np.testing.assert_allclose(got[3:6], want[3:6], rtol=0, atol=1e-13 * max(1.0, np.abs(want[3:6]).max()))
        assert abs(got[9] - want[9]) <= 1e-12 * max(abs(want[9]), 1e-3)
        assert all(type(getattr(fast, n)) is float for n in OUT_PLANT)
    assert np.ptp([fast.x_true, X0[0]]) > 1e-4                         # it moved


def test_plant_energy_kernel_equals_total_energy(model, params, configs):
    out = np.empty(PlantStepper.OUT_SIZE)
    for posture in (1, 5):
        stepper = PlantStepper(params, model, posture)
        c = configs[posture]
        ref = dm.total_energy(params, model, c["X"], c["dX"], posture)
        dq = np.einsum("...ij,...j->...i", dm.joint_velocity_jacobian(model, c["X"], c["q"]), c["dX"])
        for k in range(len(ref)):
            x = np.concatenate([c["X"][k], c["dX"][k]])
            stepper.outputs(x, out)
            np.testing.assert_array_equal(out[:6], x)
            np.testing.assert_array_equal(out[6:9], ik(model, c["X"][k], posture))
            np.testing.assert_allclose(out[9:12], dq[k], rtol=1e-13, atol=1e-13)
            assert abs(out[12] - ref[k]) <= REL * max(abs(ref[k]), 1e-6)


def test_plant_refused_step_rolls_back(model):
    """A torque that throws the platform out of the tool space: the step is refused with the numpy
    code's message and the state (the array _x) and outputs are those of the start of the step."""
    from fmu_src.RRRPlant import RRRPlant
    inst = _slave(RRRPlant, x0=0.45, y0=0.30, phi0=-0.7)
    inst.tau1, inst.tau2, inst.tau3 = 0.2, -0.1, 0.05
    for k in range(5):
        assert inst.do_step(k * 1e-3, 1e-3)
    x_before = inst._x.copy()
    outs = [getattr(inst, n) for n in OUT_PLANT]
    inst.tau1, inst.tau2, inst.tau3 = 4e4, -4e4, 4e4
    assert not inst.do_step(5e-3, 0.1)
    assert "left the tool space of posture 1" in inst.last_refusal
    np.testing.assert_array_equal(inst._x, x_before)
    assert [getattr(inst, n) for n in OUT_PLANT] == outs and inst._time == pytest.approx(5e-3)
    inst.tau1, inst.tau2, inst.tau3 = 0.2, -0.1, 0.05                # and it goes on from there
    assert inst.do_step(5e-3, 1e-3) and not np.array_equal(inst._x, x_before)


def test_steppers_refuse_with_the_one_exception(model):
    """PlantStepper / ControllerStepper: a refusal is a DynamicsError saying where; wrong lengths of
    the caller's arrays are argument errors (the compiled steps check them)."""
    p = dm.DynamicParameters()
    plant = PlantStepper(p, model, 1)
    out = np.empty(PlantStepper.OUT_SIZE)
    x = np.array([0.45, 0.30, -0.7, 0.0, 0.0, 0.0])
    with pytest.raises(DynamicsError, match="tool space of posture 1") as err:
        plant.step(4e4, -4e4, 4e4, 0.05, 2, x, out)          # thrown out of the tool space
    assert err.value.reason == "outside" and err.value.where in (0, 1)
    with pytest.raises(SolverInputError, match=r"expected float arrays of shapes \(6,\) and \(13,\)"):
        plant.step(0.0, 0.0, 0.0, 1e-3, 1, x, np.empty(12))
    traj = CircleTrajectory()
    ctrl = ControllerStepper(p, model, ComputedTorqueGains.design(), traj)
    q0, X0 = traj.joint(model, 0.0)[0], traj.task(0.0)[0]
    out = np.empty(ControllerStepper.OUT_SIZE)
    ctrl.step(0.0, *q0.tolist(), 0.0, 0.0, 0.0, *X0.tolist(), out)
    np.testing.assert_array_equal(out[6:], q0)
    with pytest.raises(DynamicsError) as err:
        ctrl.step(0.0, *q0.tolist(), 0.0, 0.0, 0.0, 3.0, 3.0, 0.0, out)
    assert (err.value.where, err.value.reason) == ("measurement", "outside")
    with pytest.raises(DynamicsError, match="reference at t = nan") as err:
        ctrl.step(float("nan"), *q0.tolist(), 0.0, 0.0, 0.0, *X0.tolist(), out)
    assert (err.value.where, err.value.reason) == ("reference", "non-finite")
    with pytest.raises(SolverInputError, match=r"out: expected a float array of shape \(9,\)"):
        ctrl.step(0.0, *q0.tolist(), 0.0, 0.0, 0.0, *X0.tolist(), np.empty(3))


OUT_CTRL = ("tau1", "tau2", "tau3", "x_ref", "y_ref", "phi_ref_out", "q1_ref", "q2_ref", "q3_ref")


@pytest.mark.parametrize("mass_scale", [1.0, 1.2])
def test_controller_step_equals_the_numpy_step(model, mass_scale):
    """ComputedTorqueController: the compiled step against the numpy one (oracle.controller_step) on
    measurements around the reference (joints off by up to 2 pi turns, poses of the joints)."""
    from fmu_src.ComputedTorqueController import ComputedTorqueController
    traj = CircleTrajectory()
    q0 = traj.joint(model, 0.0)[0]
    X0 = traj.task(0.0)[0]
    start = dict(q1=q0[0], q2=q0[1], q3=q0[2], x=X0[0], y=X0[1], phi=X0[2], mass_scale=mass_scale, bandwidth=40.0)
    fast, ref = _slave(ComputedTorqueController, **start), _slave(ComputedTorqueController, **start)
    assert [getattr(fast, n) for n in OUT_CTRL] == [getattr(ref, n) for n in OUT_CTRL]
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2.5, 150)
    X = traj.task(t)[0] + rng.normal(size=(len(t), 3)) * [2e-3, 2e-3, 1e-2]
    q = ik(model, X, 1) + 2 * np.pi * rng.integers(-1, 2, size=(len(t), 3))
    dq = traj.joint(model, t)[1] + rng.normal(size=(len(t), 3)) * 0.05
    worst = 0.0
    for k in range(len(t)):
        for inst in (fast, ref):
            inst.q1, inst.q2, inst.q3 = q[k].tolist()
            inst.dq1, inst.dq2, inst.dq3 = dq[k].tolist()
            inst.x, inst.y, inst.phi = X[k].tolist()
        assert fast.do_step(float(t[k]), 1e-3)
        oracle.controller_step(ref, float(t[k]), 1e-3)
        got = np.array([getattr(fast, n) for n in OUT_CTRL])
        want = np.array([getattr(ref, n) for n in OUT_CTRL])
        assert all(type(getattr(fast, n)) is float for n in OUT_CTRL)
        np.testing.assert_array_equal(got[6:], want[6:])                      # q_d: solver.ik's bits
        np.testing.assert_allclose(got[3:6], want[3:6], rtol=0, atol=CIRCLE_TOL)
        worst = max(worst, float(np.max(np.abs(got[:3] - want[:3])) / np.max(np.abs(want[:3]))))
    print(f"\n[controller step, compiled vs numpy] largest torque difference {worst:.1e} relative")
    assert worst <= REL


def test_controller_refusals_are_the_numpy_step_refusals(model):
    from fmu_src.ComputedTorqueController import ComputedTorqueController
    traj = CircleTrajectory()
    q0, X0 = traj.joint(model, 0.0)[0], traj.task(0.0)[0]
    inst = _slave(ComputedTorqueController, q1=q0[0], q2=q0[1], q3=q0[2], x=X0[0], y=X0[1], phi=X0[2])
    before = [getattr(inst, n) for n in OUT_CTRL]
    inst.x = 3.0                                          # the DK pose is outside the tool space
    assert not inst.do_step(0.1, 1e-3)
    assert "from the DK is outside the tool space of posture 1" in inst.last_refusal
    assert [getattr(inst, n) for n in OUT_CTRL] == before and inst._time == 0.0
    # a reference that leaves the tool space (a circle too large for the robot): the numpy code's error
    big = _slave(ComputedTorqueController, q1=q0[0], q2=q0[1], q3=q0[2], x=X0[0], y=X0[1], phi=X0[2])
    object.__setattr__(big, "_traj", CircleTrajectory(radius=0.8))
    big._stepper = ControllerStepper(big._params, big._model, big._gains, big._traj)
    assert not big.do_step(0.6, 1e-3)
    assert "reference at t = 0.6" in big.last_refusal and "tool space of posture 1" in big.last_refusal
    inst.x = X0[0]
    assert inst.do_step(0.0, 1e-3)


def test_rollback_snapshot_is_as_deep_as_the_pickle():
    """fmu_src.table_slave's in-memory rollback snapshot (what each doStep of the plant and controller
    FMUs takes) restores what the pickle it replaced restored: arrays and lists copied, sharing
    between them kept, other objects pickled, unpicklable states refused."""
    import threading
    from fmu_src.table_slave import StepRefused, TableSlave, Var

    class Probe(TableSlave):
        VARIABLES = (Var("u", "Real", "input", start=0.0), Var("y", "Real", "output", depends_on=()),
                     Var("n", "Integer", "parameter", start=1, min=1, max=5))
        STATE = ("_a", "_b", "_lst", "_obj", "_tup")

        def setup(self):
            self._a = np.arange(3.0)
            self._b, self._lst, self._obj, self._tup = self._a, [1.0, 2.0], None, (1, (2.0, "x"))

        def step(self, t, dt):
            self._a += 1.0                      # in place, then maybe refuse: the rollback must undo it
            self._lst.append(3.0)
            self.y += 1.0
            if self.u > 0:
                raise StepRefused("refused")

    s = _slave(Probe)
    assert s.do_step(0.0, 0.1) and s._a is s._b and s._a[0] == 1.0
    s.u = 1.0
    assert not s.do_step(0.1, 0.1)
    assert s._a is s._b and list(s._a) == [1.0, 2.0, 3.0] and s._lst == [1.0, 2.0, 3.0] and s.y == 1.0
    s._b = np.zeros(2)                          # no sharing: copies, restorable twice
    snap = s._capture()
    for _ in range(2):
        s._a[:] = 7.0
        s._lst.append(9.0)
        s._restore(snap)
        assert list(s._a) == [1.0, 2.0, 3.0] and s._lst == [1.0, 2.0, 3.0] and s._tup == (1, (2.0, "x"))
    s._obj = {"ref": s._a}                      # an object that refers to an array of the state
    s._restore(s._capture())
    assert s._obj["ref"] is s._a
    s._obj, s.u = threading.Lock(), 0.0
    assert not s.do_step(0.1, 0.1) and "the state does not pickle" in s.last_refusal
    s._obj = None
    s.u = float("nan")
    assert not s.do_step(0.1, 0.1) and "'u' = nan" in s.last_refusal
    s.u, s.n = 0.0, 7
    assert not s.do_step(0.1, 0.1) and "outside [1, 5]" in s.last_refusal
    s.n = 1
    assert s.do_step(0.1, 0.1) and s.y == 2.0
