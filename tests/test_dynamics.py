"""Dynamics of the 3-RRR (paper eqs. 5-7), integrators, trajectory, computed torque.

Every check compares two independent routes to the same quantity (energy vs
equations of motion, Lagrange vs Newton-Euler, joint vs task space, finite
differences vs analytic derivatives, python-control vs the gains), so each can fail.
"""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from solver import (SolverInputError, dk_all, elbow_points, ik, platform_points, posture_of,
                    singularity_measures)
from dynamics import (CircleTrajectory, ComputedTorqueController, ComputedTorqueGains, DynamicParameters,
                      NearestPoseDK, ParameterError, computed_torque, coriolis, coriolis_task, forward_dynamics,
                      forward_dynamics_task, friction, friction_power, friction_task, generalized_force_task,
                      gravity, gravity_task, inverse_dynamics, inverse_dynamics_task, joint_accelerations,
                      joint_space_rhs, joint_velocity_jacobian, kinetic_energy, mass_matrix, mass_matrix_task,
                      passive_joint_angles, passive_joint_rates, pose_velocity_jacobian, potential_energy, rk4,
                      rk4_step, simulate_tracking, solve_reference, task_space_rhs, total_energy, wrap)
from conftest import pose_distance

H = 1e-3                 # step and controller period, s
N_2S = 2000              # 2 s
#: A robot on a table tilted by 3 deg: the in-plane gravity 9.81 sin(3 deg) = 0.513 m/s^2.
#: (Full vertical gravity drives the unactuated robot out of its tool space well within 2 s.)
G_TILT = (0.0, -float(9.81 * np.sin(np.deg2rad(3.0))))
NO_FRICTION = dict(friction_active=0.0, friction_elbow=0.0, friction_platform=0.0)
#: Passive-motion starts (pose, rate), posture 1, chosen so that the 2 s of free
#: motion stays clear of singularities (asserted below): speeds of 0.1-0.36 m/s
#: and up to 0.5 rad/s, those of a slowly moving robot arm.
START_G0 = np.array([0.45, 0.30, np.deg2rad(-45.0), 0.10, 0.0, 0.5])
START_TILT = np.array([0.45, 0.20, np.deg2rad(-45.0), -0.10, 0.35, 0.0])


@pytest.fixture(scope="module")
def params():
    """Defaults with an off-centre platform mass and gravity, so that every term is exercised."""
    return DynamicParameters(gravity=(0.7, -9.81), com_platform=(0.012, -0.02))


def _states(rng, model, n):
    """Random assembled configurations of posture 1 away from singularities, with rates."""
    X = np.column_stack([rng.uniform(0.2, 0.8, 4 * n), rng.uniform(0.05, 0.6, 4 * n),
                         rng.uniform(-1.2, 0.6, 4 * n)])
    q = ik(model, X, 1)
    ok = ~np.isnan(q[:, 0])
    sm = singularity_measures(model, X[ok], q[ok])
    good = (sm.type1 > 0.15) & (sm.type2 > 0.25)
    X, q = X[ok][good][:n], q[ok][good][:n]
    assert len(X) == n
    dX = rng.normal(size=(n, 3)) * np.array([0.4, 0.4, 1.5])
    return X, q, dX


def _free_run(model, gvec, start, h=H, n=N_2S, tau=None, **kw):
    p = DynamicParameters(gravity=gvec, **{**NO_FRICTION, **kw})
    t, x = rk4(task_space_rhs(p, model, 1, tau), 0.0, start, h, n)
    return p, t, x


def _away_from_singularities(model, X):
    sm = singularity_measures(model, X, ik(model, X, 1))
    assert sm.type1.min() > 0.25 and sm.type2.min() > 0.4, "the test motion must stay regular"


