"""The step budget: a step stops its searches at a deadline, and the tube chain's proof goes on later.

Times are not asserted (``bench/bench_budget.py`` measures them); what is asserted is what a budget
may and may not change: nothing without one or with a generous one, certainty (never the choice
where the unbudgeted tracker is right) with a budget too small for any proof, and a walk or a
re-acquisition cut short that closes at a later step, never back-dated, also through a saved and
restored state.
"""
import numpy as np
import pytest

from conftest import pose_distance
from experiments.sensors import Sensor
from experiments.suite import default_suite
from solver import SolverInputError, Tracker, TrackerError
from solver._kernels.anytime import ANY_N, ANY_N_PATH, ANY_R_N_PATH, ANY_R_ON, ANY_SIZE, MAX_PATH
from solver._kernels.certify import CERT_REACQUIRED, CERT_TUBE
from solver._kernels.clock import cycles, cycles_per_second, deadline_after, expired
from solver.tracker_state import TrackerState

SENSOR = Sensor("16-bit", bits=16, noise=1e-4)


@pytest.fixture(scope="module")
def circle(model):
    """The paper's circle at 1 kHz (far from singularities)."""
    return default_suite(model, samplings=(1000,))[0]


def _measured(path, seed=3):
    q = SENSOR.measure(path.q, seed=seed).q.copy()
    q[0] = path.q[0]
    return q


def _tracker(model, map1, budget, tol=SENSOR.tolerance(3.0)):
    return Tracker(model, map1, joint_tolerance=tol, speed_bound=(3.0, 1.0), start_tolerance=(1e-9,) * 3,
                   step_budget=budget)


def _cut_short(model, map1, circle, steps):
    """A tracker whose first ``steps`` steps had no time for any proof (a 1 ns budget), and the readings."""
    q = _measured(circle)
    tr = _tracker(model, map1, 1e-9)
    tr.reset(circle.X[0], q[0])
    for k in range(1, steps + 1):
        tr.step(q[k], 1e-3)
    return tr, q


def _goes_on_elsewhere(model, map1, circle, tr, q, k):
    """``tr``'s state saved and restored into another tracker; both given time for the reading ``q[k]``,
    where their poses must agree.  Returns (the saved array, ``tr``'s info, the other's)."""
    saved = tr.state.as_array()
    restored = TrackerState.from_array(saved)
    np.testing.assert_array_equal(restored.walk, tr.state.walk)
    other = _tracker(model, map1, 10.0)
    other.reset(circle.X[0], q[0])
    other.state = restored
    tr.step_budget = 10.0
    Xa, ia = tr.step(q[k], 1e-3)
    Xb, ib = other.step(q[k], 1e-3)
    np.testing.assert_array_equal(Xa, Xb)
    return saved, ia, ib


def _track(tracker, q, X0, n=None):
    """Poses (n, 3), infos of a stream stepped at 1 kHz."""
    tracker.reset(X0, q[0])
    n = len(q) if n is None else n
    X, infos = np.empty((n, 3)), [None]
    X[0] = tracker.state.X
    for k in range(1, n):
        X[k], info = tracker.step(q[k], 1e-3)
        infos.append(info)
    return X, infos


def test_the_clock_counts_and_a_deadline_passes(model):
    rate = cycles_per_second()
    assert 1e8 < rate < 1e11                               # counts per second of a CPU's cycle counter
    a = cycles()
    assert cycles() >= a
    assert not expired(0.0) and not expired(deadline_after(10.0)) and expired(deadline_after(1e-9) - 1.0)
    assert deadline_after(None) == 0.0


def test_a_generous_budget_changes_nothing(model, coarse_map1, circle):
    """The walk is the unbudgeted tube chain cut into parts: given all the time it needs, the same steps."""
    q = _measured(circle)
    X0, info0 = _track(_tracker(model, coarse_map1, None), q, circle.X[0], 400)
    X1, info1 = _track(_tracker(model, coarse_map1, 10.0), q, circle.X[0], 400)
    np.testing.assert_array_equal(X0, X1)
    assert [i.certain for i in info0[1:]] == [i.certain for i in info1[1:]]
    assert all(i.certain for i in info0[1:])
    b0 = np.array([i.pose_bound for i in info0[1:]])
    b1 = np.array([i.pose_bound for i in info1[1:]])
    np.testing.assert_allclose(b1, b0, rtol=1e-9, atol=1e-15)
    assert not any(i.out_of_budget for i in info1[1:])


def test_a_budget_too_small_for_any_proof_leaves_every_step_uncertain_but_right(model, coarse_map1, circle):
    q = _measured(circle)
    X0, info0 = _track(_tracker(model, coarse_map1, None), q, circle.X[0], 400)
    X1, info1 = _track(_tracker(model, coarse_map1, 1e-9), q, circle.X[0], 400)
    assert not any(i.certain for i in info1[1:])
    assert all(i.out_of_budget and not np.isfinite(i.pose_bound).any() for i in info1[1:])
    right = pose_distance(X0, circle.X[:400]) < 1e-3            # where the unbudgeted tracker is right
    assert right[1:].all()
    assert np.all(pose_distance(X1[right], X0[right]) < 1e-12)  # the same choice


