"""The tracker's gates on measured joints (solver._kernels.gates): the outlier gate near a serial
singularity, and the speed gate on an ill-conditioned path."""
import numpy as np
import pytest

from conftest import coarse_map, pose_distance, track_stream
from experiments.sensors import Sensor, sensor_truth
from experiments.suite import hard_suite
from solver import STATUS, Tracker, jacobians
from solver._kernels.exclusion import reacquire
from solver._kernels.gates import GATE_PASS, GATE_REFUSE, GATE_SUSPECT, outlier_gate, pose_gains
from solver._kernels.kinematics import geometry
from solver._kernels.tube import TUBE_SIZE
from solver.baselines import NewtonTracker
from solver.direct_kinematics import kernel_constants

REJECTED = [k for k, v in STATUS.items() if v == "rejected"][0]
SENSOR = Sensor("16-bit", bits=16, noise=1e-3)


@pytest.fixture(scope="module")
def hard(model):
    return {p.name: p for p in hard_suite(model, samplings=(1000,))}


def measured(path, seed):
    q = SENSOR.measure(path.q, seed=seed).q.copy()
    q[0] = path.q[0]
    return q


def test_pose_gains_are_the_jacobians_velocity_model(model):
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    p = hard_suite(model, samplings=(50,))[0]
    for k in range(0, 50, 7):
        S = np.empty((3, 3))
        assert pose_gains(p.X[k], p.q[k], M, l1, l2sq, b, S)
        J, K = jacobians(model, p.X[k], p.q[k])
        np.testing.assert_allclose(S, np.abs(np.linalg.solve(J, K)), rtol=1e-9, atol=1e-12)


def test_the_outlier_gate_weighs_a_joints_swing_by_what_it_does_to_the_pose(model, hard):
    """Next to a serial singularity a joint swings by a radian within a sample while the platform
    barely moves: suspect, not refused.  The same swing where the joint moves the platform, or a
    0.1 rad jump of the joint that moves it most, is refused; a step within the threshold passes."""
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    p = hard["p2-lissajous-0.5mm/1000"]
    d2 = np.abs(np.diff(np.unwrap(p.q, axis=0), 2, axis=0))
    k = int(np.argmax(d2.max(axis=1))) + 2                      # the sample of the largest swing
    j = int(np.argmax(d2[k - 2]))
    assert d2[k - 2, j] > 1.0
    innov = np.zeros(3)
    innov[j] = d2[k - 2, j]
    thr, noise = 0.02, 0.012
    assert outlier_gate(innov, thr, noise, p.X[k - 1], p.q[k - 1], M, l1, l2sq, b) == GATE_SUSPECT
    S = np.empty((3, 3))
    pose_gains(p.X[k - 1], p.q[k - 1], M, l1, l2sq, b, S)
    strong = np.zeros(3)
    strong[int(np.argmax(S.max(axis=0)))] = 0.1
    assert outlier_gate(strong, thr, noise, p.X[k - 1], p.q[k - 1], M, l1, l2sq, b) == GATE_REFUSE
    regular = hard["p2-lissajous-far/1000"]
    assert outlier_gate(innov, thr, noise, regular.X[100], regular.q[100], M, l1, l2sq, b) == GATE_REFUSE
    assert outlier_gate(innov * thr / innov.max() * 0.99, thr, noise, p.X[k - 1], p.q[k - 1], M, l1, l2sq,
                        b) == GATE_PASS


def test_a_serial_singularitys_swing_is_taken_and_an_outlier_still_refused(model, hard):
    """On the path passing 0.5 mm from a serial singularity (16-bit encoder, 1e-3 rad noise) no sample
    is refused and no wrong pose vouched for; a 0.1 rad outlier on the same stream is refused."""
    p = hard["p2-lissajous-0.5mm/1000"]
    q = measured(p, 7)
    truth, counted = sensor_truth(model, q, p.X)
    tr = Tracker(model, coarse_map(model, 2), joint_tolerance=SENSOR.tolerance(3.0))
    X, infos = track_stream(tr, q, p.X[0])
    assert not any(i.status == REJECTED for i in infos[1:])
    certain = np.array([True] + [i.certain for i in infos[1:]])
    assert np.sum((pose_distance(X, truth) > 1e-6) & counted & certain) == 0
    bad = q.copy()
    bad[600, 1] += 0.1
    X2, infos2 = track_stream(tr, bad, p.X[0])
    assert infos2[600].status == REJECTED and not infos2[600].certain
    np.testing.assert_allclose(X2[601:], X[601:], atol=1e-6)


