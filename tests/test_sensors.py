"""The tracker fed by sensors: the sensor model, the tube certificates, the outlier gate."""
import numpy as np
import pytest

from conftest import pose_distance, track_stream
from experiments.sensors import SENSOR_GRADES, Sensor, sensor_truth
from experiments.suite import default_suite, near_singular_circle, make_path
from solver import STATUS, SolverInputError, Tracker, wrap_angle
from solver._kernels.certify import TINY
from solver._kernels.krawczyk import W_SIZE, krawczyk, newton_on_path
from solver._kernels.kinematics import geometry
from solver._kernels.layout import STATE_ANCHOR_AGE, STATE_REFUSED, STATE_SIZE
from solver.direct_kinematics import kernel_constants
from solver.sensors import quantize
from solver.trajectories import circle_path
from solver.tracker_state import TrackerState

REJECTED = [k for k, v in STATUS.items() if v == "rejected"][0]
TOL = Sensor("14-bit", bits=14, noise=1e-3).tolerance(3.0)


@pytest.fixture(scope="module")
def map1(coarse_map1):
    return coarse_map1


@pytest.fixture(scope="module")
def near_fold(model):
    """The posture-1 circle passing 5 mm from a type-1 singularity, at 1000 samples (1 kHz, 1 rev/s)."""
    radius, _ = near_singular_circle(model, 1, (0.50, 0.29), 0.0, 0.005)
    return make_path(model, "p1-near-sing-5mm/1000", 1, circle_path(1000, (0.50, 0.29), radius, 0.0))


def run(tracker, q, X0):
    """Poses (n, 3) and ``certain`` (n,) of a tracked stream (the reset counts as certain)."""
    X, infos = track_stream(tracker, q, X0)
    return X, np.array([True] + [i.certain for i in infos[1:]])


def wrong(X, truth):
    return pose_distance(X, truth) > 1e-6


# ----------------------------------------------------------------------------- the sensor model
def test_quantization_puts_every_reading_on_the_encoder_grid(rng):
    q = rng.uniform(-np.pi, np.pi, (200, 3))
    for bits in (12, 14, 16):
        res = 2 * np.pi / 2 ** bits
        m = quantize(q, bits)
        np.testing.assert_allclose(m / res, np.round(m / res), atol=1e-6)
        assert np.max(np.abs(m - q)) <= res / 2 + 1e-12
    with pytest.raises(SolverInputError, match="bits"):
        quantize(q, 0)


def test_sensor_streams_are_deterministic_and_glitch_where_they_say(model, rng):
    q = np.cumsum(rng.normal(0, 1e-3, (600, 3)), axis=0)
    for sensor in SENSOR_GRADES:
        a, b = sensor.measure(q, seed=7), sensor.measure(q, seed=7)
        np.testing.assert_array_equal(a.q, b.q)
        if sensor.glitch is None:
            assert not a.glitch.any()
            assert np.max(np.abs(a.q - q)) < sensor.tolerance(6.0) + 1e-12
            continue
        assert a.glitch.any() and not a.glitch[:3].any()
        if sensor.glitch == "dropout":
            assert np.array_equal(np.isnan(a.q).any(axis=1), a.glitch)
        if sensor.glitch == "outlier":
            jumps = np.max(np.abs(a.q - q), axis=1)
            assert np.all(jumps[a.glitch] > 0.09) and np.all(jumps[~a.glitch] < 0.02)
        if sensor.glitch == "stuck":
            starts = np.nonzero(a.glitch & ~np.roll(a.glitch, 1))[0]
            for k in starts:                       # one joint holds the value it had before the glitch
                held = a.q[k:k + sensor.stuck] == a.q[k - 1]
                assert held.all(axis=0).any()
    with pytest.raises(SolverInputError, match="glitch"):
        Sensor("bad", glitch="spike")


def test_truth_counts_only_clearly_nearest_steps(model, near_fold):
    sensor = Sensor("12-bit", bits=12, noise=1e-3)
    stream = sensor.measure(near_fold.q, seed=3)
    X, counted = sensor_truth(model, stream.q, near_fold.X)
    assert counted.mean() > 0.8
    far = np.max(np.abs(X - near_fold.X), axis=1)
    assert np.median(far[counted]) < 0.01              # mostly the noise-free pose moved by the noise
    _, counted_strict = sensor_truth(model, stream.q, near_fold.X, factor=30.0)
    assert counted_strict.sum() < counted.sum()