def test_certainty_returns_when_the_walk_closes_and_is_never_back_dated(model, coarse_map1, circle):
    """Steps cut short leave a walk with their readings; the first step with time enough closes it and is
    certain (its proof complete when it returned), the steps before stay uncertain."""
    q = _measured(circle)
    tr = _tracker(model, coarse_map1, 1e-9)
    tr.reset(circle.X[0], q[0])
    for k in range(1, 6):
        _, info = tr.step(q[k], 1e-3)
        assert not info.certain and info.out_of_budget
    walk = tr.state.walk
    assert walk is not None and int(walk[ANY_N_PATH]) == 6          # the start's reading and five more
    tr.step_budget = 10.0
    X, info = tr.step(q[6], 1e-3)
    assert info.certain and info.certificate == CERT_TUBE and not info.out_of_budget
    assert tr.state.walk is None
    assert np.all(np.abs(X - circle.X[6]) <= info.pose_bound + 1e-12)  # the robot within the bound


def test_a_walk_longer_than_its_path_ends(model, coarse_map1, circle):
    tr, q = _cut_short(model, coarse_map1, circle, MAX_PATH + 1)
    walk = tr.state.walk
    assert walk[ANY_N] == 0                              # past MAX_PATH readings the walk is given up,
    assert walk[ANY_R_ON] > 0 and 1 <= walk[ANY_R_N_PATH] <= 2   # a re-acquisition since begun
    tr.step_budget = 10.0
    X, info = tr.step(q[MAX_PATH + 2], 1e-3)
    assert info.certain and info.certificate == CERT_REACQUIRED  # closed, and its walk caught up
    assert tr.state.walk is None
    assert np.all(np.abs(X - circle.X[MAX_PATH + 2]) <= info.pose_bound + 1e-12)


def test_a_reacquisition_cut_into_parts_is_the_whole_proof(model, coarse_map1, circle):
    """Re-acquisition resumed across many deadlines ends as the uncut one, with the same cover."""
    from solver._kernels import layout as lay
    from solver._kernels.anytime import ANY_R_TUBES
    from solver._kernels.reacquisition import R_DONE, R_PENDING, reacquire_begin, reacquire_on

    q = _measured(circle)
    tr = _tracker(model, coarse_map1, None)
    _track(tr, q, circle.X[0], 41)
    X, qu = tr.state.X.copy(), q[40]
    region = np.ravel(np.column_stack([X - (0.03, 0.03, 0.2), X + (0.03, 0.03, 0.2)]))
    tol, posture = SENSOR.tolerance(3.0), int(tr._params[lay.PARAM_POSTURE_BITS])
    ends = []
    for deadline in (lambda: 0.0, lambda: deadline_after(3e-6)):
        pack = np.zeros(ANY_SIZE)
        reacquire_begin(pack, X, qu, region)
        calls, status = 0, R_PENDING
        while status == R_PENDING and calls < 100_000:
            status, n = reacquire_on(pack, tol, posture, 20_000, deadline(), tr._model_pack)
            calls += 1
        ends.append((status, n, calls, pack[ANY_R_TUBES:ANY_R_TUBES + n * 36].copy()))
    (s0, n0, c0, t0), (s1, n1, c1, t1) = ends
    assert s0 == R_DONE and c0 == 1
    assert c1 > 5                                        # cut many times
    assert (s1, n1) == (s0, n0)
    np.testing.assert_array_equal(t1, t0)


def test_a_saved_state_keeps_the_unfinished_proof(model, coarse_map1, circle):
    tr, q = _cut_short(model, coarse_map1, circle, 3)
    saved, ia, ib = _goes_on_elsewhere(model, coarse_map1, circle, tr, q, 4)
    assert ia.certain and ib.certain and ib.certificate == CERT_TUBE
    np.testing.assert_array_equal(ia.pose_bound, ib.pose_bound)
    with pytest.raises(TrackerError):
        TrackerState.from_array(np.concatenate([saved, [0.0]]))


def test_a_rejected_input_keeps_the_walk(model, coarse_map1, circle):
    q = _measured(circle)
    tr = _tracker(model, coarse_map1, 1e-9)
    tr.reset(circle.X[0], q[0])
    tr.step(q[1], 1e-3)
    before = tr.state
    with pytest.raises(SolverInputError):
        tr.step([np.nan, 0.0, 0.0], 1e-3)
    assert tr.state is before and tr.state.walk is not None


@pytest.mark.parametrize("bad", [0.0, -1e-3, float("nan"), float("inf"), "fast", True])
def test_the_budget_is_checked(model, coarse_map1, bad):
    with pytest.raises(TrackerError, match="step_budget"):
        Tracker(model, coarse_map1, step_budget=bad)


