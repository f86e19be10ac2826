"""The tracker's certainty: Krawczyk certificates, the candidate set, and what `certain` promises."""
import numpy as np
import pytest

from conftest import coarse_map, pose_distance
from experiments.suite import hard_suite
from solver import CERTIFICATES, SolverInputError, Tracker, TrackerState, dk_all, ik, wrap_angle
from solver._kernels.certify import TINY, follow_branch
from solver._kernels.kinematics import geometry
from solver._kernels.krawczyk import W_SIZE, krawczyk, newton_on_path
from solver.baselines import NewtonSeparationTracker
from solver.direct_kinematics import kernel_constants
from solver.tracker_state import STATE_FLOATS
from solver.trajectories import circle_path

@pytest.fixture(scope="module")
def geo(model):
    return geometry(kernel_constants(model)["pack"])


@pytest.fixture(scope="module")
def hard(model):
    """Hard-suite streams of four postures at the two coarsest samplings (the costly cases)."""
    return [p for p in hard_suite(model, samplings=(30, 50)) if p.posture in (1, 2, 5, 8)]


@pytest.fixture(scope="module")
def maps(model, hard):
    return {p: coarse_map(model, p) for p in sorted({s.posture for s in hard} | {1})}


def wrong(X, truth):
    return pose_distance(X, truth) > 1e-6


# ------------------------------------------------------------------ the Krawczyk test itself
def test_krawczyk_proves_a_lone_solution_and_refuses_two_or_none(model, geo):
    M, l1, l2sq, b = geo
    X = np.array([0.45, 0.30, -0.5])
    q = ik(model, X, 1)
    w = np.empty(W_SIZE)
    zero = np.zeros(3)
    assert krawczyk(X, np.full(3, TINY), q, zero, zero, 0.0, 0.0, zero, M, l1, b, l2sq, w)
    assert krawczyk(X, np.full(3, 1e-3), q, zero, zero, 0.0, 0.0, zero, M, l1, b, l2sq, w)
    # a box that holds no solution: K is not inside it
    assert not krawczyk(X + [0.01, 0, 0], np.full(3, 1e-3), q, zero, zero, 0.0, 0.0, zero, M, l1, b, l2sq, w)
    # a box that holds every solution of q is refused (more than one zero)
    assert not krawczyk(np.array([0.5, 0.3, 0.0]), np.array([1.0, 1.0, np.pi]), q, zero, zero, 0.0, 0.0, zero,
                        M, l1, b, l2sq, w)


def test_a_chain_ends_where_a_fine_continuation_ends(model, geo):
    """Soundness on random segments: a closed chain agrees with 2,000-step Newton continuation."""
    M, l1, l2sq, b = geo
    rng = np.random.default_rng(7)
    closed = 0
    out = np.empty(3)
    w = np.empty(W_SIZE)
    zero = np.zeros(3)
    for _ in range(60):
        X0 = np.array([rng.uniform(0.3, 0.7), rng.uniform(0.15, 0.45), rng.uniform(-1.0, 1.0)])
        q0 = ik(model, X0, int(rng.integers(1, 9)))
        if np.any(np.isnan(q0)):
            continue
        dq = rng.normal(0.0, 0.15, 3)
        if follow_branch(X0, False, q0, dq, zero, 0.0, M, l1, b, l2sq, 2000, out) < 0:
            continue
        closed += 1
        x = X0.copy()
        for s in np.linspace(0.0, 1.0, 2001)[1:]:
            assert newton_on_path(x, q0, dq, zero, s, M, l1, b, l2sq, w, 30) < 1e-10
        assert np.max(np.abs(x - out)) < 1e-8
    assert closed >= 30


# ------------------------------------------------------------------ what `certain` promises
def test_circle_is_certain_at_every_step(model, maps):
    X = circle_path(1000)
    q = ik(model, X, 1)
    res = Tracker(model, maps[1]).track(q, X[0])
    assert not wrong(res.X, X).any()
    assert res.certain.all()
    assert (res.uncertain_since == -1).all()
    assert set(res.certificate[1:]) == {5}                          # a tube chain at every step
    err = np.abs(res.X - X)
    err[:, 2] = np.abs(wrap_angle(res.X[:, 2] - X[:, 2]))
    assert np.all(err <= res.pose_bound) and res.pose_bound.max() < 1e-11   # the bound: a numerical enclosure


@pytest.mark.parametrize("mode", ["default", "paper"])
def test_a_wrong_pose_is_never_certain(model, maps, hard, mode):
    """On coarse streams near singularities in four postures: no silent error."""
    n_wrong = n_steps = n_certain = 0
    for p in hard:                                   # the start pose is exact: a start tolerance of rounding
        res = Tracker(model, maps[p.posture], mode=mode, start_tolerance=(1e-9, 1e-9, 1e-9)).track(p.q, p.X[0])
        bad = wrong(res.X, p.X)
        assert not np.any(bad & res.certain), p.name
        n_wrong += int(bad.sum())
        n_certain += int(res.certain.sum())
        n_steps += len(p.X)
    if mode == "default":
        assert n_certain > 0.9 * n_steps                             # and it vouches for most steps
    else:
        assert n_wrong > 0                                           # the anchor does make errors here


