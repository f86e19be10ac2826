"""Tube certificates (solver._kernels.tube), the proven pose bound and the honest start."""
import warnings

import numpy as np
import pytest

from conftest import coarse_map, pose_distance, track_stream
from experiments.sensors import Sensor
from solver import Tracker, TrackerState, circle_path, dk_all, ik, jacobians, wrap_angle
from solver._kernels.kinematics import geometry
from solver._kernels.handoff import handoff
from solver._kernels.tube import (TUBE_K, TUBE_Q, TUBE_R, TUBE_S, TUBE_SIZE, TUBE_T, TUBE_V, TUBE_W, TUBE_X, predictor,
                                  slab_test, tube_test)
from solver._kernels.tube_chain import MAX_COVER, PAD, ROUNDING_KAPPA, SLABS, cover, pose_bound, refine, tube_chain
from solver.direct_kinematics import kernel_constants
from solver.tracker_state import NO_BOUND, STATE_FLOATS, TRUST


@pytest.fixture(scope="module")
def geo(model):
    return geometry(kernel_constants(model)["pack"])


def newton(model, X, q, iters=30):
    """The DK solution near ``X`` at joints ``q`` (plain Newton)."""
    from solver import constraints
    X = X.copy()
    for _ in range(iters):
        J, _ = jacobians(model, X, q)
        X = X - np.linalg.solve(J, constraints(model, X, q))
    return X


def deviation(tube, X, q):
    """x - x~ - S (q - q~), phi wrapped."""
    p = np.empty(3)
    predictor(tube, q, p)
    d = X - p
    d[2] = wrap_angle(d[2])
    return d


def assert_holds_the_solution(model, tube, q):
    """At joints ``q`` of the tube's joint set: the solution Newton finds from the predictor deviates by
    at most kappa from it, and every other real DK solution lies outside the tube."""
    p = np.empty(3)
    predictor(tube, q, p)
    X = newton(model, p, q)
    assert np.all(np.abs(deviation(tube, X, q)) <= tube[TUBE_K:TUBE_K + 3])
    for other in dk_all(model, q).real_poses():
        if pose_distance(other, X) > 1e-9:
            assert np.any(np.abs(deviation(tube, other, q)) >= tube[TUBE_R:TUBE_R + 3])


@pytest.mark.parametrize("tol", [0.0, 1e-4, 1e-3])
def test_the_tube_holds_the_solution_of_every_joint_vector_of_its_box(model, geo, rng, tol):
    """At random joints of the box: the solution Newton finds from the predictor deviates by at most
    kappa from it, and every other real DK solution lies outside the tube."""
    X0 = np.array([0.45, 0.30, -np.pi / 4])
    q0 = ik(model, X0, 1)
    tube = np.empty(TUBE_SIZE)
    assert tube_test(X0.copy(), q0, np.full(3, tol), np.zeros(3), *geo, tube)
    assert np.all(tube[TUBE_K:TUBE_K + 3] < tube[TUBE_R:TUBE_R + 3])
    for q in q0 + tol * rng.uniform(-1, 1, (40, 3)):
        assert_holds_the_solution(model, tube, q)


def test_handoff_needs_the_old_enclosure_inside_the_new_tube(model, geo):
    X0 = np.array([0.45, 0.30, -np.pi / 4])
    q0 = ik(model, X0, 1)
    a, b_ = np.empty(TUBE_SIZE), np.empty(TUBE_SIZE)
    assert tube_test(X0.copy(), q0, np.full(3, 1e-4), np.zeros(3), *geo, a)
    assert tube_test(X0.copy(), q0, np.full(3, 1e-4), np.zeros(3), *geo, b_)
    need = np.empty(3)
    assert handoff(a, b_, q0, np.eye(3), np.full(3, 1e-4), need)                 # the same tube takes over from itself
    b_[TUBE_X] += 10 * b_[TUBE_R]                                     # shifted off: it cannot
    assert not handoff(a, b_, q0, np.eye(3), np.full(3, 1e-4), need)
    assert need[0] > b_[TUBE_R]