# ---------------------------------------------------------------------------- parameters
def test_parameters_validate_and_scale(model):
    with pytest.raises(ParameterError, match=r"mass_distal: expected positive values in kg, got \[0.2, -1.0, 0.2\]"):
        DynamicParameters(mass_distal=[0.2, -1.0, 0.2])
    with pytest.raises(ParameterError, match=r"gravity: expected shape \(2,\)"):
        DynamicParameters(gravity=(0.0, 0.0, -9.81))
    with pytest.raises(ParameterError, match="friction_elbow: expected non-negative"):
        DynamicParameters(friction_elbow=-0.1)
    with pytest.raises(ParameterError, match="inertia_platform: expected finite"):
        DynamicParameters(inertia_platform=np.nan)
    with pytest.raises(ParameterError, match="factor"):
        DynamicParameters().with_scaled_masses(0.0)
    p = DynamicParameters()
    assert isinstance(ParameterError("x"), ValueError)
    assert DynamicParameters.from_dict(p.to_dict()) == p
    # a uniformly 20 % denser robot (rotor too) has a 20 % larger inertia everywhere
    X = np.array([0.45, 0.3, -0.7])
    M1 = mass_matrix_task(p, model, X)
    M2 = mass_matrix_task(p.with_scaled_masses(1.2, rotor=True), model, X)
    np.testing.assert_allclose(M2, 1.2 * M1, rtol=1e-13)
    # without the rotor: strictly between
    M3 = mass_matrix_task(p.with_scaled_masses(1.2), model, X)
    assert np.all(np.linalg.eigvalsh(M2 - M3) > 0) and np.all(np.linalg.eigvalsh(M3 - M1) > 0)


# ---------------------------------------------------------------------------- model vs independent derivations
def _body_kinetic_energy_fd(params, model, X, dX, eps=1e-6):
    """Kinetic energy from central differences of body positions and angles along X + s dX."""
    def bodies(Xs):
        q = ik(model, Xs, 1)
        D, A = elbow_points(model, q), platform_points(model, Xs)
        c, s = np.cos(Xs[2]), np.sin(Xs[2])
        cp = params.com_platform
        e = np.column_stack([np.cos(q), np.sin(q)])
        pos = np.vstack([Xs[:2] + [c * cp[0] - s * cp[1], s * cp[0] + c * cp[1]],
                         model.motors + params.com_proximal[:, None] * e,
                         D + (params.com_distal / model.l2)[:, None] * (A - D)])
        ang = np.concatenate([[Xs[2]], q, np.arctan2(A[:, 1] - D[:, 1], A[:, 0] - D[:, 0])])
        return pos, ang
    (p1, a1), (p0, a0) = bodies(X + eps * dX), bodies(X - eps * dX)
    v = (p1 - p0) / (2 * eps)
    w = wrap(a1 - a0) / (2 * eps)
    m = np.concatenate([[params.mass_platform], params.mass_proximal, params.mass_distal])
    inertia = np.concatenate([[params.inertia_platform], params.inertia_proximal + params.rotor_inertia,
                              params.inertia_distal])
    return 0.5 * np.sum(m * np.sum(v * v, axis=1)) + 0.5 * np.sum(inertia * w * w)


