"""Procedures 2-3 (the tracker) and the baselines."""
import numpy as np
import pytest

from conftest import coarse_map
from experiments.suite import default_suite, make_path, near_singular_circle
from solver import (STATUS, Manipulator, SolverInputError, Tracker, TrackerError, TrackerState, circle_path, dk_all,
                    ik, jacobians, wrap_angle)
from solver.baselines import BASELINES, NewtonTracker

@pytest.fixture(scope="module")
def maps(model):
    return {p: coarse_map(model, p) for p in (1, 3, 5)}


@pytest.fixture(scope="module")
def suite(model):
    return default_suite(model)


def errors(X, truth):
    d = np.abs(X - truth)
    d[:, 2] = np.abs(wrap_angle(X[:, 2] - truth[:, 2]))
    return d.max(axis=1)


# ------------------------------------------------------------------ the targets, on the suite
def test_suite_has_hard_and_easy_paths(suite):
    postures = {p.posture for p in suite}
    assert len(postures) >= 3
    assert {len(p.X) for p in suite} >= {1000, 30}
    assert any(p.resolvable for p in suite) and any(not p.resolvable for p in suite)
    assert min(p.min_gap for p in suite) < 5e-3                 # two solutions come within 5 mm


def test_newton_jumps_branch_near_singularities(model, suite):
    """The suite contains the failure the paper is about."""
    bad = 0
    for p in suite:
        if "near-sing" in p.name:
            res = NewtonTracker(model).track(p.q, p.X[0])
            bad += int(np.sum(errors(res.X, p.X) > 1e-6))
    assert bad > 0


def test_default_mode_has_no_branch_error_on_resolvable_paths_and_beats_every_method(model, maps, suite):
    totals = {}
    for p in suite:
        makers = {"default": Tracker(model, maps[p.posture]),
                  "paper": Tracker(model, maps[p.posture], mode="paper")}
        makers.update({n: c(model) for n, c in BASELINES.items()})
        for name, tr in makers.items():
            e = errors(tr.track(p.q, p.X[0]).X, p.X)
            n_err = int(np.sum(e > 1e-6))
            if name == "default" and p.resolvable:
                assert n_err == 0, p.name
            totals[name] = totals.get(name, 0) + n_err
    for name, n in totals.items():
        if name != "default":
            assert totals["default"] < n, totals


# ------------------------------------------------------------------ procedures 2-3 as written
def test_paper_mode_follows_procedures_2_and_3(model, maps):
    mt = maps[1]
    radius, _ = near_singular_circle(model, 1, (0.50, 0.29), 0.0, 0.01)   # crosses label borders
    X = circle_path(300, (0.50, 0.29), radius, 0.0)
    q = ik(model, X, 1)
    tr = Tracker(model, mt, mode="paper")
    tr.reset(X[0], q[0])
    seen_border = seen_far = 0
    for k in range(1, len(q)):
        st = tr.state
        Xk, info = tr.step(q[k])
        near = mt.near_labels(st.X)
        near[0] = False
        J, K = jacobians(model, st.X, st.q)
        pred = st.X - np.linalg.solve(J, K @ wrap_angle(q[k] - st.q))
        np.testing.assert_allclose(info.X_pred, pred, atol=1e-12)
        assert info.near_border == (near.sum() > 1)
        region = int(np.nonzero(near)[0][0]) if near.sum() == 1 else int(mt.label_at(pred))
        sol = dk_all(model, q[k], rule=mt.rule)
        if region and sol.real[region - 1]:
            assert info.label == region
            np.testing.assert_allclose(Xk, sol.poses[region - 1].real, atol=1e-12)
        else:
            assert info.ambiguous
        seen_border += info.near_border
        seen_far += not info.near_border
    assert seen_border > 0 and seen_far > 0


# ------------------------------------------------------------------ interface and state
def test_track_starts_at_x0_and_reports_per_step(model, maps):
    X = circle_path(200)
    q = ik(model, X, 1)
    tracker = Tracker(model, maps[1])
    res = tracker.track(q, X[0])
    assert tracker.start.certain and res.certain[0]                 # the honest start: the DK solution of q[0]
    np.testing.assert_allclose(res.X[0], X[0], atol=1e-12)
    assert res.X.shape == (200, 3) and res.label.shape == (200,)
    assert np.all(res.n_real[1:] >= 2) and np.all(res.status[1:] == 0)
    assert np.all(errors(res.X, X) < 1e-9)
    assert np.all((res.cond[1:] > 0) & (res.cond[1:] <= 1))


def test_state_is_kept_apart_and_restorable(model, maps):
    X = circle_path(100)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    for k in range(1, 10):
        tr.step(q[k])
    saved = tr.state
    a = [tr.step(q[k])[0] for k in range(10, 20)]
    tr.state = saved                                            # roll back
    b = [tr.step(q[k])[0] for k in range(10, 20)]
    np.testing.assert_array_equal(a, b)
    again = TrackerState.from_array(saved.as_array())
    np.testing.assert_array_equal(again.as_array(), saved.as_array())
    with pytest.raises(TrackerError, match="state"):
        TrackerState.from_array([1, 2, 3])