def test_a_chain_of_tubes_follows_the_branch_along_a_path(model, geo):
    X = circle_path(100)
    q = ik(model, X, 1)
    cover, out = np.empty((MAX_COVER, TUBE_SIZE)), np.empty((MAX_COVER, TUBE_SIZE))
    assert tube_test(X[0].copy(), q[0], np.zeros(3), np.zeros(3), *geo, cover[0])
    n, used = 1, []
    for k in range(1, len(q)):
        dq = wrap_angle(q[k] - q[k - 1])
        tests, n = tube_chain(cover, n, q[k - 1].copy(), dq, 0.0, 256, *geo, out)
        assert tests > 0 and n == 1
        used.append(tests)
        assert np.all(out[0, TUBE_K:TUBE_K + 3] <= ROUNDING_KAPPA * PAD * (1 + np.abs(out[0, TUBE_X:TUBE_X + 3])))
        cover[:n] = out[:n]
        h = np.empty(3)
        assert pose_bound(cover, n, q[k - 1] + dq, 0.0, X[k], h)
        assert np.all(pose_distance(cover[0, TUBE_X:TUBE_X + 3], X[k]) <= h.max()) and h.max() < 1e-11
    # most steps: the segment's cover and the reading's, one test each (no refine: the reading's is at rounding)
    assert used.count(2) >= 0.9 * len(used), np.bincount(used)


def test_exact_joints_take_two_covers_a_step_and_a_tube_at_rounding_is_not_refined(model, geo):
    """The reading's tube (a single joint vector) starts wide enough to take over from the step's piece
    (:func:`point_prior`), so it runs once; it then ends at rounding level and :func:`refine` leaves it:
    the piece and the reading, two covers a step (counted along the circle by the chain test above).  A
    point tube whose kappa is far above rounding is refined."""
    X = circle_path(200)
    q = ik(model, X, 1)
    # why one test: the reading's point tube from its own width fails the hand-off from the step's piece,
    # from point_prior's width it passes
    from solver._kernels.handoff import point_prior, takes_over
    k, eye, z = 50, np.eye(3), np.zeros(3)
    pieces = np.empty((8, TUBE_SIZE))
    assert tube_test(X[k - 1].copy(), q[k - 1], z, z, *geo, pieces[0])
    dq = wrap_angle(q[k] - q[k - 1])
    assert cover(pieces, 1, pieces[0], q[k - 1] + 0.5 * dq, 0.5 * np.abs(dq), *geo)[0] == 2
    qk, xg, point, need = q[k - 1] + dq, np.empty(3), np.empty(TUBE_SIZE), np.zeros(3)
    predictor(pieces[1], qk, xg)
    assert slab_test(xg, qk, eye, z, z, need, *geo, point) and not takes_over(pieces, 2, point, np.empty(3))
    assert point_prior(pieces, 2, xg, qk, need) and need.min() > 2 * pieces[1, TUBE_K:TUBE_K + 3].min()
    assert slab_test(xg, qk, eye, z, z, need, *geo, point) and takes_over(pieces, 2, point, np.empty(3))
    wide = np.empty((1, TUBE_SIZE))
    assert tube_test(X[5].copy(), q[5], np.zeros(3), np.full(3, 1e-3), *geo, wide[0])       # rho 1 mm
    wide[0, TUBE_K:TUBE_K + 3] = 1e-7           # a looser kappa (still a bound): not at rounding, refined
    kappa = wide[0, TUBE_K:TUBE_K + 3].copy()
    pieces = np.empty((4, TUBE_SIZE))
    pieces[0] = wide[0]
    assert refine(wide, pieces, 1, q[5].copy(), np.zeros(3), *geo) >= 1
    assert np.all(wide[0, TUBE_K:TUBE_K + 3] < 1e-3 * kappa)
    again = wide.copy()
    assert refine(again, pieces, 1, q[5].copy(), np.zeros(3), *geo) == 0 and np.array_equal(again, wide)