# ----------------------------------------------------------------------------- tube certificates
def test_krawczyk_over_a_joint_box_holds_the_solution_of_every_joint_in_it(model, rng):
    M, l1, b, l2sq = (lambda g: (g[0], g[1], g[3], g[2]))(geometry(kernel_constants(model)["pack"]))
    from solver import ik
    X = np.array([0.5, 0.35, 0.1])
    q = ik(model, X, 1)
    zero, w = np.zeros(3), np.empty(W_SIZE)
    eps = 1e-3
    rho = np.full(3, 0.02)
    assert krawczyk(X, rho, q, zero, zero, 0.0, 0.0, np.full(3, eps), M, l1, b, l2sq, w)
    assert not krawczyk(X, np.full(3, TINY), q, zero, zero, 0.0, 0.0, np.full(3, eps), M, l1, b, l2sq, w)
    assert not krawczyk(X, rho, q, zero, zero, 0.0, 0.0, np.full(3, 0.3), M, l1, b, l2sq, w)
    for _ in range(50):                            # every joint vector of the box has its solution inside
        qe = q + rng.uniform(-eps, eps, 3)
        Xe = X.copy()
        assert newton_on_path(Xe, qe, zero, zero, 0.0, M, l1, b, l2sq, w, 30) < 1e-12
        assert np.all(np.abs(Xe - X) <= rho)


def test_measured_joints_past_a_fold_are_never_vouched_for_when_wrong(model, map1, near_fold):
    """12-bit encoder with 1e-3 rad of noise on a circle 5 mm from a singularity: the measured joints
    cross a fold that the robot does not.  Proved along the measured joints alone (tolerance 0, the
    readings calibrated off the encoder grid so that nothing tells them from exact joints) the tracker
    vouches for wrong poses; with the sensor's tolerance it never does, nor does the default tracker
    given the raw readings (it sees the grid and takes half a step)."""
    sensor = Sensor("12-bit", bits=12, noise=1e-3)
    stream = sensor.measure(near_fold.q, seed=1000)
    q = stream.q.copy()
    q[0] = near_fold.q[0]
    truth, counted = sensor_truth(model, q, near_fold.X)
    calibrated = q + 1e-8                                          # off the grid: floats like exact joints
    truth_c, counted_c = sensor_truth(model, calibrated, near_fold.X)
    X0, c0 = run(Tracker(model, map1), calibrated, near_fold.X[0])
    assert np.sum(wrong(X0, truth_c) & counted_c & c0) > 0        # silent errors without the tube
    with pytest.warns(UserWarning, match="12-bit encoder grid"):
        Xg, cg = run(Tracker(model, map1), q, near_fold.X[0])
    assert np.sum(wrong(Xg, truth) & counted & cg) == 0
    X1, c1 = run(Tracker(model, map1, joint_tolerance=sensor.tolerance(3.0)), q, near_fold.X[0])
    assert np.sum(wrong(X1, truth) & counted & c1) == 0
    assert c1[:10].all()                                          # vouched for at the start


def test_exact_joints_are_unchanged_by_a_zero_tolerance(model, map1):
    path = default_suite(model, samplings=(100,))[0]
    a = Tracker(model, map1).track(path.q, path.X[0])
    tr = Tracker(model, map1, joint_tolerance=0.0)
    b = tr.track(path.q, path.X[0])
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.certain, b.certain)
    assert a.certain.all() and not np.any(b.status == REJECTED)


# ----------------------------------------------------------------------------- the outlier gate
def _noisy_circle(model, n=400, seed=5):
    X = circle_path(n)
    from solver import ik
    exact = ik(model, X, 1)
    q = Sensor("14-bit", bits=14, noise=1e-3).measure(exact, seed=seed).q
    q[0] = exact[0]                                   # the tracker starts from a known configuration
    return X, q


def test_an_outlier_is_refused_with_the_state_intact_and_the_next_sample_continues(model, map1):
    X, q = _noisy_circle(model)
    tol = Sensor("14-bit", bits=14, noise=1e-3).tolerance(3.0)
    tr = Tracker(model, map1, joint_tolerance=tol)
    tr.reset(X[0], q[0])
    for k in range(1, 200):
        tr.step(q[k], 1e-3)
    before = tr.state.as_array()
    bad = q[200].copy()
    bad[1] += 0.1
    Xr, info = tr.step(bad, 1e-3)
    assert info.status == REJECTED and not info.certain
    np.testing.assert_array_equal(Xr, tr.state.X)
    after = tr.state.as_array()
    same = np.isclose(before, after, equal_nan=True)
    assert same.sum() == len(before) - 3 and tr.state.refused == tr.state.skipped == 1   # only the counts moved
    assert tr.state.skipped_time == 1e-3                                                    # (and their seconds)
    ref = Tracker(model, map1, joint_tolerance=tol)
    ref.reset(X[0], q[0])
    for k in range(1, 202):
        if k != 200:
            Xg, ig = ref.step(q[k], 1e-3 if k != 201 else 2e-3)
    Xn, info = tr.step(q[201], 1e-3)
    assert info.status != REJECTED and info.certain == ig.certain
    np.testing.assert_allclose(Xn, Xg, atol=1e-9)            # as if the outlier had never come