def test_bad_input_leaves_the_state_untouched(model, maps):
    X = circle_path(100)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    tr.step(q[1])
    before = tr.state
    for bad in ([np.nan, 0, 0], [0, np.inf, 0], [0, 0], [[0, 0, 0]], "abc"):
        with pytest.raises(SolverInputError, match="q"):
            tr.step(bad)
        assert tr.state is before
    X2, info = tr.step(q[2])                                     # continues correctly
    assert errors(X2[None], X[2][None])[0] < 1e-9 and info.status == 0
    with pytest.raises(TrackerError, match="reset"):
        Tracker(model, maps[1]).step(q[0])


def test_unreachable_joints_hold_the_pose_and_tracking_resumes(model, maps):
    X = circle_path(100)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    X1, _ = tr.step(q[1])
    far = np.array([np.pi, 0.0, np.pi / 2])     # D1, D2 2.2 m apart > 0.6 + 0.3 + 0.6: no assembly
    assert dk_all(model, far).n_real == 0
    Xh, info = tr.step(far)
    assert info.status == 1 and STATUS[info.status] == "unreachable" and info.n_real == 0
    np.testing.assert_array_equal(Xh, X1)
    X2, info = tr.step(q[2])
    assert info.status == 0 and errors(X2[None], X[2][None])[0] < 1e-9


def test_joint_angles_modulo_two_pi(model, maps):
    X = circle_path(150)
    q = ik(model, X, 1)
    shift = 2 * np.pi * np.array([1, -2, 3])
    a = Tracker(model, maps[1]).track(q, X[0]).X
    b = Tracker(model, maps[1]).track(q + shift, X[0]).X
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_a_jump_is_flagged_ambiguous(model, maps):
    X = circle_path(1000)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    for k in range(1, 50):
        _, info = tr.step(q[k])
        assert not info.ambiguous and not info.jump
    _, info = tr.step(q[400])                                   # 350 steps at once
    assert info.jump and info.ambiguous


def test_a_singular_configuration_is_flagged(model, maps):
    radius, r_star = near_singular_circle(model, 1, (0.50, 0.29), 0.0, 0.0)
    X = circle_path(2000, (0.50, 0.29), r_star, 0.0)
    q = ik(model, X, 1)
    J = np.linalg.det(jacobians(model, X, q)[0])
    k = int(np.argmin(np.abs(J)))                                 # the touching point
    tr = Tracker(model, maps[1])
    tr.reset(X[k - 5], q[k - 5])
    statuses = [tr.step(q[j])[1].status for j in range(k - 4, k + 1)]
    assert statuses[-1] == 2 and STATUS[2] == "singular"


def test_constructor_checks(model, maps):
    other = Manipulator.symmetric(1.0, 0.6, 0.65, 0.3, name="other")
    with pytest.raises(TrackerError, match="geometry"):
        Tracker(other, maps[1])
    with pytest.raises(TrackerError, match="mode"):
        Tracker(model, maps[1], mode="magic")
    with pytest.raises(TrackerError, match="map_tensor"):
        Tracker(model, "map.npz")
    with pytest.raises(TrackerError, match="ambiguity_ratio"):
        Tracker(model, maps[1], ambiguity_ratio=-1)


def test_baselines_share_the_interface(model):
    X = circle_path(100)
    q = ik(model, X, 1)
    for name, cls in BASELINES.items():
        res = cls(model).track(q, X[0])
        assert np.all(errors(res.X, X) < 1e-9), name
        with pytest.raises(SolverInputError):
            tr = cls(model)
            tr.reset(X[0], q[0])
            tr.step([np.nan, 0, 0])


def test_make_path_measures_the_ambiguity_ratio(model):
    X = circle_path(50)
    p = make_path(model, "c", 1, X)
    w = np.array([1.0, 1.0, np.mean(model.platform_radius) ** 2])
    ratios = []
    for k in range(len(X)):
        sol = dk_all(model, p.q[k])
        others = [P for P in sol.real_poses() if errors(P[None], X[k][None])[0] > 1e-9]
        gap = min(np.sqrt(np.sum(w * np.r_[P[:2] - X[k, :2], wrap_angle(P[2] - X[k, 2])] ** 2))
                  for P in others)
        prev = X[k - 1]
        step = np.sqrt(np.sum(w * np.r_[X[k, :2] - prev[:2], wrap_angle(X[k, 2] - prev[2])] ** 2))
        ratios.append(step / gap)
    assert p.ratio == pytest.approx(max(ratios), rel=1e-9)
    assert p.resolvable == (max(ratios) < 0.5)