def test_the_cover_solution_is_found_whatever_the_numbering(model, geo, rng):
    """:func:`cover_solution` tries the solutions nearest the cover's predictor first: the same solution
    under every order of the six, with the bound :func:`pose_bound` gives it."""
    from solver._kernels.reacquisition import cover_solution
    X0 = np.array([0.45, 0.30, -np.pi / 4])
    q0 = ik(model, X0, 1)
    tube = np.empty((1, TUBE_SIZE))
    assert tube_test(X0.copy(), q0, np.full(3, 1e-4), np.zeros(3), *geo, tube[0])
    poses, real = dk_all(model, q0)
    k_true = int(np.argmin([np.inf if not r else np.abs(pose_distance(p.real, X0)).max() for p, r in zip(poses, real)]))
    want = np.empty(3)
    assert pose_bound(tube, 1, q0, 0.0, poses[k_true].real.copy(), want)
    for _ in range(6):
        order = rng.permutation(6)
        bound = np.full(3, np.inf)
        k = cover_solution(tube, 1, q0, 0.0, np.ascontiguousarray(poses[order]), np.ascontiguousarray(real[order]),
                           bound)
        assert order[k] == k_true
        np.testing.assert_array_equal(bound, want)
    none = real.copy()
    none[k_true] = False
    bound = np.full(3, np.inf)
    assert cover_solution(tube, 1, q0, 0.0, poses, none, bound) == -1 and np.all(np.isinf(bound))


def test_a_cover_holds_a_joint_box_one_tube_cannot(model, geo):
    """An ill-conditioned joint box: the tube test fails on the whole box, the cover in parts proves it,
    and its pose bound holds the solutions of joints sampled in the box."""
    X = circle_path(1000)
    q = ik(model, X, 1)
    sigma = np.array([np.linalg.svd(jacobians(model, X[k], q[k])[0])[1][-1] for k in range(0, 1000, 10)])
    k = 10 * int(np.argmin(sigma))
    X0, q0 = X[k], q[k]
    one = np.empty(TUBE_SIZE)
    tol = next(t for t in np.geomspace(1e-5, 1e-1, 60)
               if not tube_test(X0.copy(), q0, np.full(3, t), np.zeros(3), *geo, one))
    pieces = np.empty((40, TUBE_SIZE))
    assert tube_test(X0.copy(), q0, np.zeros(3), np.zeros(3), *geo, pieces[0])
    m, _ = cover(pieces, 1, pieces[0], q0, np.full(3, tol), *geo)
    assert m > 1, f"no cover at the tolerance where one tube fails ({tol:.2e} rad)"
    h = np.empty(3)
    assert pose_bound(pieces[1:m], m - 1, q0, tol, X0, h)
    rng = np.random.default_rng(5)
    for qs in q0 + tol * rng.uniform(-1, 1, (30, 3)):
        Xs = newton(model, X0 + np.linalg.solve(*(lambda J, K: (J, -K @ (qs - q0)))(*jacobians(model, X0, q0))), qs)
        err = np.abs(Xs - X0)
        err[2] = abs(wrap_angle(Xs[2] - X0[2]))
        assert np.all(err <= h)


def in_slab(tube, q):
    """Is ``q`` (3,) in the tube's joint set: ``|V^T (q - q~)| <= tw`` and ``|q - q~| <= t``?"""
    V = tube[TUBE_V:TUBE_V + 9].reshape(3, 3)
    d = wrap_angle(q - tube[TUBE_Q:TUBE_Q + 3])
    return bool(np.all(np.abs(V.T @ d) <= tube[TUBE_W:TUBE_W + 3]) and np.all(np.abs(d) <= tube[TUBE_T:TUBE_T + 3]))


def test_a_slab_tube_holds_the_solution_of_every_joint_vector_of_its_parallelepiped(model, geo, rng):
    """slab_test over a rotated, thin joint parallelepiped: at random joints of it, the solution
    deviates from the predictor by at most kappa, and the other real solutions lie outside."""
    X0 = np.array([0.45, 0.30, -np.pi / 4])
    q0 = ik(model, X0, 1)
    V, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    tw = np.array([2e-4, 2e-3, 1e-3])
    tube = np.empty(TUBE_SIZE)
    assert slab_test(X0.copy(), q0, V, tw, np.full(3, np.inf), np.zeros(3), *geo, tube)
    assert np.allclose(tube[TUBE_T:TUBE_T + 3], np.abs(V) @ tw)           # the joint box holding it
    for w in tw * rng.uniform(-1, 1, (40, 3)):
        q = q0 + V @ w
        assert in_slab(tube, q)
        assert_holds_the_solution(model, tube, q)