@pytest.mark.parametrize("name, seed", [("p3-circle-far/1000", 1044), ("p3-circle-5mm/1000", 1042)])
def test_the_speed_gate_does_not_hold_a_solution_a_chain_of_boxes_reached(model, hard, name, seed):
    """Ill-conditioned paths (1 mrad of joint noise moves phi by 0.1 to 0.4 rad): the measured
    solution jumps more than a speed bound allows, but along a branch a chain of boxes follows
    (on the 5 mm circle only a longer chain, tried before the gate holds the pose); the tracker
    errs no more often than Newton from the previous pose, and never silently."""
    p = hard[name]
    q = measured(p, seed)
    truth, counted = sensor_truth(model, q, p.X)
    counted[0] = False
    tr = Tracker(model, coarse_map(model, 3), joint_tolerance=SENSOR.tolerance(3.0), speed_bound=(3.76, 1.10))
    X, infos = track_stream(tr, q, p.X[0])
    certain = np.array([False] + [i.certain for i in infos[1:]])
    assert np.sum((pose_distance(X, truth) > 1e-6) & certain) == 0
    Xn, _ = track_stream(NewtonTracker(model), q, p.X[0])
    errors = np.sum((pose_distance(X, truth) > 1e-6) & counted)
    assert errors <= np.sum((pose_distance(Xn, truth) > 1e-6) & counted)


@pytest.mark.parametrize("k", [190, 200, 208])
def test_an_outlier_after_a_swing_is_never_vouched_for(model, hard, k):
    """Right after the serial singularity's swing the gate's envelope is wide open, and a 0.1 rad
    outlier may be taken; with a speed bound, re-acquisition then has nothing to prove about the
    robot.  Neither that sample nor any later one is vouched for wrongly."""
    p = hard["p2-lissajous-0.5mm/1000"]
    q = measured(p, 7)
    truth, _ = sensor_truth(model, q, p.X)
    q[k, 1] += 0.1
    tr = Tracker(model, coarse_map(model, 2), joint_tolerance=SENSOR.tolerance(3.0), speed_bound=(2.35, 1.05))
    X, infos = track_stream(tr, q, p.X[0])
    certain = np.array([False] + [i.certain for i in infos[1:]])
    assert not certain[k]
    assert np.sum((pose_distance(X, truth) > 1e-6) & certain) == 0


def test_reacquisition_refuses_a_solution_outside_the_region(model):
    """The branch and bound proves that no *other* pose of the region reaches the joints: for a
    solution outside the region that is no proof about the robot (its joints were off)."""
    from solver import ik
    pack = kernel_constants(model)["pack"]
    X = np.array([0.5, 0.35, 0.1])
    q = ik(model, X, 1)
    around = np.array([X[0] - 0.05, X[0] + 0.05, X[1] - 0.05, X[1] + 0.05, X[2] - 0.2, X[2] + 0.2])
    assert reacquire(X, q, 1e-3, 0, around, 10000, pack, np.empty(6))
    away = around + np.array([0.3, 0.3, 0.0, 0.0, 0.0, 0.0])
    assert not reacquire(X, q, 1e-3, 0, away, 10000, pack, np.empty(6))