def test_time_steps_scale_the_extrapolation(model, maps):
    """Constant dt is the uniform case; a bad dt is refused with the state intact."""
    radius, _ = near_singular_circle(model, 1, (0.50, 0.29), 0.0, 0.005)
    X = circle_path(100, (0.50, 0.29), radius, 0.0)
    q = ik(model, X, 1)
    a, b = Tracker(model, maps[1]), Tracker(model, maps[1])
    a.reset(X[0], q[0])
    b.reset(X[0], q[0])
    for k in range(1, len(q)):
        np.testing.assert_array_equal(a.step(q[k])[0], b.step(q[k], dt=0.01)[0])
    assert b.state.dt == 0.01 and np.isnan(a.state.dt)
    before = b.state
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(SolverInputError, match="dt"):
            b.step(q[0], dt=bad)
        assert b.state is before
    # the same path sampled twice as densely for a while: half steps, dt says so
    c = Tracker(model, maps[1])
    c.reset(X[0], q[0])
    for k in range(1, len(q)):
        if 30 <= k < 60:
            mid = ik(model, 0.5 * (X[k - 1] + X[k]), 1)
            c.step(mid, dt=0.005)
            Xk, _ = c.step(q[k], dt=0.005)
        else:
            Xk, _ = c.step(q[k], dt=0.01)
        assert errors(Xk[None], X[k][None])[0] < 1e-9


def test_state_packs_itself_and_reads_the_result_pack(model, maps):
    """TrackerState.pack writes the fields the step reads at their offsets; TrackerState.after makes the
    next state from the result pack (an accepted step a new state, a refused one only the counts)."""
    from solver._kernels import layout as lay

    X = circle_path(200)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    for k in range(1, 6):
        tr.step(q[k], 1e-3 * k)
    st = tr.state
    pk = np.full(lay.STATE_SIZE, -1.0)
    st.pack(pk, 2e-3)
    np.testing.assert_array_equal(pk[lay.STATE_X:lay.STATE_X + 3], st.X)
    np.testing.assert_array_equal(pk[lay.STATE_Q:lay.STATE_Q + 3], st.q)
    np.testing.assert_array_equal(pk[lay.STATE_X2:lay.STATE_X2 + 3], st.X2)
    np.testing.assert_array_equal(pk[lay.STATE_Q2:lay.STATE_Q2 + 3], st.q2)
    n = len(st.candidates)
    assert pk[lay.STATE_N_CAND] == n >= 1 and pk[lay.STATE_HAVE_Q2] == 1.0 and pk[lay.STATE_HISTORY] == 2
    np.testing.assert_array_equal(pk[lay.STATE_CANDS:lay.STATE_CANDS + 3 * n], st.candidates.ravel())
    assert pk[lay.STATE_EXT_SCALE] == pytest.approx(2e-3 / 5e-3)      # this time step over the last one
    assert pk[lay.STATE_DQ_SCALE] == st.dq_scale > 0
    out_real, out_int = tr._out_real.copy(), tr._out_int.copy()       # the result pack of the last step
    out_int[lay.I_STATUS] = lay.STATUS_REJECTED
    refused = st.after(q[6], 2e-3, out_real, out_int, {})
    assert refused.X is st.X and (refused.refused, refused.skipped, refused.steps) == (1, 1, st.steps)
    out_int[lay.I_STATUS] = lay.STATUS_OK
    out_real[lay.OUT_X:lay.OUT_X + 3] = X[6]
    taken = st.after(q[6], 2e-3, out_real, out_int, {})
    np.testing.assert_array_equal(taken.X, X[6])
    assert taken.X2 is st.X and taken.q2 is st.q and taken.steps == st.steps + 1 and taken.dt == 2e-3
    assert len(taken.candidates) == out_int[lay.I_N_CAND]


def test_options_are_one_checked_object_the_keywords_make(model, coarse_map1):
    from solver import TrackerOptions
    from solver.checks import Bound, check_number
    from solver.options import BOUNDS

    by_keywords = Tracker(model, coarse_map1, joint_tolerance=1e-4, speed_bound=[0.5, 2.0], max_tests=np.int64(300))
    opts = by_keywords.options
    assert opts == TrackerOptions(joint_tolerance=1e-4, speed_bound=(0.5, 2.0), max_tests=300)
    assert isinstance(opts.max_tests, int) and opts.speed_bound == (0.5, 2.0)
    by_object = Tracker(model, coarse_map1, options=opts)
    assert np.array_equal(by_object._params, by_keywords._params)
    paper = Tracker(model, coarse_map1, mode="paper", options=opts)      # keywords replace fields
    assert paper.mode == "paper" and paper.options.joint_tolerance == 1e-4 and opts.mode == "default"
    # every scalar option of the table refuses what its bound refuses, by name
    for name, bound in BOUNDS.items():
        for bad in (bound.low - 1.0 if not bound.open else bound.low, float("nan"), "1", True,
                    None if not bound.none else float("inf")):
            with pytest.raises(TrackerError, match=f"^{name}: expected"):
                TrackerOptions(**{name: bad})
    assert check_number("k", np.int32(3), Bound(integer=True)) == 3
    with pytest.raises(TrackerError, match="options"):
        Tracker(model, coarse_map1, options={"joint_tolerance": 1e-4})
    with pytest.raises(TypeError, match="bogus"):
        Tracker(model, coarse_map1, bogus=1)