def test_slabs_across_the_needle_hold_a_box_one_tube_cannot(model, geo, rng):
    """An ill-conditioned pose (|S| about 30 rad/rad, a 16-bit + 1e-4 rad encoder's tolerance): one tube
    fails on the joint box, a few slabs across the needle's joint direction prove it; at sampled
    joints every slab holding them has the same solution within its kappa, and the pose bound holds."""
    X0 = np.array([0.8521, 0.5826, 0.0317])
    q0 = ik(model, X0, 1)
    tol = 3.5e-4
    one = np.empty(TUBE_SIZE)
    assert not tube_test(X0.copy(), q0, np.full(3, tol), np.zeros(3), *geo, one)
    pieces = np.empty((60, TUBE_SIZE))
    assert tube_test(X0.copy(), q0, np.zeros(3), np.zeros(3), *geo, pieces[0])
    m, _ = cover(pieces, 1, pieces[0], q0, np.full(3, tol), *geo)
    slabs = pieces[1:m]
    assert 2 <= len(slabs) <= max(SLABS)
    v1 = slabs[0, TUBE_V:TUBE_V + 9].reshape(3, 3)[:, 0]
    S = slabs[0, TUBE_S:TUBE_S + 9].reshape(3, 3)
    assert np.linalg.norm(S @ v1) > 0.99 * np.linalg.svd(S, compute_uv=False)[0]       # across the needle
    h = np.empty(3)
    assert pose_bound(slabs, len(slabs), q0, tol, X0, h)
    for q in q0 + tol * rng.uniform(-1, 1, (40, 3)):
        holding = [t for t in slabs if in_slab(t, q)]
        assert holding                                                # the slabs cover the box
        p = np.empty(3)
        predictor(holding[0], q, p)
        X = newton(model, p, q)
        for t in holding:
            assert np.all(np.abs(deviation(t, X, q)) <= t[TUBE_K:TUBE_K + 3])
        err = np.abs(X - X0)
        err[2] = abs(wrap_angle(X[2] - X0[2]))
        assert np.all(err <= h)


def noisy_stream(model, sensor, n=1000, seed=3):
    X = circle_path(n)
    q_true = ik(model, X, 1)
    q = sensor.measure(q_true, seed=seed).q
    q[0] = q_true[0]
    return X, q_true, q


@pytest.mark.parametrize("grade", [Sensor("16-bit-1e-4", bits=16, noise=1e-4), Sensor("12-bit", bits=12, noise=1e-3)])
def test_the_pose_bound_holds_on_a_noisy_stream(model, grade):
    """Against the noise-free poses, wherever the sensor kept its tolerance: |X - X_true| <= pose_bound
    on every certain step; the bound is finite exactly there; certain on most steps."""
    X_true, q_true, q = noisy_stream(model, grade)
    tol = grade.tolerance(3.0)
    tracker = Tracker(model, coarse_map(model, 1), joint_tolerance=tol)
    X, infos = track_stream(tracker, q, X_true[0])
    kept = np.all(np.abs(wrap_angle(q - q_true)) <= tol, axis=1)
    n_certain = 0
    for k in range(1, len(q)):
        info = infos[k]
        assert np.all(np.isfinite(info.pose_bound)) == info.certain
        assert (info.trust == 2) == info.certain
        if info.certain and kept[k]:
            err = np.abs(X[k] - X_true[k])
            err[2] = abs(wrap_angle(X[k, 2] - X_true[k, 2]))
            assert np.all(err <= info.pose_bound), k
            n_certain += 1
    assert n_certain > 0.9 * kept[1:].sum()


