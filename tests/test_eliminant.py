"""Re-acquisition by the eliminant (solver._kernels.eliminant): the DK's one-variable equation over a
joint box in affine arithmetic, where the tube covers fail on a long, curved needle."""
import numpy as np
import pytest

from conftest import coarse_map, pose_distance
from experiments.sensors import Sensor
from solver import Tracker, dk_all, ik, wrap_angle
from solver._kernels.eliminant import PHI_STEP, Q_SIZE, eliminant, eliminant_certificate, joint_box_elbows, run_box
from solver._kernels.exclusion import EXCLUSION_COVERS, exclusion_cover
from solver._kernels.kinematics import geometry
from solver._kernels.tube import TUBE_SIZE, tube_test
from solver.direct_kinematics import kernel_constants

#: A pose of posture 3 two millimetres from a type-2 singularity (the benchmark's ``p3-circle-2mm`` at its
#: sample 700): |S| = 351, 1e-4 rad of joint error moves phi by 0.035 rad.
NEAR_FOLD = np.array([1.0380179507009424, 0.5794802894291958, -0.3244205894027633])
#: The tolerance of a 16-bit encoder with 1e-4 rad of noise (3 sigma + half a step), rad.
TOL = Sensor("16-bit-1e-4", bits=16, noise=1e-4).tolerance(3.0)


@pytest.fixture(scope="module")
def geo(model):
    return geometry(kernel_constants(model)["pack"])


def enclosure(q, tol, pm, h, geo):
    """(f lo, f hi, df lo, df hi, ...) over phi = pm +- h and the joints q +- tol."""
    M, l1, l2sq, b = geo
    D0, D1 = np.empty((3, Q_SIZE)), np.empty((3, Q_SIZE))
    joint_box_elbows(np.asarray(q, float), np.full(3, tol), M, l1, D0, D1)
    ev = np.empty(10)
    eliminant(pm, h, D0, D1, b, l2sq, ev)
    return ev


def test_the_eliminant_vanishes_exactly_at_the_real_solutions(model, geo, rng):
    """At exact joints: the enclosure holds 0 at every real DK solution's phi, and not halfway between two."""
    for _ in range(20):
        X = np.array([rng.uniform(0.3, 0.7), rng.uniform(0.2, 0.5), rng.uniform(-np.pi, np.pi)])
        q = ik(model, X, int(rng.integers(1, 9)))
        phis = np.sort([p[2] for p in dk_all(model, q).real_poses()])
        for p in phis:
            ev = enclosure(q, 0.0, p, 0.0, geo)
            assert ev[0] <= 0.0 <= ev[1]
        gaps = np.diff(np.append(phis, phis[0] + 2 * np.pi))
        for p, g in zip(phis, gaps):
            if g > 0.05:
                ev = enclosure(q, 0.0, p + 0.5 * g, 0.0, geo)
                assert ev[0] > 0.0 or ev[1] < 0.0


@pytest.mark.parametrize("where", ["near a fold", "anywhere"])
def test_the_enclosure_holds_the_eliminant_and_its_derivative_over_the_box(model, geo, rng, where):
    """At the corners and random points of a phi interval times a joint box, the exact values of f,
    df/dphi, delta and n lie in the enclosure (the phi interval's ends with the joints' corners are where
    a symbol shared by mistake between phi and a joint would show)."""
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    for _ in range(12):
        if where == "near a fold":
            X = NEAR_FOLD
            q0 = ik(model, X, 3)
        else:
            X = np.array([rng.uniform(0.3, 0.7), rng.uniform(0.2, 0.5), rng.uniform(-np.pi, np.pi)])
            q0 = ik(model, X, int(rng.integers(1, 9)))
        tol = TOL * rng.uniform(0.5, 3.0)
        pm, h = X[2] + rng.uniform(-0.2, 0.2), rng.uniform(1e-3, 0.05)
        ev = enclosure(q0, tol, pm, h, geo)
        points = [(c, e) for c in corners for e in (-1.0, 1.0)] + \
                 [(rng.uniform(-1, 1, 3), rng.uniform(-1, 1)) for _ in range(30)]
        for c, e in points:
            pt = enclosure(q0 + tol * c, 0.0, pm + h * e, 0.0, geo)
            for j in (0, 2, 4, 6, 8):                               # f, df/dphi, delta, nx, ny
                assert ev[j] <= pt[j] and pt[j + 1] <= ev[j + 1], (j, c, e)