@pytest.mark.parametrize("held_dt, dt", [(5e-3, 1e-3), (1e-3, 7e-3)])
def test_a_refused_sample_only_delays_the_next_step_over_uneven_time_steps(model, map1, held_dt, dt):
    """The step after a refused sample sees the time since the last accepted one as the sum of the
    two samples' steps, whatever they are: its state pack is that of one step over that time (the
    anchor's age, the speed gate's step, the extrapolation scale), but for the refusal count.
    With the seconds counted as samples times the last ``dt`` the robot's region came out too small
    (the paving and re-acquisition proved in a box the robot may have left)."""
    X, q = _noisy_circle(model)
    make = lambda: Tracker(model, map1, joint_tolerance=TOL, speed_bound=(2.0, 2.0))   # noqa: E731
    tr, ref = make(), make()
    for t in (tr, ref):
        t.reset(X[0], q[0])
        for k in range(1, 120):
            t.step(q[k], 1e-3)
    k_bad = 119 + round(held_dt / 1e-3)                         # the samples the time steps stand for
    bad = q[k_bad].copy()
    bad[0] += 0.1
    _, info = tr.step(bad, held_dt)
    assert info.status == REJECTED and tr.state.skipped_time == held_dt
    a, b = np.zeros(STATE_SIZE), np.zeros(STATE_SIZE)
    tr.state.pack(a, dt)
    ref.state.pack(b, held_dt + dt)
    assert a[STATE_ANCHOR_AGE] == pytest.approx(ref.state.anchor_age + held_dt + dt, rel=1e-12)
    assert a[STATE_REFUSED] == 1 and b[STATE_REFUSED] == 0
    a[STATE_REFUSED] = 0
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
    saved = TrackerState.from_array(tr.state.as_array())       # the seconds survive a save
    assert saved.skipped_time == held_dt
    Xn, info = tr.step(q[k_bad + round(dt / 1e-3)], dt)
    Xg, ig = ref.step(q[k_bad + round(dt / 1e-3)], held_dt + dt)
    assert info.status == ig.status == 0 and info.certain == ig.certain
    np.testing.assert_array_equal(Xn, Xg)
    assert tr.state.skipped_time == 0.0 and tr.state.dt == pytest.approx(held_dt + dt, rel=1e-12)


def _tracked(model, map1, n):
    """A tracker with the 14-bit tolerance that has tracked the noisy circle's first ``n`` samples."""
    X, q = _noisy_circle(model)
    tr = Tracker(model, map1, joint_tolerance=TOL)
    tr.reset(X[0], q[0])
    for k in range(1, n):
        tr.step(q[k], 1e-3)
    return tr, q


def test_a_dropout_is_refused_by_name_and_changes_nothing(model, map1):
    tr, q = _tracked(model, map1, 50)
    before = tr.state
    with pytest.raises(SolverInputError, match="q"):
        tr.step([q[50, 0], np.nan, q[50, 2]], 1e-3)
    assert tr.state is before
    _, info = tr.step(q[51], 1e-3)
    assert info.certain and info.status != REJECTED


def test_a_level_change_is_taken_after_refusals_and_ends_the_vouching(model, map1):
    tr, q = _tracked(model, map1, 100)
    shifted = q[100:110].copy()
    shifted[:, 0] += 0.1                              # a joint that jumps and stays (a stuck encoder let go)
    statuses = [tr.step(s, 1e-3)[1] for s in shifted]
    assert [i.status == REJECTED for i in statuses[:3]] == [True, True, False]
    assert not any(i.certain for i in statuses) and not tr.state.intact


def test_joint_tolerance_is_checked(model, map1):
    for bad in (-1e-3, np.nan, "1e-3"):
        with pytest.raises(ValueError, match="joint_tolerance"):
            Tracker(model, map1, joint_tolerance=bad)