def test_the_set_membership_box_holds_the_robot_while_uncertain(model):
    """An ill-conditioned circle (|S| up to about 80) read by a 16-bit + 1e-3 rad encoder, with a speed
    bound: where the tube chain fails the tracker keeps a pose box (the state's anchor +- anchor_bound,
    from the previous box grown by the speed bound and cut to the poses reaching the reading's joint
    box; also on the steps the eliminant re-acquires, which keep it); it holds the noise-free pose
    wherever the sensor kept its tolerance, and certainty comes back after the uncertain stretches."""
    from experiments.suite import hard_suite
    path = next(p for p in hard_suite(model, samplings=(1000,)) if p.name == "p1-circle-5mm/1000")
    grade = Sensor("16-bit", bits=16, noise=1e-3)             # at 1e-4 rad the eliminant vouches for every step
    q = grade.measure(path.q, seed=1000).q
    q[0] = path.q[0]
    tol = grade.tolerance(3.0)
    v = 1.25 * np.max(np.hypot(*np.diff(path.X[:, :2], axis=0).T)) / 1e-3
    w = max(1.25 * np.max(np.abs(wrap_angle(np.diff(path.X[:, 2])))) / 1e-3, 0.5)
    tracker = Tracker(model, coarse_map(model, 1), joint_tolerance=tol, speed_bound=(v, w),
                      start_tolerance=(1e-9, 1e-9, 1e-9))
    tracker.reset(path.X[0], q[0])
    kept = np.all(np.abs(wrap_angle(q - path.q)) <= tol, axis=1)
    boxes, certain = 0, []
    for k in range(1, len(q)):
        _, info = tracker.step(q[k], 1e-3)
        certain.append(info.certain)
        st = tracker.state
        if st.paving is not None and st.anchor_age == 0.0 and kept[k]:
            d = np.abs(path.X[k] - st.anchor)
            d[2] = abs(wrap_angle(path.X[k, 2] - st.anchor[2]))
            assert np.all(d <= st.anchor_bound), k
            boxes += 1
    assert boxes > 10
    first = certain.index(False) if False in certain else len(certain)
    assert any(certain[first:]) or first == len(certain)          # certainty comes back


def test_an_approximate_start_within_the_start_tolerance_is_certain(model):
    X = circle_path(200)
    q = ik(model, X, 1)
    tracker = Tracker(model, coarse_map(model, 1), start_tolerance=(0.01, 0.01, 0.05))
    start = tracker.reset(X[0] + np.array([0.004, -0.003, 0.02]), q[0])
    assert start.certain and start.reason == "" and tracker.state.certain
    assert pose_distance(start.X, X[0]) < 1e-12                  # the DK solution, not the pose given
    assert np.all(start.pose_bound < 1e-11)
    res = tracker.track(q, X[0] + np.array([0.004, -0.003, 0.02]))
    assert res.certain.all() and pose_distance(res.X, X).max() < 1e-9


def test_a_start_outside_the_start_tolerance_is_not_certain_and_says_why(model):
    X = circle_path(200)
    q = ik(model, X, 1)
    tracker = Tracker(model, coarse_map(model, 1), start_tolerance=(0.001, 0.001, 0.005))
    start = tracker.reset(X[0] + np.array([0.004, 0.0, 0.0]), q[0])
    assert not start.certain and "start_tolerance" in start.reason and not tracker.state.certain
    assert np.all(np.isinf(start.pose_bound))
    _, info = tracker.step(q[1], 1e-3)
    assert not info.certain and info.uncertain_since == 0       # exact joints: no way back without a start


def test_a_start_tolerance_that_holds_two_solutions_is_not_certain(model):
    X0 = np.array([0.45, 0.30, -np.pi / 4])
    q0 = ik(model, X0, 1)
    sols = dk_all(model, q0).real_poses()
    far = max(pose_distance(s, X0) for s in sols)
    tracker = Tracker(model, coarse_map(model, 1), start_tolerance=(far + 1, far + 1, 7.0))
    start = tracker.reset(X0, q0)
    assert not start.certain and "smaller start_tolerance" in start.reason