def test_a_step_without_budget_drops_the_unfinished_proof(model, coarse_map1, circle):
    """The walk holds the readings up to the last budgeted step: a step without a budget (which does not
    extend it) must not leave it for a later budgeted step to skip a reading."""
    tr, q = _cut_short(model, coarse_map1, circle, 3)
    assert tr.state.walk is not None
    tr.step_budget = None
    tr.step(q[4], 1e-3)
    assert tr.state.walk is None


def test_a_saved_walk_that_does_not_fit_its_state_is_refused(model, coarse_map1, circle):
    """A corrupt saved state must not reach the kernels: a walk not ending at the state's joints, or with
    counts past its buffers, is refused by name."""
    from solver._kernels.anytime import ANY_N, ANY_N_PATH, ANY_PATH
    from solver.tracker_state import _WALK

    tr, q = _cut_short(model, coarse_map1, circle, 3)
    saved = tr.state.as_array()
    TrackerState.from_array(saved)                                     # as saved: fine
    m = int(saved[_WALK + ANY_N_PATH])
    end = _WALK + ANY_PATH + 3 * (m - 1)
    for at, value in ((end, saved[end] + 0.1), (_WALK + ANY_N, 1e6), (_WALK + ANY_N_PATH, 1e6),
                      (_WALK + ANY_N, np.inf)):
        bad = saved.copy()
        bad[at] = value
        with pytest.raises(TrackerError, match="walk"):
            TrackerState.from_array(bad)


def test_a_saved_reacquisition_goes_on_and_a_corrupt_one_is_refused(model, coarse_map1, circle):
    from solver._kernels.anytime import ANY_R_F, ANY_R_K, ANY_R_PATH, ANY_R_PROG
    from solver.tracker_state import _WALK

    tr, q = _cut_short(model, coarse_map1, circle, MAX_PATH + 3)
    saved, ia, ib = _goes_on_elsewhere(model, coarse_map1, circle, tr, q, MAX_PATH + 4)
    assert saved[_WALK + ANY_R_ON] > 0 and saved[_WALK + ANY_R_N_PATH] == 4
    assert ia.certain and ib.certain and ib.certificate == CERT_REACQUIRED
    end = _WALK + ANY_R_PATH + 3 * 3
    for at, value in ((end, saved[end] + 0.1), (_WALK + ANY_R_ON, 9.0), (_WALK + ANY_R_ON, 1.5),
                      (_WALK + ANY_R_K, 40.0), (_WALK + ANY_R_F, 2.0), (_WALK + ANY_R_PROG, 65.0),
                      (_WALK + ANY_R_N_PATH, 1e6)):
        bad = saved.copy()
        bad[at] = value
        with pytest.raises(TrackerError, match="walk"):
            TrackerState.from_array(bad)


def test_the_anytime_continuation_takes_the_parabola_where_the_segment_fails(model):
    """Exact joints 0.5 mm from a type-2 singularity (suite path p2-circle-0.5mm/1000, samples 110-113):
    the straight segment 112 -> 113 loses the branch, the parabola through 111, 112, 113 keeps it, as the
    unbudgeted continuation (:func:`solver._kernels.candidates.continue_single`) does; so must the
    continuation a budget cuts."""
    from solver._kernels.anytime import cont_append, cont_begin, cont_on
    from solver._kernels.certify import FOLLOW_CUT, FOLLOW_DONE, FOLLOW_FAILED
    from solver._kernels.kinematics import geometry
    from solver._kernels.linalg import wrap
    from solver.direct_kinematics import kernel_constants

    q = np.array([[1.3828677493409418, 0.5528529158843907, -2.2672574295797947],
                  [1.3856930444698743, 0.5562380108649414, -2.2694314444370063],
                  [1.3885234883428654, 0.5596281693345313, -2.2716420813401985],
                  [1.391359049952626, 0.5630232727954088, -2.273889808285359]])
    X112 = np.array([0.7429660005409897, 0.4259319073475557, 0.34176469232328666])
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    d2 = np.array([(wrap(q[1, i] - q[2, i]) + (q[3, i] - q[2, i])) / 2.0 for i in range(3)])  # r = 1
    ends = {}
    for have_par in (False, True):
        for deadline in (lambda: 0.0, lambda: deadline_after(5e-6)):
            pack = np.zeros(ANY_SIZE)
            cont_begin(pack, X112, False, True, q[2])
            cont_append(pack, q[3], d2, have_par)
            out, status, calls = np.empty(3), FOLLOW_CUT, 0
            while status == FOLLOW_CUT and calls < 100_000:
                status, calls = cont_on(pack, 2000, deadline(), M, l1, b, l2sq, out), calls + 1
            ends[have_par, calls > 1] = (status, out.copy() if status == FOLLOW_DONE else None)
    assert ends[False, False][0] == ends[False, True][0] == FOLLOW_FAILED     # straight: lost
    assert ends[True, False][0] == ends[True, True][0] == FOLLOW_DONE         # the parabola: kept
    np.testing.assert_array_equal(ends[True, True][1], ends[True, False][1])  # cut or not, the same end
    assert pose_distance(ends[True, False][1][None], X112[None])[0] < 0.01