def test_task_space_terms_against_energy_and_lagrange(model, params, rng):
    X, q, dX = _states(rng, model, 25)
    MX = mass_matrix_task(params, model, X)
    CX = coriolis_task(params, model, X, dX)
    GX = gravity_task(params, model, X)
    np.testing.assert_allclose(MX, np.swapaxes(MX, -1, -2), rtol=0, atol=1e-14)
    assert np.all(np.linalg.eigvalsh(MX) > 0)
    eps = 1e-6
    for k in range(len(X)):
        T = 0.5 * dX[k] @ MX[k] @ dX[k]
        # M_X against kinetic energy from finite differences of body positions (solver functions)
        assert T == pytest.approx(_body_kinetic_energy_fd(params, model, X[k], dX[k]), rel=1e-8)
        assert T == pytest.approx(kinetic_energy(params, model, X[k], dX[k]), rel=1e-12)
        # Coriolis (Newton-Euler / Kane, analytic) against Lagrange: dM/dt dX - 1/2 d(dX^T M dX)/dX
        Mp, Mm = (mass_matrix_task(params, model, X[k] + s * eps * dX[k]) for s in (1, -1))
        grad = [(dX[k] @ mass_matrix_task(params, model, X[k] + eps * e) @ dX[k]
                 - dX[k] @ mass_matrix_task(params, model, X[k] - eps * e) @ dX[k]) / (2 * eps) for e in np.eye(3)]
        lagrange = (Mp - Mm) / (2 * eps) @ dX[k] - 0.5 * np.array(grad)
        np.testing.assert_allclose(CX[k], lagrange, rtol=0, atol=1e-7 * (1 + np.abs(CX[k]).max()))
        # gravity against the gradient of the potential energy
        dV = [(potential_energy(params, model, X[k] + eps * e) - potential_energy(params, model, X[k] - eps * e))
              / (2 * eps) for e in np.eye(3)]
        np.testing.assert_allclose(GX[k], dV, rtol=0, atol=1e-7 * (1 + np.abs(GX[k]).max()))


def test_passive_joints_and_friction(model, params, rng):
    X, q, dX = _states(rng, model, 20)
    eps = 1e-6
    for k in range(len(X)):
        a1 = passive_joint_angles(model, X[k] + eps * dX[k], ik(model, X[k] + eps * dX[k], 1))
        a0 = passive_joint_angles(model, X[k] - eps * dX[k], ik(model, X[k] - eps * dX[k], 1))
        np.testing.assert_allclose(passive_joint_rates(model, X[k], q[k], dX[k]), wrap(a1 - a0) / (2 * eps),
                                   atol=1e-7)
    # friction: dissipated power, and at the motors b_a dq when the passive joints are frictionless
    Pf = friction_power(params, model, X, dX)
    np.testing.assert_allclose(np.sum(friction_task(params, model, X, dX) * dX, axis=-1), Pf, rtol=1e-12)
    dq = np.einsum("...ij,...j->...i", joint_velocity_jacobian(model, X, q), dX)
    rates = np.concatenate([dq, passive_joint_rates(model, X, q, dX)], axis=-1)
    b = np.concatenate([params.friction_active, params.friction_elbow, params.friction_platform])
    np.testing.assert_allclose(Pf, np.sum(b * rates ** 2, axis=-1), rtol=1e-12)
    active_only = DynamicParameters(friction_elbow=0.0, friction_platform=0.0, friction_active=[0.01, 0.02, 0.03])
    np.testing.assert_allclose(friction(active_only, model, q, dq, X), [0.01, 0.02, 0.03] * dq, atol=1e-14)