# ----------------------------------------------------------------------------- re-acquisition
def test_posture_preimage_proof_refuses_a_second_solution_in_the_posture(model):
    """At this pose two real DK solutions share posture 1: no box about one of them can hold every
    posture-1 pose of the tool space that reaches the joints; with the region cut to exclude the
    other one, the proof goes through."""
    from solver import ik, dk_all, posture_of
    from solver._kernels.exclusion import posture_preimage_in
    from solver._kernels.krawczyk import W_TOT
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    X = np.array([0.5, 0.35, 0.1])
    q = ik(model, X, 1)
    sol = dk_all(model, q[None])
    real = sol.poses[0].real[sol.real[0]]
    same = real[posture_of(model, real, np.repeat(q[None], len(real), 0)) == 1]
    assert len(same) == 2
    eps, zero, w = 1e-3, np.zeros(3), np.empty(W_SIZE)
    rho = np.full(3, 2 * TINY)
    while not krawczyk(X, rho, q, zero, zero, 0.0, 0.0, np.full(3, eps), M, l1, b, l2sq, w):
        rho = np.maximum(rho, 1.25 * w[W_TOT:W_TOT + 3] + 2 * TINY)
    whole = np.array([-0.2, 1.2, -0.3, 1.1, -np.pi, np.pi])
    assert posture_preimage_in(X, rho, q, eps, 0, whole, M, l1, l2sq, b, 20000) < 0
    near = np.array([X[0] - 0.1, X[0] + 0.1, X[1] - 0.1, X[1] + 0.1, X[2] - 0.5, X[2] + 0.5])
    other = same[np.argmax(np.abs(same[:, 2] - X[2]))]
    assert abs(other[2] - X[2]) > 0.5                              # the other one is outside the region
    assert posture_preimage_in(X, rho, q, eps, 0, near, M, l1, l2sq, b, 20000) > 0


def test_certainty_comes_back_after_a_near_singular_passage(model, map1, near_fold):
    """The tube cannot be proved next to the singularity; away from it the branch is re-acquired
    (a speed bound keeps the robot near its last certain pose), and never wrongly."""
    sensor = Sensor("14-bit", bits=14, noise=1e-3)
    q = sensor.measure(near_fold.q, seed=1000).q.copy()
    q[0] = near_fold.q[0]
    truth, counted = sensor_truth(model, q, near_fold.X)
    tr = Tracker(model, map1, joint_tolerance=sensor.tolerance(3.0), speed_bound=(3.0, 1.0))
    X, certain = run(tr, q, near_fold.X[0])
    lost = np.nonzero(~certain)[0]
    assert lost.size and certain[lost[0]:].any()                  # lost, then regained
    assert np.sum(wrong(X, truth) & counted & certain) == 0


def test_speed_bound_is_checked(model, map1):
    for bad in ((0.0, 1.0), (1.0,), "fast"):
        with pytest.raises(ValueError, match="speed_bound"):
            Tracker(model, map1, joint_tolerance=1e-3, speed_bound=bad)


def test_a_speed_bound_from_the_plan_holds_every_planned_step_and_ignores_the_wrap_of_phi(model, coarse_map1):
    from solver.sensors import speed_bound
    t = np.arange(2001) * 1e-3
    r, omega = 0.05, 2 * np.pi                                 # a 5 cm circle a second; phi turns 3 rad/s across +-pi
    X = np.c_[0.8 + r * np.cos(omega * t), 0.6 + r * np.sin(omega * t), wrap_angle(3.0 - 3.0 * t)]
    v, w = speed_bound(X, 1e-3)
    assert v == pytest.approx(1.25 * r * omega, rel=1e-4) and w == pytest.approx(1.25 * 3.0, rel=1e-9)
    steps = np.diff(X, axis=0)
    assert np.all(np.hypot(steps[:, 0], steps[:, 1]) / 1e-3 <= v)
    assert speed_bound(X[:, :3] * [1, 1, 0], 1e-3)[1] == 0.5    # constant orientation: the least angular bound
    still = speed_bound(np.repeat(X[:1], 5, axis=0), 1e-3)      # a plan holding still: the least bounds, which
    assert still == (0.01, 0.5)                                # a tracker takes (both > 0)
    Tracker(model, coarse_map1, joint_tolerance=1e-4, speed_bound=still)
    with pytest.raises(ValueError, match=r"dt: expected a number > 0, got True"):
        speed_bound(X, True)
    with pytest.raises(ValueError, match=r"margin: expected a number >= 1, got 0.9"):
        speed_bound(X, 1e-3, margin=0.9)
    with pytest.raises(ValueError, match=r"X: expected planned poses of shape \(n, 3\) with n >= 2"):
        speed_bound(X[:1], 1e-3)
