"""The stuck-joint detector (solver.stuck): how often a joint at rest repeats, the refusal, the roll-back."""
import numpy as np
import pytest

from experiments.sensors import SENSOR_GRADES, Sensor
from solver import STATUS, Tracker, ik
from solver.stuck import repeat_probability, stuck_samples
from solver.tracker_state import TrackerError, TrackerState
from solver.trajectories import circle_path

REJECTED = [k for k, v in STATUS.items() if v == "rejected"][0]
SENSOR = Sensor("14-bit", bits=14, noise=1e-3)


@pytest.fixture(scope="module")
def map1(coarse_map1):
    return coarse_map1


@pytest.fixture(scope="module")
def noisy(model):
    X = circle_path(400)
    exact = ik(model, X, 1)
    q = SENSOR.measure(exact, seed=5).q
    q[0] = exact[0]
    return X, q


def _detecting(model, map1, X, q, upto):
    """A tracker with the detector, reset at the stream's start and stepped through ``q[1:upto]``."""
    tr = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0), stuck_after=SENSOR.stuck_after())
    tr.reset(X[0], q[0])
    for k in range(1, upto):
        tr.step(q[k], 1e-3)
    return tr


@pytest.mark.parametrize("bits", [12, 14, 16])
def test_repeat_probability_is_that_of_a_simulated_encoder_at_rest(rng, bits):
    step = 2 * np.pi / 2 ** bits
    n = 200_000
    at = rng.uniform(0, step, n)                                 # where the joint sits within its bin
    a = np.round((at + 1e-3 * rng.standard_normal(n)) / step)
    b = np.round((at + 1e-3 * rng.standard_normal(n)) / step)
    p = repeat_probability(1e-3, step)
    assert abs(np.mean(a == b) - p) < 4 * np.sqrt(p * (1 - p) / n)


def test_stuck_after_is_the_shortest_run_a_joint_at_rest_makes_rarely():
    assert Sensor("exact").stuck_after() == 0                    # an exact joint at rest repeats: off
    ks = []
    for s in [g for g in SENSOR_GRADES if g.noise == 1e-3 and not g.glitch]:   # 16, 14, 12 bits
        p = repeat_probability(s.noise, 2 * np.pi / 2 ** s.bits)
        k = s.stuck_after()
        assert p ** (k - 1) <= 1e-6 < p ** (k - 2)              # k readings: k - 1 repeats
        ks.append(k)
    assert ks == sorted(ks)                                      # coarser encoders repeat more often
    assert stuck_samples(1e-3, 0.0) == 2                         # real-valued readings never repeat


def test_a_stuck_joint_is_refused_rolled_back_and_its_release_is_one_step(model, map1, noisy):
    X, q = noisy
    k_stuck = SENSOR.stuck_after()
    q = q.copy()
    q[201:221, 1] = q[200, 1]                                   # joint 2 reads q[200] for 20 more samples
    tr = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0), stuck_after=k_stuck)
    ref = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0))
    tr.reset(X[0], q[0])
    ref.reset(X[0], q[0])
    for k in range(1, 201):
        tr.step(q[k], 1e-3)
        ref.step(q[k], 1e-3)
    clean = ref.state
    statuses = []
    for k in range(201, 221):
        x, info = tr.step(q[k], 1e-3)
        statuses.append(info.status)
        if info.status == REJECTED:
            assert not info.certain
            np.testing.assert_array_equal(x, clean.X)            # the pose before the repeats
    first = statuses.index(REJECTED)
    assert first == k_stuck - 2 and statuses[first:] == [REJECTED] * (20 - first)
    np.testing.assert_array_equal(tr.state.q, clean.q)
    np.testing.assert_array_equal(tr.state.candidates, clean.candidates)
    assert tr.state.skipped == 20
    # the release: one step from the clean state over 21 ms, as if the stuck readings never came
    x, info = tr.step(q[221], 1e-3)
    xr, info_r = ref.step(q[221], 21e-3)
    np.testing.assert_array_equal(x, xr)
    assert info.certain == info_r.certain and info.status == info_r.status