def test_joint_space_consistent_with_task_space(model, params, rng):
    X, q, dX = _states(rng, model, 30)
    Jq = joint_velocity_jacobian(model, X, q)
    Jx = pose_velocity_jacobian(model, X, q)
    dq = np.einsum("...ij,...j->...i", Jq, dX)
    # J_x = dX/dq against central differences of the direct kinematics (nearest real solution)
    eps = 1e-7
    for k in range(5):
        cols = []
        for e in np.eye(3):
            Xp, Xm = (NearestPoseDK(model, X[k])(q[k] + s * eps * e) for s in (1, -1))
            cols.append((Xp - Xm) / (2 * eps))
        np.testing.assert_allclose(Jx[k], np.column_stack(cols), rtol=0, atol=1e-7 * np.abs(Jx[k]).max())
    # M = J_x^T M_X J_x and 1/2 dq^T M dq = kinetic energy
    M = mass_matrix(params, model, q, X)
    MX = mass_matrix_task(params, model, X)
    np.testing.assert_allclose(M, np.swapaxes(Jx, -1, -2) @ MX @ Jx, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(M, np.swapaxes(M, -1, -2), atol=1e-14)
    assert np.all(np.linalg.eigvalsh(M) > 0)
    T = kinetic_energy(params, model, X, dX)
    np.testing.assert_allclose(0.5 * np.einsum("...i,...ij,...j->...", dq, M, dq), T, rtol=1e-12)
    # inverse dynamics in both forms for the same motion: ddq from the second-order velocity model
    ddX = rng.normal(size=X.shape)
    ddq = joint_accelerations(model, X, q, dX, ddX)
    tau = inverse_dynamics(params, model, q, dq, ddq, X)
    np.testing.assert_allclose(tau, inverse_dynamics_task(params, model, X, dX, ddX), rtol=1e-10, atol=1e-12)
    # ... and forward dynamics both ways
    np.testing.assert_allclose(forward_dynamics(params, model, q, dq, X, tau), ddq, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(forward_dynamics_task(params, model, X, dX, tau), ddX, rtol=1e-9, atol=1e-9)
    # generalised force of the torques: J_q^T tau - F_X
    Q = generalized_force_task(params, model, X, dX, tau)
    np.testing.assert_allclose(Q, (mass_matrix_task(params, model, X) @ ddX[..., None])[..., 0]
                               + coriolis_task(params, model, X, dX) + gravity_task(params, model, X),
                               rtol=1e-9, atol=1e-9, err_msg="M_X ddX + C_X dX + G_X = J_q^T tau - F_X")
    # joint-space Coriolis against Lagrange in q, with the pose from the DK
    eps = 1e-6
    for k in range(5):
        def Mq(qq):
            return mass_matrix(params, model, qq, NearestPoseDK(model, X[k])(qq))
        dM = (Mq(q[k] + eps * dq[k]) - Mq(q[k] - eps * dq[k])) / (2 * eps)
        grad = np.array([(dq[k] @ Mq(q[k] + eps * e) @ dq[k] - dq[k] @ Mq(q[k] - eps * e) @ dq[k]) / (2 * eps)
                         for e in np.eye(3)])
        C = coriolis(params, model, q[k], dq[k], X[k])
        np.testing.assert_allclose(C, dM @ dq[k] - 0.5 * grad, rtol=0, atol=1e-6 * (1 + np.abs(C).max()))
        dV = [(potential_energy(params, model, NearestPoseDK(model, X[k])(q[k] + eps * e))
               - potential_energy(params, model, NearestPoseDK(model, X[k])(q[k] - eps * e))) / (2 * eps)
              for e in np.eye(3)]
        np.testing.assert_allclose(gravity(params, model, q[k], X[k]), dV, atol=1e-6)


@settings(max_examples=60)
@given(seed=st.integers(0, 2 ** 32 - 1), scale=st.floats(0.01, 3.0))
def test_inverse_of_forward_dynamics_is_identity(model, params, seed, scale):
    rng = np.random.default_rng(seed)
    X, q, dX = _states(rng, model, 1)
    dq = joint_velocity_jacobian(model, X, q)[0] @ dX[0] * scale
    tau = rng.normal(size=3) * 5.0
    ddq = forward_dynamics(params, model, q[0], dq, X[0], tau)
    np.testing.assert_allclose(inverse_dynamics(params, model, q[0], dq, ddq, X[0]), tau, rtol=1e-9, atol=1e-9)


@settings(max_examples=40)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_instantaneous_energy_balance(model, params, seed):
    """dE/dt along the task-space vector field = tau . dq - friction power."""
    rng = np.random.default_rng(seed)
    X, q, dX = _states(rng, model, 1)
    tau = rng.normal(size=3)
    f = task_space_rhs(params, model, 1, tau)
    x = np.concatenate([X[0], dX[0]])
    eps = 1e-6
    E = [total_energy(params, model, y[:3], y[3:]) for y in (x + eps * f(0, x), x - eps * f(0, x))]
    dE = (E[0] - E[1]) / (2 * eps)
    dq = joint_velocity_jacobian(model, X[0], q[0]) @ dX[0]
    power = tau @ dq - friction_power(params, model, X[0], dX[0])
    assert dE == pytest.approx(power, abs=1e-6 * (1 + abs(power) + abs(tau @ dq)))


def test_batched_equals_single(model, params, rng):
    X, q, dX = _states(rng, model, 6)
    dq = np.einsum("...ij,...j->...i", joint_velocity_jacobian(model, X, q), dX)
    tau = rng.normal(size=(6, 3))
    batch = forward_dynamics(params, model, q.reshape(2, 3, 3), dq.reshape(2, 3, 3), X.reshape(2, 3, 3),
                             tau.reshape(2, 3, 3)).reshape(6, 3)
    single = np.array([forward_dynamics(params, model, q[k], dq[k], X[k], tau[k]) for k in range(6)])
    np.testing.assert_allclose(batch, single, rtol=1e-13, atol=1e-13)
    # broadcast a single state against a batch of torques
    np.testing.assert_allclose(forward_dynamics(params, model, q[0], dq[0], X[0], tau)[2],
                               forward_dynamics(params, model, q[0], dq[0], X[0], tau[2]), rtol=1e-13)


# ---------------------------------------------------------------------------- passive motion: energy
@pytest.mark.parametrize("gvec, start", [((0.0, 0.0), START_G0), (G_TILT, START_TILT)],
                         ids=["g=0", "tilted-3deg"])
def test_passive_motion_conserves_energy(model, gvec, start):
    p, t, x = _free_run(model, gvec, start)
    _away_from_singularities(model, x[:, :3])
    E = total_energy(p, model, x[:, :3], x[:, 3:])
    K = kinetic_energy(p, model, x[:, :3], x[:, 3:])
    V = potential_energy(p, model, x[:, :3])
    if gvec != (0.0, 0.0):
        assert np.ptp(V) > 0.5 * K.max(), "the potential energy must matter"
    drift = np.max(np.abs(E - E[0]))
    print(f"\n[energy, {gvec}] max|E - E0| = {drift:.3g} J, relative to max kinetic {drift / K.max():.3g}, "
          f"to |E0| {drift / abs(E[0]):.3g}")
    assert drift <= 1e-6 * K.max()
    assert drift <= 1e-6 * abs(E[0])


def test_energy_balance_along_a_driven_trajectory(model):
    """E(t) - E(0) equals the work of the motors minus the friction losses (as an extra RK4 state)."""
    p = DynamicParameters(gravity=G_TILT, friction_elbow=0.01, friction_platform=0.01)

    def tau(t, x):
        return 0.05 * np.array([np.sin(3 * t), np.cos(2 * t), -np.sin(5 * t)])
    f = task_space_rhs(p, model, 1, tau)

    def g(t, y):
        x = y[:6]
        q = ik(model, x[:3], 1)
        power = tau(t, x) @ (joint_velocity_jacobian(model, x[:3], q) @ x[3:]) - friction_power(p, model, x[:3], x[3:])
        return np.append(f(t, x), power)
    t, y = rk4(g, 0.0, np.append(START_TILT, 0.0), H, N_2S)
    _away_from_singularities(model, y[:, :3])
    E = total_energy(p, model, y[:, :3], y[:, 3:6])
    lost = np.max(np.abs(E - E[0] - y[:, 6]))
    scale = np.max(np.abs(y[:, 6])) + np.max(kinetic_energy(p, model, y[:, :3], y[:, 3:6]))
    assert np.max(np.abs(E - E[0])) > 1e-3 * scale    # energy does change
    assert lost <= 1e-9 * scale


# ---------------------------------------------------------------------------- joint space vs task space
def test_joint_space_with_dk_matches_task_space(model):
    p = DynamicParameters(gravity=G_TILT)         # default friction

    def tau(t, x):
        return 0.05 * np.array([np.sin(3 * t), np.cos(2 * t), -np.sin(5 * t)])
    _, xt = rk4(task_space_rhs(p, model, 1, tau), 0.0, START_TILT, H, N_2S)
    _away_from_singularities(model, xt[:, :3])
    X0, dX0 = START_TILT[:3], START_TILT[3:]
    q0 = ik(model, X0, 1)
    dq0 = joint_velocity_jacobian(model, X0, q0) @ dX0
    _, xj = rk4(joint_space_rhs(p, model, NearestPoseDK(model, X0), tau), 0.0, np.concatenate([q0, dq0]), H, N_2S)
    dk = NearestPoseDK(model, X0)
    Xj = np.array([dk(qk) for qk in xj[:, :3]])
    diff = pose_distance(Xj, xt[:, :3]).max()
    print(f"\n[joint vs task] largest pose difference over 2 s: {diff:.3g}")
    assert np.ptp(xt[:, 1]) > 0.2                  # the robot did move
    assert diff <= 1e-6
    np.testing.assert_allclose(wrap(xj[:, :3] - ik(model, xt[:, :3], 1)), 0.0, atol=1e-6)


# ---------------------------------------------------------------------------- integrators
def test_rk4_is_fourth_order_and_matches_reference():
    # y' = -2 t y^2, y(0) = 1: y = 1 / (1 + t^2); plus a rotation, exact cos/sin
    def f(t, x):
        return np.array([-2.0 * t * x[0] ** 2, -x[2], x[1]])

    def exact(t):
        return np.array([1.0 / (1.0 + t * t), np.cos(t), np.sin(t)])
    errors = []
    for n in (20, 40, 80, 160):
        t, x = rk4(f, 0.0, exact(0.0), 2.0 / n, n)
        assert t[-1] == 2.0 and t[1] == 2.0 / n
        errors.append(np.abs(x[-1] - exact(2.0)).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 4.0) < 0.25), orders
    t, xr = solve_reference(f, 0.0, exact(0.0), 0.01, 200)
    assert np.abs(xr[-1] - exact(2.0)).max() < 1e-11
    _, x4 = rk4(f, 0.0, exact(0.0), 0.01, 200)
    np.testing.assert_allclose(x4, xr, atol=1e-9)
    # time is t0 + k h, not accumulated
    t, _ = rk4(lambda t, x: x, 0.1, np.ones(1), 0.1, 1000)
    assert t[-1] == 0.1 + 0.1 * 1000


def test_reference_solver_agrees_with_rk4_on_the_robot(model):
    p = DynamicParameters(gravity=G_TILT)
    f = task_space_rhs(p, model, 1)
    _, x4 = rk4(f, 0.0, START_TILT, H, 500)
    _, xr = solve_reference(f, 0.0, START_TILT, H, 500)
    assert np.abs(x4 - xr).max() < 1e-9


# ---------------------------------------------------------------------------- trajectory
def test_circle_trajectory_from_rest_and_exact_derivatives(model):
    traj = CircleTrajectory()
    X, dX, ddX = traj.task(np.array([0.0, -0.3]))
    assert np.all(dX == 0) and np.all(ddX == 0)
    np.testing.assert_allclose(X[0], [0.70, 0.30, np.deg2rad(-45.0)])
    h = 1e-5
    t = np.linspace(0.0, 3.0, 301)
    X, dX, ddX = traj.task(t)
    np.testing.assert_allclose(np.hypot(X[:, 0] - 0.45, X[:, 1] - 0.30), 0.25, atol=1e-15)
    Xp, dXp, _ = traj.task(t + h)
    Xm, dXm, _ = traj.task(t - h)
    np.testing.assert_allclose((Xp - Xm) / (2 * h), dX, atol=1e-8)
    np.testing.assert_allclose((dXp - dXm) / (2 * h), ddX, atol=1e-7)
    # cruise: one revolution in `period`, constant speed after the ramp
    speed = np.hypot(dX[:, 0], dX[:, 1])
    np.testing.assert_allclose(speed[t >= traj.ramp_time], 0.25 * 2 * np.pi / traj.period, rtol=1e-14)
    # joints: posture 1, rates and accelerations against central differences
    q, dq, ddq = traj.joint(model, t)
    qp, dqp, _ = traj.joint(model, t + h)
    qm, dqm, _ = traj.joint(model, t - h)
    np.testing.assert_allclose(wrap(qp - qm) / (2 * h), dq, atol=1e-6)
    np.testing.assert_allclose((dqp - dqm) / (2 * h), ddq, atol=1e-5 * np.abs(ddq).max())
    assert np.all(dq[0] == 0) and np.all(ddq[0] == 0)
    assert np.all(posture_of(model, X, q) == 1)


# ---------------------------------------------------------------------------- control
@pytest.mark.parametrize("bandwidth, damping", [(50.0, 1.0), (20.0, 0.7), (80.0, 1.5)])
def test_gains_place_the_requested_poles(bandwidth, damping):
    gains = ComputedTorqueGains.design(bandwidth, damping)
    poles = gains.error_dynamics().poles()
    want = np.tile(ComputedTorqueGains.requested_poles(bandwidth, damping), 3)
    key = lambda p: (round(p.real, 3), round(p.imag, 3))      # noqa: E731
    got, want = sorted(poles, key=key), sorted(want.astype(complex), key=key)
    # a double pole (damping 1) is computed to ~sqrt(eps) by the eigenvalue solver
    np.testing.assert_allclose(got, want, atol=1e-6 * bandwidth)
    np.testing.assert_allclose(gains.kp, bandwidth ** 2, rtol=1e-10)
    np.testing.assert_allclose(gains.kd, 2 * damping * bandwidth, rtol=1e-10)


def test_computed_torque_with_exact_model_cancels_the_dynamics(model, params, rng):
    """With tau from the law, the plant's acceleration is ddq_d + Kd de + Kp e (exact model)."""
    gains = ComputedTorqueGains.design(30.0, 0.8)
    X, q, dX = _states(rng, model, 8)
    dq = np.einsum("...ij,...j->...i", joint_velocity_jacobian(model, X, q), dX)
    q_d, dq_d, ddq_d = q + rng.normal(size=q.shape) * 0.01, dq + rng.normal(size=q.shape) * 0.1, rng.normal(size=q.shape)
    tau = computed_torque(params, model, gains, q, dq, X, q_d, dq_d, ddq_d)
    ddq = forward_dynamics(params, model, q, dq, X, tau)
    np.testing.assert_allclose(ddq, ddq_d + gains.kd * (dq_d - dq) + gains.kp * (q_d - q), rtol=1e-9, atol=1e-9)


@pytest.fixture(scope="module")
def tracking_runs(model):
    nominal = DynamicParameters()
    controller = ComputedTorqueController(nominal, model, ComputedTorqueGains.design(50.0, 1.0))
    traj = CircleTrajectory()
    exact = simulate_tracking(controller, nominal, traj, 2.5, H)
    heavy = simulate_tracking(controller, nominal.with_scaled_masses(1.2), traj, 2.5, H)
    return exact, heavy


def test_closed_loop_tracks_the_circle_exact_model(tracking_runs):
    exact, _ = tracking_runs
    rms, worst = exact.rms_error(0.5), exact.max_error(0.0)
    print(f"\n[computed torque, exact model] RMS joint error after 0.5 s: {rms:.3g} rad, max {worst:.3g} rad")
    assert rms <= 1e-4
    assert np.ptp(exact.X[:, 0]) > 0.45              # it went round the circle


def test_closed_loop_with_masses_off_by_20_percent(tracking_runs):
    exact, heavy = tracking_runs
    rms, worst = heavy.rms_error(0.5), heavy.max_error(0.0)
    print(f"\n[computed torque, plant masses +20 %] RMS joint error after 0.5 s: {rms:.3g} rad, max {worst:.3g} rad")
    assert np.all(np.isfinite(heavy.q))
    assert rms < 1e-2 and worst < 1e-2
    assert rms > 5 * exact.rms_error(0.5)         # the mismatch is felt
    # no growth: the last half revolution errs no more than the half revolution after the ramp
    late, early = heavy.t >= 1.5, (heavy.t >= 0.5) & (heavy.t < 1.5)
    assert np.abs(heavy.error[late]).max() <= 1.5 * np.abs(heavy.error[early]).max()


# ---------------------------------------------------------------------------- bad input
def test_bad_input_names_the_argument(model, params):
    X = np.array([0.45, 0.3, -0.7])
    q = ik(model, X, 1)
    with pytest.raises(SolverInputError, match=r"q: expected shape \(\.\.\., 3\), got \(4,\)"):
        mass_matrix(params, model, np.zeros(4), X)
    with pytest.raises(SolverInputError, match="dq: expected finite numbers"):
        forward_dynamics(params, model, q, [0.0, np.nan, 0.0], X, np.zeros(3))
    with pytest.raises(SolverInputError, match="X: expected the pose of the joints q"):
        forward_dynamics(params, model, q, np.zeros(3), X + [0.01, 0, 0], np.zeros(3))
    with pytest.raises(SolverInputError, match="tool space of posture 1"):
        mass_matrix_task(params, model, [3.0, 3.0, 0.0])
    with pytest.raises(SolverInputError, match="leading dimensions do not broadcast"):
        coriolis(params, model, np.zeros((2, 3)), np.zeros((4, 3)), X)
    with pytest.raises(SolverInputError, match="params: expected a DynamicParameters"):
        gravity({"mass": 1}, model, q, X)
    with pytest.raises(SolverInputError, match="tau: expected shape"):
        task_space_rhs(params, model, 1, tau=np.zeros(4))
    with pytest.raises(SolverInputError, match="h: expected a positive"):
        rk4(lambda t, x: x, 0.0, np.ones(2), -1e-3, 10)
    with pytest.raises(SolverInputError, match=r"f: expected f\(t, x\) of shape"):
        rk4(lambda t, x: np.ones(3), 0.0, np.ones(2), 1e-3, 10)
    with pytest.raises(SolverInputError, match="damping: expected a positive"):
        ComputedTorqueGains.design(50.0, -1.0)
    with pytest.raises(SolverInputError, match="kp: expected three positive"):
        ComputedTorqueGains(kp=[1.0, -1.0, 1.0], kd=1.0)
    with pytest.raises(SolverInputError, match="radius: expected a positive"):
        CircleTrajectory(radius=-0.1)
    with pytest.raises(SolverInputError, match="X0: expected shape"):
        NearestPoseDK(model, [0.1, 0.2])
    with pytest.raises(SolverInputError, match="gains: expected a ComputedTorqueGains"):
        computed_torque(params, model, None, q, np.zeros(3), X, q, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError):      # all of them are ValueErrors
        joint_accelerations(model, X, q, np.zeros(3), np.zeros(2))


def test_rk4_step_and_nearest_dk_follow_the_robot(model):
    """One RK4 step of the joint-space form lands on the configuration of the task-space step."""
    p = DynamicParameters()
    X0 = np.array([0.45, 0.3, -0.7])
    q0 = ik(model, X0, 1)
    dX0 = np.array([0.2, -0.1, 0.4])
    dq0 = joint_velocity_jacobian(model, X0, q0) @ dX0
    dk = NearestPoseDK(model, X0)
    xj = rk4_step(joint_space_rhs(p, model, dk), 0.0, np.concatenate([q0, dq0]), 1e-3)
    xt = rk4_step(task_space_rhs(p, model, 1), 0.0, np.concatenate([X0, dX0]), 1e-3)
    assert pose_distance(dk(xj[:3]), xt[:3]) < 1e-12
    assert dk_all(model, xj[:3]).n_real >= 2    # several assembly modes: the tracker chose one