def test_the_certificate_closes_near_a_fold_where_the_tube_covers_fail(model, geo, rng):
    """Next to a fold (|S| = 351) the reading's joint box defeats every tube cover of re-acquisition; the
    eliminant proves that every joint vector of the box has exactly one solution in the phi range, in
    the box it returns (checked at random joint vectors against all DK solutions)."""
    M, l1, l2sq, b = geo
    q0 = ik(model, NEAR_FOLD, 3) + TOL * np.array([0.3, -0.5, 0.2])
    X0 = min(dk_all(model, q0).real_poses(), key=lambda p: pose_distance(p, NEAR_FOLD))
    point, out = np.empty(TUBE_SIZE), np.empty((64, TUBE_SIZE))
    assert tube_test(X0.copy(), q0, np.zeros(3), np.zeros(3), M, l1, l2sq, b, point)
    for attempt in range(1, len(EXCLUSION_COVERS) + 1):
        assert exclusion_cover(out, point, q0, np.full(3, TOL), attempt, M, l1, l2sq, b) <= 0
    plo, phi = X0[2] - 0.15, X0[2] + 0.15
    box = np.empty(6)
    assert eliminant_certificate(X0[2], q0, np.full(3, TOL), plo, phi, M, l1, l2sq, b, box)
    assert box[0] <= X0[0] <= box[1] and box[2] <= X0[1] <= box[3] and box[4] <= X0[2] <= box[5]
    for _ in range(300):
        q = q0 + TOL * rng.uniform(-1, 1, 3)
        inside = [p for p in dk_all(model, q).real_poses() if plo <= p[2] <= phi]
        assert len(inside) <= 1
        for p in inside:
            assert box[0] <= p[0] <= box[1] and box[2] <= p[1] <= box[3] and box[4] <= p[2] <= box[5]
    assert box[5] - box[4] > 0.1                                    # the needle really is long


def test_the_certificate_refuses_a_range_that_can_hold_two_solutions(model, geo):
    """A phi range holding two real solutions, a whole turn, or a prismatic leg: no certificate."""
    M, l1, l2sq, b = geo
    q = ik(model, np.array([0.5, 0.35, 0.3]), 1)
    phis = np.sort([p[2] for p in dk_all(model, q).real_poses()])
    assert len(phis) >= 2
    box = np.empty(6)
    t = np.full(3, 1e-5)
    assert not eliminant_certificate(phis[0], q, t, phis[0] - 0.01, phis[1] + 0.01, M, l1, l2sq, b, box)
    assert not eliminant_certificate(phis[0], q, t, -np.pi, np.pi, M, l1, l2sq, b, box)
    assert eliminant_certificate(phis[0], q, t, phis[0] - 0.01, phis[0] + 0.01, M, l1, l2sq, b, box)
    assert not eliminant_certificate(phis[0], q, t, phis[0] - 0.01, phis[0] + 0.01, M, l1, -np.abs(l2sq), b, box)