def test_certainty_returns_only_through_a_certificate(model, maps, hard):
    for p in hard:
        res = Tracker(model, maps[p.posture]).track(p.q, p.X[0])
        assert np.all(res.certificate[1:][res.certain[1:]] > 0)
        for k in range(1, len(p.X)):
            if res.certain[k]:
                assert res.uncertain_since[k] == -1 and res.n_candidates[k] == 1
            else:
                lost = k if res.certain[k - 1] else res.uncertain_since[k - 1]
                assert res.uncertain_since[k] == lost


def test_certificates_correct_the_heuristic_choice(model, maps, hard):
    """With certificates the default mode makes fewer errors than the heuristic alone would report."""
    errs = sum(int(wrong(Tracker(model, maps[p.posture]).track(p.q, p.X[0]).X, p.X).sum()) for p in hard)
    paper = sum(int(wrong(Tracker(model, maps[p.posture], mode="paper").track(p.q, p.X[0]).X, p.X).sum())
                for p in hard)
    assert errs < paper


def test_uncertain_until_a_certificate_names_the_branch(model, maps, hard):
    """Lose the branch on purpose (after one step, the state forgets its cover of tubes and keeps every
    real solution as a candidate), then let the certificates work: certainty comes back only through
    elimination or the posture, and never on a wrong pose."""
    from dataclasses import replace
    regained = 0
    for p in hard:
        tr = Tracker(model, maps[p.posture], start_tolerance=(1e-9, 1e-9, 1e-9))
        tr.reset(p.X[0], p.q[0])
        tr.step(p.q[1])
        sols = dk_all(model, p.q[1]).real_poses()
        if len(sols) < 2:
            continue                                  # a single real solution: nothing to lose
        tr.state = replace(tr.state, tube=None, candidates=sols, verified=False, uncertain_since=1)
        for k in range(2, len(p.q)):
            Xk, info = tr.step(p.q[k])
            assert not (info.certain and wrong(Xk[None], p.X[k][None])[0]), p.name
            if info.certain:
                assert info.certificate in (2, 3) and info.uncertain_since == -1
                regained += 1
                break
            assert info.uncertain_since == 1
    assert regained > 0


# ------------------------------------------------------------------ state and input
def test_certainty_survives_save_and_restore(model, maps, hard):
    p = next(p for p in hard if p.posture == 1 and len(p.X) == 30)
    tr = Tracker(model, maps[1], max_tests=30)
    tr.reset(p.X[0], p.q[0])
    infos = []
    for k in range(1, len(p.q)):
        infos.append(tr.step(p.q[k])[1])
    saved = tr.state
    again = TrackerState.from_array(saved.as_array())
    np.testing.assert_array_equal(again.as_array(), saved.as_array())
    assert again.uncertain_since == saved.uncertain_since and again.verified == saved.verified
    tr.reset(p.X[0], p.q[0])
    tr.state = again
    X1, i1 = tr.step(p.q[0])
    tr.state = saved
    X2, i2 = tr.step(p.q[0])
    np.testing.assert_array_equal(X1, X2)
    assert i1.certain == i2.certain and i1.uncertain_since == i2.uncertain_since
    with pytest.raises(ValueError, match=f"{STATE_FLOATS} floats"):
        TrackerState.from_array(np.zeros(12))


def test_a_refused_step_keeps_the_certainty(model, maps):
    X = circle_path(100)
    q = ik(model, X, 1)
    tr = Tracker(model, maps[1])
    tr.reset(X[0], q[0])
    tr.step(q[1])
    before = tr.state
    with pytest.raises(SolverInputError, match="q"):
        tr.step([np.nan, 0.0, 0.0])
    assert tr.state is before and tr.state.certain
    _, info = tr.step(q[2])
    assert info.certain and CERTIFICATES[info.certificate] == "tube"


def test_newton_separation_baseline_vouches_and_can_be_wrong(model, hard):
    silent = vouched = 0
    for p in hard:
        res = NewtonSeparationTracker(model).track(p.q, p.X[0])
        silent += int(np.sum(wrong(res.X, p.X) & res.certain))
        vouched += int(res.certain.sum())
    assert vouched > 0
    assert silent > 0                      # a separation margin is a heuristic, not a proof


def test_certificate_names():
    assert CERTIFICATES == {0: "none", 1: "continuation", 2: "elimination", 3: "posture", 4: "reacquired", 5: "tube"}
