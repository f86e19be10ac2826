"""One manipulator interface: the 3-RPR through the functions and procedure 1 written for the 3-RRR."""
import numpy as np
import pytest

from solver.baselines import BASELINES

from experiments.rpr_scan import dk_all_scan
from solver import MapTensor, Manipulator, SolverInputError, constraints, default_bounds, dk_all, ik, jacobians, \
    posture_of, singularity_measures
from solver.maptensor import MATCH_TOL, label_poses
from solver.manipulators import MANIPULATOR_TYPES, check_manipulator, manipulator_from_dict
from solver.rpr import RPR_HOME_POSE, RPR_WORK_BOUNDS, RPRManipulator, det_j
from solver.rpr import ik as rpr_ik
from solver.rpr import jacobians as rpr_jacobians

#: A grid over the 3-RPR's working area around the published slice: 5 cm, 4 degrees.
RPR_BOUNDS = np.array([[-1.0, 3.0], [-1.5, 2.5], [-np.pi, np.pi]])
RPR_SHAPE = (81, 81, 90)


@pytest.fixture(scope="module")
def rpr():
    return RPRManipulator.zein_wenger_chablat()


@pytest.fixture(scope="module")
def rpr_map(rpr):
    return MapTensor.build(rpr, 1, bounds=RPR_BOUNDS, shape=RPR_SHAPE)


def _poses(rng, n):
    return np.column_stack([rng.uniform(0.3, 1.9, n), rng.uniform(-0.6, 1.3, n), rng.uniform(-np.pi, np.pi, n)])


def test_every_model_has_the_interface(model, rpr):
    for m, kind, n, unit in ((model, "3-RRR", 8, "rad"), (rpr, "3-RPR", 1, "m")):
        assert MANIPULATOR_TYPES[m.kind] is type(m) and (m.kind, m.n_postures, m.joint_unit) == (kind, n, unit)
        assert check_manipulator(m) is m
        assert manipulator_from_dict(m.to_dict()) == m
        centres, radii = m.reach_discs()
        assert centres.shape == (3, 2) and radii.shape == (3,) and np.all(radii > 0)
    with pytest.raises(SolverInputError, match="model"):
        check_manipulator("3-RPR")


def test_the_sextic_dk_of_the_3rpr_finds_what_the_dense_scan_finds(rpr, rng):
    """The circle-leg kernel written for the 3-RRR, fed the 3-RPR's legs, against an independent scan."""
    X = _poses(rng, 150)
    rho = rpr_ik(rpr, X)
    sol = dk_all(rpr, rho)
    ref, count = dk_all_scan(rpr, rho)
    assert np.array_equal(sol.real.sum(axis=-1), count)
    for n in range(len(X)):
        P = sol.poses[n][sol.real[n]].real
        for r in ref[n, :count[n]]:
            d = np.abs(P[:, :2] - r[:2]).max(axis=1) + np.abs((P[:, 2] - r[2] + np.pi) % (2 * np.pi) - np.pi)
            assert d.min() < 1e-9
        np.testing.assert_allclose(constraints(rpr, P, rho[n]), 0.0, atol=1e-9)


def test_the_generic_functions_dispatch_to_the_3rpr(rpr, rng):
    X = _poses(rng, 20)
    rho = ik(rpr, X)
    np.testing.assert_array_equal(rho[np.isfinite(rho[:, 0])], rpr_ik(rpr, X)[np.isfinite(rho[:, 0])])
    assert np.all(posture_of(rpr, X, rpr_ik(rpr, X)) == 1)
    J, K = jacobians(rpr, X, rpr_ik(rpr, X))
    Jr, Kr = rpr_jacobians(rpr, X, rpr_ik(rpr, X))
    np.testing.assert_array_equal(J, Jr)
    np.testing.assert_array_equal(K, Kr)
    sm = singularity_measures(rpr, X, rpr_ik(rpr, X))
    np.testing.assert_allclose(sm.det_J, np.linalg.det(Jr))
    assert np.all((sm.type1 > 0) & (sm.type1 <= 1))
    with pytest.raises(SolverInputError, match="posture"):
        ik(rpr, X, 2)
    far = np.array([[10.0, 10.0, 0.0]])                          # legs longer than rho_max
    assert np.all(np.isnan(ik(rpr, far)))


def test_procedure_1_labels_the_3rpr_and_its_nodes_are_their_solutions(rpr, rpr_map):
    xs, ys, phis = rpr_map.axes()
    G = np.stack(np.meshgrid(xs, ys, phis, indexing="ij"), axis=-1).reshape(-1, 3)
    labels, mismatch = label_poses(rpr, G, 1)
    np.testing.assert_array_equal(labels.reshape(RPR_SHAPE), rpr_map.labels)
    off = mismatch > 1e-8                        # found only to about sqrt(eps): exactly singular nodes (double roots)
    assert mismatch.max() < 10 * MATCH_TOL and np.all(np.abs(det_j(rpr, G[off])) < 1e-9)
    counts = rpr_map.stats["label_counts"]
    assert counts[0] > 0 and sum(c > 0 for c in counts[1:]) >= 4  # outside the limits; several regions
    with pytest.raises(SolverInputError, match="postures 1..1"):
        MapTensor.build(rpr, 2, bounds=RPR_BOUNDS, shape=(3, 3, 3))