@pytest.mark.parametrize("posture", [3, 6])
def test_a_whole_turn_closes_where_the_other_solutions_are_in_other_postures(model, geo, rng, posture):
    """With the posture known, the runs of the other real DK solutions are ruled out by their boxes:
    over a whole turn of phi the certificate closes where the solution is the only one in its posture
    (and only there), and every DK solution in that posture at random joint vectors of the box lies in
    the returned box.  Without the posture a whole turn is refused."""
    from solver.kinematics import posture_of
    M, l1, l2sq, b = geo
    t, box = np.full(3, 1e-4), np.empty(6)
    sole, closed, checked = 0, 0, 0
    for _ in range(120):
        X0 = np.array([rng.uniform(0.2, 0.9), rng.uniform(0.1, 0.7), rng.uniform(-np.pi, np.pi)])
        q0 = ik(model, X0, posture)
        if not np.all(np.isfinite(q0)):                              # out of reach
            continue
        alone = sum(int(posture_of(model, p, q0)) == posture for p in dk_all(model, q0).real_poses()) == 1
        ok = eliminant_certificate(X0[2], q0, t, X0[2] - np.pi, X0[2] + np.pi, M, l1, l2sq, b, box, 0.0,
                                   posture - 1)
        assert not ok or alone
        sole, closed = sole + alone, closed + ok
        if ok and checked < 4:
            checked += 1
            assert not eliminant_certificate(X0[2], q0, t, X0[2] - np.pi, X0[2] + np.pi, M, l1, l2sq, b,
                                             np.empty(6))
            for _ in range(100):
                q = q0 + 1e-4 * rng.uniform(-1, 1, 3)
                for p in dk_all(model, q).real_poses():
                    if int(posture_of(model, p, q)) == posture:
                        c = p[2] + 2 * np.pi * np.round((0.5 * (box[4] + box[5]) - p[2]) / (2 * np.pi))
                        assert box[0] <= p[0] <= box[1] and box[2] <= p[1] <= box[3] and box[4] <= c <= box[5]
    assert sole >= 5 and closed >= 0.8 * sole and checked >= 4


def test_the_tracker_stays_certain_through_a_needle_the_tubes_cannot_hold(model):
    """The encoder stream of ``p3-circle-2mm`` at 16 bits + 1e-4 rad through its ill-conditioned
    stretch: certain on most steps (the tube covers alone were certain on none of them), with the
    robot inside the pose bound on every certain step where the sensor kept its tolerance."""
    from experiments.suite import hard_suite
    path = next(p for p in hard_suite(model, samplings=(1000,)) if p.name == "p3-circle-2mm/1000")
    sensor = Sensor("16-bit-1e-4", bits=16, noise=1e-4)
    q = sensor.measure(path.q, seed=5).q[600:760]
    q[0] = path.q[600]
    X_true, q_true = path.X[600:760], path.q[600:760]
    tracker = Tracker(model, coarse_map(model, 3), joint_tolerance=TOL, speed_bound=(3.76, 1.1))
    tracker.reset(X_true[0], q[0])
    kept = np.all(np.abs(wrap_angle(q - q_true)) <= TOL, axis=1)
    n_certain = 0
    for k in range(1, len(q)):
        X, info = tracker.step(q[k], 1e-3)
        if info.certain and kept[k]:
            err = np.abs(X - X_true[k])
            err[2] = abs(wrap_angle(X[2] - X_true[k, 2]))
            assert np.all(err <= info.pose_bound), k
        n_certain += info.certain
    assert n_certain >= 0.6 * (len(q) - 1)          # 117 of 159 (the tube covers alone: 0, coarse map)


def test_the_enclosure_of_a_run_stops_at_the_deadline(model, geo):
    """The pose enclosure of a long run (the needle next to a fold, 30 intervals) spends up to
    REFINE_EVALS interval evaluations: it stops at a deadline that has passed (a cycle count of 1) and
    says so (False), where without one it closes; the certificate that needs it refuses too.  (A step
    budget bounds this search: before it did not, and steps ran a millisecond over 500 us.)"""
    M, l1, l2sq, b = geo
    q0 = ik(model, NEAR_FOLD, 3) + TOL * np.array([0.3, -0.5, 0.2])
    X0 = min(dk_all(model, q0).real_poses(), key=lambda p: pose_distance(p, NEAR_FOLD))
    D0, D1 = np.empty((3, Q_SIZE)), np.empty((3, Q_SIZE))
    joint_box_elbows(q0, np.full(3, TOL), M, l1, D0, D1)
    n = int(np.ceil(0.3 / PHI_STEP))
    edges = X0[2] - 0.15 + 0.3 * np.arange(n + 1) / n
    run = np.column_stack([edges[:-1], edges[1:]])
    ev, box = np.empty(10), np.empty(6)
    assert run_box(run, n, D0, D1, b, l2sq, ev, box)
    assert box[4] <= X0[2] <= box[5]
    assert not run_box(run, n, D0, D1, b, l2sq, ev, box, 1.0)
    assert not eliminant_certificate(X0[2], q0, np.full(3, TOL), X0[2] - 0.15, X0[2] + 0.15, M, l1, l2sq, b,
                                     box, 1.0)