def test_the_release_after_a_stuck_joint_spans_the_seconds_of_uneven_steps(model, map1, noisy):
    """The rollback counts the seconds of the stuck readings, not their number times the last step:
    with steps of 1 to 9 ms the release is one step over their sum, as from the clean state."""
    X, q = noisy
    q = q.copy()
    q[201:221, 1] = q[200, 1]
    steps = 1e-3 * (1 + np.arange(21) % 9)                       # the steps of samples 201..221 (s)
    tr = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0), stuck_after=SENSOR.stuck_after(),
                 speed_bound=(2.0, 2.0))
    ref = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0), speed_bound=(2.0, 2.0))
    for t in (tr, ref):
        t.reset(X[0], q[0])
        for k in range(1, 201):
            t.step(q[k], 1e-3)
    for k in range(201, 221):
        tr.step(q[k], steps[k - 201])
    assert tr.state.skipped == 20 and tr.state.skipped_time == pytest.approx(steps[:20].sum(), rel=1e-12)
    x, info = tr.step(q[221], steps[20])
    xr, info_r = ref.step(q[221], steps.sum())
    np.testing.assert_array_equal(x, xr)
    assert info.certain == info_r.certain and info.status == info_r.status
    assert tr.state.dt == pytest.approx(ref.state.dt, rel=1e-12)
    assert tr.state.anchor_age == pytest.approx(ref.state.anchor_age, rel=1e-12)


def test_the_detector_leaves_a_noisy_stream_without_stuck_joints_alone(model, map1, noisy):
    X, q = noisy
    tr = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0), stuck_after=SENSOR.stuck_after())
    ref = Tracker(model, map1, joint_tolerance=SENSOR.tolerance(3.0))
    tr.reset(X[0], q[0])
    ref.reset(X[0], q[0])
    repeats = 0
    for k in range(1, len(q)):
        x, info = tr.step(q[k], 1e-3)
        xr, _ = ref.step(q[k], 1e-3)
        np.testing.assert_array_equal(x, xr)
        repeats += int(tr.state.repeats.max() > 0)
    assert repeats > 10                                          # repeats happen; none was long enough


def test_the_state_with_a_clean_state_round_trips(model, map1, noisy):
    X, q = noisy
    q = q.copy()
    q[51:54, 0] = q[50, 0]
    st = _detecting(model, map1, X, q, 54).state
    assert st.clean is not None and st.clean_lag == 3 and st.repeats[0] == 3
    again = TrackerState.from_array(st.as_array())
    np.testing.assert_array_equal(again.as_array(), st.as_array())
    np.testing.assert_array_equal(again.clean.X, st.clean.X)


@pytest.mark.parametrize("bad", [1, -1, 2.5, True])
def test_stuck_after_is_checked(model, map1, bad):
    with pytest.raises(TrackerError, match="stuck_after"):
        Tracker(model, map1, joint_tolerance=1e-3, stuck_after=bad)


def test_refusals_of_a_stuck_joint_report_the_uncertainty_of_the_clean_state(model, map1, noisy):
    X, q = noisy
    q = q.copy()
    q[201:221, 1] = q[200, 1]
    tr = _detecting(model, map1, X, q, 201)
    clean_since = tr.state.uncertain_since
    since = set()
    for k in range(201, 221):
        _, info = tr.step(q[k], 1e-3)
        if info.status == REJECTED:
            since.add(info.uncertain_since)
    assert since == {clean_since if clean_since >= 0 else 201}


def test_a_stuck_joint_rolls_back_to_before_its_own_run(model, map1, noisy):
    """Joint 1 repeats once at sample 100, joint 2 sticks from sample 101: the rollback goes to the state
    after sample 100, not to before joint 1's repeat."""
    X, q = noisy
    q = q.copy()
    q[100, 0] = q[99, 0]
    q[101:121, 1] = q[100, 1]
    tr = _detecting(model, map1, X, q, 120)
    _, info = tr.step(q[120], 1e-3)
    assert info.status == REJECTED and tr.state.steps == 100
    np.testing.assert_array_equal(tr.state.q, q[100])


def test_stuck_after_needs_measured_joints(model, map1):
    with pytest.raises(TrackerError, match="joint_tolerance"):
        Tracker(model, map1, stuck_after=8)