def test_a_swing_the_first_order_gate_refuses_is_taken_when_the_platform_stayed_within_reach(model, hard):
    """With a 16-bit encoder and 1e-4 rad of noise the gate's threshold is tight, and its first-order
    test refuses the serial singularity's swing (1.4 rad in a sample).  With a speed bound the DK
    solutions show the platform moved as usual (within the speed bound's reach plus the noise's
    effect): the swing is taken, vouched for by nothing, and the pose is right at every sample of it
    (refused, the pose was held: 2 errors).  Certainty is back within a few samples, nothing wrong is
    vouched for; without a speed bound the swing is refused as before.  A sample taken so leaves the
    gate's envelopes as they were (it may still be a glitch)."""
    p = hard["p2-lissajous-0.5mm/1000"]
    sensor = Sensor("16-bit-1e-4", bits=16, noise=1e-4)
    q = sensor.measure(p.q, seed=3).q.copy()
    q[0] = p.q[0]
    truth, counted = sensor_truth(model, q, p.X)
    swing = int(np.argmax(np.abs(np.diff(np.unwrap(q, axis=0), axis=0)).max(axis=1))) + 1
    make = lambda speed: Tracker(model, coarse_map(model, 2), joint_tolerance=sensor.tolerance(3.0),  # noqa: E731
                                 speed_bound=speed, stuck_after=sensor.stuck_after())
    X, infos = track_stream(make((3.76, 1.10)), q, p.X[0])
    assert not any(k and i.status == REJECTED for k, i in enumerate(infos))
    assert not infos[swing].certain and infos[swing].status == 0
    certain = np.array([True] + [i.certain for i in infos[1:]])
    wrong = (pose_distance(X, truth) > 1e-6) & counted
    assert not wrong[swing - 3:swing + 4].any() and not (wrong & certain).any()
    assert certain[swing + 10:].all()                          # re-acquired, then chained
    _, unbounded = track_stream(make(None), q[:swing + 2], p.X[0])
    assert unbounded[swing].status == REJECTED
    tr = make((3.76, 1.10))                                    # the swing leaves the gate's envelopes alone:
    tr.reset(p.X[0], q[0])                                     # a glitch taken so cannot open the gate
    for k in range(1, swing):
        tr.step(q[k], 1e-3)
    before = tr.state
    _, info = tr.step(q[swing], 1e-3)
    assert info.status == 0 and not info.certain
    assert tr.state.a_scale == before.a_scale and tr.state.dq_scale == before.dq_scale


def test_the_region_steers_the_choice_back_and_reacquires_its_solution(model, hard):
    """On p1-circle-0.5mm (20-bit encoder, 2e-5 rad) the measured joints pass a fold at step ~246
    and the nearest-to-prediction choice can follow the other branch.  The pose box that holds the
    robot (the last certain pose plus the speed bound, cut to the poses reaching each reading)
    soon leaves that branch out: the tracker takes the one solution inside it, and re-acquires it
    when the proof closes.  Errors no more than Newton's, none vouched for, certain again well
    before the end."""
    from solver.baselines import NewtonTracker
    p = hard["p1-circle-0.5mm/1000"]
    sensor = Sensor("20-bit-2e-5", bits=20, noise=2e-5)
    q = sensor.measure(p.q, seed=1010).q.copy()         # before the region steered, 737 errors here (Newton 7)
    q[0] = p.q[0]
    truth, counted = sensor_truth(model, q, p.X)
    tr = Tracker(model, coarse_map(model, 1), joint_tolerance=sensor.tolerance(3.0), speed_bound=(3.76, 1.10),
                 stuck_after=sensor.stuck_after())
    X, infos = track_stream(tr, q, p.X[0])
    certain = np.array([True] + [i.certain for i in infos[1:]])
    wrong = (pose_distance(X, truth) > 1e-6) & counted
    Xn, _ = track_stream(NewtonTracker(model), q, p.X[0])
    assert wrong.sum() <= ((pose_distance(Xn, truth) > 1e-6) & counted).sum()
    assert not (wrong & certain).any()
    assert any(i.certificate == 4 for i in infos[1:]) and certain[-200:].all()


def _in_paving(X, paving):
    """The pose ``X`` (3,) lies in one of the boxes (n, 6) (phi compared modulo 2 pi)."""
    for box in paving:
        phi = box[4] + np.mod(X[2] - box[4], 2 * np.pi)
        if box[0] <= X[0] <= box[1] and box[2] <= X[1] <= box[3] and phi <= box[5]:
            return True
    return False