def test_a_3rpr_region_border_that_is_not_a_singularity(rpr, rpr_map):
    """Basic regions of a cuspidal manipulator: a border where the label changes while det J keeps its
    sign on both sides and stays far from zero (a characteristic surface, not a singular one)."""
    xs, ys, phis = rpr_map.axes()
    L = np.asarray(rpr_map.labels)
    a, b = L[:-1], L[1:]                                          # neighbours along x
    i, j, k = np.nonzero((a > 0) & (b > 0) & (a != b))
    Xa = np.stack([xs[i], ys[j], phis[k]], axis=-1)
    Xb = np.stack([xs[i + 1], ys[j], phis[k]], axis=-1)
    da, db = det_j(rpr, Xa), det_j(rpr, Xb)
    scale = np.percentile(np.abs(det_j(rpr, Xa)), 90)
    regular = (np.sign(da) == np.sign(db)) & (np.minimum(np.abs(da), np.abs(db)) > 0.05 * scale)
    assert regular.sum() > 0
    assert regular.sum() < len(da)                                # and borders that are singular curves too


def test_the_3rrr_results_are_unchanged_by_the_interface(model):
    """The default manipulator through the same kernel: its DK still returns the pose it came from."""
    X = np.array([[0.5, 0.3, 0.1], [0.45, 0.25, -0.4]])
    q = ik(model, X, 1)
    sol = dk_all(model, q)
    for n in range(2):
        P = sol.poses[n][sol.real[n]].real
        assert np.min(np.abs(P - X[n]).max(axis=1)) < 1e-12
    assert isinstance(model, Manipulator)
    np.testing.assert_allclose(default_bounds(model)[:2], [[-0.38, 1.38], [-0.51, 1.24]], atol=1e-9)


@pytest.fixture(scope="module")
def loop_map(rpr):
    return MapTensor.build(rpr, 1, bounds=RPR_WORK_BOUNDS, shape=(46, 41, 60))


@pytest.mark.parametrize("n", [30, 9, 5])
def test_the_tracker_follows_a_nonsingular_assembly_mode_change_where_newton_jumps(rpr, loop_map, n):
    """Around cusp 1 the legs come back to their start and the platform to another assembly mode;
    the tracker (certificates, not the map) ends in it, vouching all the way; at 9 samples a loop
    Newton from the previous pose jumps branch and says nothing."""
    from solver import Tracker
    from solver.baselines import NewtonTracker
    from experiments.rpr_suite import cusp_loop_path
    path = cusp_loop_path(rpr, 1, n)
    np.testing.assert_allclose(path.X[0], RPR_HOME_POSE, atol=1e-12)           # the FMU's start values
    assert np.array_equal(path.q[0], path.q[-1]) and np.abs(path.X[-1] - path.X[0]).max() > 0.3
    res = Tracker(rpr, loop_map).track(path.q, path.X[0])
    wrong = np.abs(res.X - path.X).max(axis=1) > 1e-9
    assert not wrong.any() and res.certain.all()
    newton = NewtonTracker(rpr).track(path.q, path.X[0])
    jumped = np.abs(newton.X - path.X).max(axis=1) > 1e-6
    assert jumped.any() == (n == 9)


def test_the_tracker_refuses_a_map_of_another_manipulator(model, rpr, loop_map):
    from solver import Tracker, TrackerError
    with pytest.raises(TrackerError, match="map_tensor"):
        Tracker(model, loop_map)


def test_legs_outside_the_joint_limits_are_refused_by_name(rpr, loop_map):
    """The re-acquisition proof searches the tool space the joint limits bound: a leg beyond them is
    refused (SolverInputError naming q), and the state is kept."""
    from solver import SolverInputError, Tracker
    from experiments.rpr_suite import cusp_loop_path
    path = cusp_loop_path(rpr, 1, 30)
    tr = Tracker(rpr, loop_map, joint_tolerance=1e-6)
    tr.reset(path.X[0], path.q[0])
    before = tr.state
    with pytest.raises(SolverInputError, match="joint limits"):
        tr.step(path.q[1] + np.array([0.0, rpr.rho_max, 0.0]), 1e-3)
    assert tr.state is before
    _, info = tr.step(path.q[1], 1e-3)
    assert info.status == 0
    # a whole stream (track's compiled loop): refused before any step, naming the row
    bad = path.q.copy()
    bad[5, 1] += rpr.rho_max
    for tracker in (tr, BASELINES["newton"](rpr)):
        with pytest.raises(SolverInputError, match="q_stream: expected leg lengths within the joint limits.*row 5"):
            tracker.track(bad, path.X[0])