def test_a_default_tracker_on_encoder_readings_takes_half_a_step_and_says_so(model):
    """Exact 16-bit readings, joint_tolerance left at 0: the tracker recognises the encoder grid at the
    reset, warns, takes half a step as its tolerance, and its bound then holds against the robot."""
    sensor = Sensor("16-bit-exact", bits=16)
    X_true, q_true, q = noisy_stream(model, sensor, n=1000)        # 1 kHz, a revolution a second
    q[0] = sensor.measure(q_true[:1], seed=0).q[0]
    tracker = Tracker(model, coarse_map(model, 1))
    with pytest.warns(UserWarning, match="16-bit encoder grid"):
        res = tracker.track(q, X_true[0])
    assert "joint_tolerance" in tracker.start.note and tracker.joint_tolerance == pytest.approx(np.pi / 2 ** 16)
    assert "pass speed_bound" in tracker.start.note                       # what else to set
    bounded = Tracker(model, coarse_map(model, 1), speed_bound=(2.0, 2.0))
    with pytest.warns(UserWarning, match="16-bit encoder grid"):
        assert "speed_bound" not in bounded.reset(X_true[0], q[0]).note
    assert res.certain.mean() > 0.9
    err = np.abs(res.X - X_true)
    err[:, 2] = np.abs(wrap_angle(res.X[:, 2] - X_true[:, 2]))
    assert np.all(err[res.certain] <= res.pose_bound[res.certain])
    assert Tracker(model, coarse_map(model, 1)).reset(X_true[0], q_true[0]).note == ""   # float joints: exact
    from solver.encoder_grid import encoder_bits
    assert encoder_bits([0.0, np.pi / 2, -np.pi]) is None                               # set by hand
    assert encoder_bits(np.array([3, -700, 12345]) * 2 * np.pi / 2 ** 14) == 14


def test_a_tracker_started_at_exact_joints_then_fed_encoder_readings_says_so_and_is_never_silently_wrong(model):
    """Homed at exact joints (the reset's q0 off any grid), then exact 16-bit readings: the first reading
    on the grid makes the tracker take half a step as its tolerance, with a warning that says what to
    set; from there on it is never certain and wrong, and its bound holds against the robot."""
    sensor = Sensor("16-bit-exact", bits=16)
    X_true, q_true, q = noisy_stream(model, sensor, n=600)
    q[0] = q_true[0]
    tracker = Tracker(model, coarse_map(model, 1))
    with pytest.warns(UserWarning, match="the reading of step 1 lies on a 16-bit encoder grid"):
        res = tracker.track(q, X_true[0])
    assert tracker.start.note == "" and tracker.joint_tolerance == pytest.approx(np.pi / 2 ** 16)
    err = np.abs(res.X - X_true)
    err[:, 2] = np.abs(wrap_angle(res.X[:, 2] - X_true[:, 2]))
    assert np.all(err[res.certain] <= res.pose_bound[res.certain])
    assert res.certain.mean() > 0.9
    exact = Tracker(model, coarse_map(model, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert exact.track(q_true[:50], X_true[0]).certain.all()        # float joints: nothing to say


def test_the_tube_survives_a_rejected_step_and_a_saved_state(model):
    grade = Sensor("16-bit-1e-4", bits=16, noise=1e-4)
    X_true, q_true, q = noisy_stream(model, grade, n=300)
    tracker = Tracker(model, coarse_map(model, 1), joint_tolerance=grade.tolerance(3.0))
    track_stream(tracker, q[:100], X_true[0])
    saved = tracker.state.as_array()
    assert saved.shape == (STATE_FLOATS,) and tracker.state.tube is not None and tracker.state.tube.ndim == 2
    with pytest.raises(Exception):
        tracker.step([np.nan, 0.0, 0.0], 1e-3)
    _, a = tracker.step(q[100], 1e-3)
    tracker.state = TrackerState.from_array(saved)
    _, b = tracker.step(q[100], 1e-3)
    assert a.certain and b.certain and np.array_equal(a.pose_bound, b.pose_bound)
    assert TRUST[a.trust] == "certain" and a.trust_name == "certain"
    assert NO_BOUND.flags.writeable is False