def test_the_paving_holds_every_consistent_pose_and_is_thinner_than_its_hull(model, hard):
    """Where p1-ellipse-20mm passes near a fold, the poses reaching a joint box form a thin curved
    needle: the paving (solver._kernels.paving) holds the DK solutions of joints anywhere in the box
    (and the pose itself), while its boxes fill a small part of their hull, the one box the tracker
    kept before (why that set-membership step could not shrink along the needle)."""
    from solver import dk_all, posture_of
    from solver._kernels.layout import PAVE_BOXES
    from solver._kernels.paving import preimage_paving
    M, l1, l2sq, b = geometry(kernel_constants(model)["pack"])
    p = hard["p1-ellipse-20mm/1000"]
    X, q, eps = p.X[460], p.q[460], 3.5e-4
    root = np.ravel(np.column_stack([X - (0.03, 0.03, 0.15), X + (0.03, 0.03, 0.15)]))[None, :]
    pave = np.empty((PAVE_BOXES, 6))
    n = preimage_paving(q, eps, 0, root, 1, np.array([5e-4, 1.4e-4]), 10 ** 6, M, l1, l2sq, b, pave)
    assert 1 <= n <= PAVE_BOXES
    paving = pave[:n]
    assert _in_paving(X, paving)
    inside = 0
    for dq in np.random.default_rng(5).uniform(-eps, eps, (300, 3)):
        for Y in dk_all(model, q + dq).real_poses():
            if _in_paving(Y, root) and posture_of(model, Y, q + dq) == 1:
                assert _in_paving(Y, paving)
                inside += 1
    assert inside >= 300
    hull = np.ravel(np.column_stack([paving[:, 0::2].min(0), paving[:, 1::2].max(0)]))
    assert hull[5] - hull[4] > 0.02                               # a long needle
    volume = np.prod(paving[:, 1::2] - paving[:, 0::2], axis=1).sum()
    assert volume < 0.2 * np.prod(hull[1::2] - hull[0::2])
    # two roots with a gap in phi: the poses of the gap are the robot's for no root, and no box is kept there
    lo, hi = root[0].copy(), root[0].copy()
    lo[5], hi[4] = X[2] - 0.015, X[2] + 0.015                  # wider than a slice of the paving
    n = preimage_paving(q, eps, 0, np.array([lo, hi]), 2, np.array([5e-4, 1.4e-4]), 10 ** 6, M, l1, l2sq, b, pave)
    assert n >= 2 and not _in_paving(X, pave[:n])
    assert np.all((pave[:n, 5] <= lo[5] + 1.4e-4) | (pave[:n, 4] >= hi[4] - 1.4e-4))


def test_the_tracker_s_paving_holds_the_robot_and_survives_a_save(model, hard):
    """On a noisy stream across folds (p1-ellipse-20mm, noise spread over the whole tolerance) the
    uncertain steps keep a paving of the poses the robot can be in: the robot's pose is in it at
    every such step (the soundness the re-acquisition's region rests on; the sensor keeps its
    tolerance and the robot its speed bound), and a saved state carries it; a corrupt one is
    refused by name."""
    from solver import TrackerState
    from solver.tracker_state import TrackerError
    p = hard["p1-ellipse-20mm/1000"]
    tol = 3.5e-4
    q = p.q + np.random.default_rng(11).uniform(-0.98 * tol, 0.98 * tol, p.q.shape)
    q[0] = p.q[0]
    upto = len(q)
    tr = Tracker(model, coarse_map(model, 1), joint_tolerance=tol, speed_bound=(3.76, 1.10), stuck_after=0)
    tr.reset(p.X[0], q[0])
    checked, saved = 0, None
    for k in range(1, upto):
        _, info = tr.step(q[k], 1e-3)
        paving = tr.state.paving
        if paving is not None and tr.state.anchor_age == 0.0 and info.status == 0:   # this reading's paving
            assert _in_paving(p.X[k], paving), k
            checked += 1
            saved = saved if saved is not None else tr.state.as_array()
    assert checked >= 50
    back = TrackerState.from_array(saved)
    assert back.paving is not None and np.array_equal(back.as_array(), saved, equal_nan=True)
    from solver.tracker_state import _N_PAVE, _PAVE, _SINCE
    bad = saved.copy()
    bad[_PAVE], bad[_PAVE + 1] = 1.0, 0.0                     # a box with lo > hi
    with pytest.raises(TrackerError, match="paving"):
        TrackerState.from_array(bad)
    bad = saved.copy()
    bad[_N_PAVE] = 99.0
    with pytest.raises(TrackerError, match="paving"):
        TrackerState.from_array(bad)
    from solver.state_array import _N_TUBES, _TUBE
    bad = saved.copy()
    bad[_SINCE], bad[_N_TUBES], bad[_TUBE:_TUBE + TUBE_SIZE] = -1.0, 1.0, 0.0   # a paving beside a certain
    with pytest.raises(TrackerError, match="paving"):                           # state's cover of tubes
        TrackerState.from_array(bad)
    ok = saved.copy()
    ok[_SINCE] = -1.0                                         # certain without tubes (the eliminant's): kept
    assert TrackerState.from_array(ok).paving is not None
