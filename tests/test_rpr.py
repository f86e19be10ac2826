"""The 3-RPR module: kinematics against finite differences, the scan DK, cusps and the
non-singular assembly-mode change of the Zein-Wenger-Chablat geometry."""
import numpy as np
import pytest

from experiments.rpr_cusps import assembly_mode_change_path, cusp_points
from experiments.rpr_scan import dk_all_scan, follow
from solver.checks import GeometryError, SolverInputError
from solver.rpr import ZEIN_RHO1, RPRManipulator, constraints, det_j, ik, jacobians
from conftest import pose_distance


@pytest.fixture(scope="module")
def rpr():
    return RPRManipulator.zein_wenger_chablat()


@pytest.fixture(scope="module")
def cusps(rpr):
    return cusp_points(rpr, ZEIN_RHO1)


@pytest.fixture(scope="module")
def change(rpr):
    return assembly_mode_change_path(rpr)


def poses(rng, n):
    return np.column_stack([rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-np.pi, np.pi, n)])


def nearest(sol, X):
    """Pose distance from X (..., 3) to the nearest of the NaN-padded solutions (..., 6, 3)."""
    return np.nanmin(np.where(np.isnan(sol[..., 0]), np.inf, pose_distance(sol, X[..., None, :])), axis=-1)


# ------------------------------------------------------------------ geometry
def test_geometry_is_the_recalled_one_scaled_to_metres(rpr):
    np.testing.assert_allclose(rpr.base, [[0, 0], [1.591, 0], [0, 1.0]])
    b = rpr.platform
    sides = [np.linalg.norm(b[i] - b[j]) for i, j in ((0, 1), (1, 2), (2, 0))]
    np.testing.assert_allclose(sides, [1.704, 1.654, 2.084], rtol=1e-14)
    assert b[2, 1] > 0 and np.all(b[0] == 0)


def test_model_is_frozen_and_serialisable(rpr):
    with pytest.raises(AttributeError):
        rpr.base = np.zeros((3, 2))
    with pytest.raises(ValueError):
        rpr.platform[0, 0] = 1.0
    again = RPRManipulator.from_dict(rpr.to_dict())
    assert again == rpr and hash(again) == hash(rpr) and again.digest() == rpr.digest()
    other = RPRManipulator.from_dict({**rpr.to_dict(), "rho_max": 3.9})
    assert other != rpr and other.digest() != rpr.digest()


@pytest.mark.parametrize("kwargs, word", [
    (dict(base=[[0, 0], [1, 0], [2, 0]]), "base"),
    (dict(base=[[0, 0], [1, 0]]), "base"),
    (dict(platform=np.zeros((3, 2))), "platform"),
    (dict(platform=[[0, 0], [1, np.nan], [0, 1]]), "platform"),
    (dict(rho_min=-0.1), "rho_min"),
    (dict(rho_min=2.0, rho_max=1.0), "rho_max"),
    (dict(name=3), "name"),
])
def test_invalid_geometry_names_the_argument(rpr, kwargs, word):
    with pytest.raises(GeometryError, match=word):
        RPRManipulator(**{**dict(base=rpr.base, platform=rpr.platform), **kwargs})
    with pytest.raises(GeometryError, match="platform"):
        RPRManipulator.from_dict({k: v for k, v in rpr.to_dict().items() if k != "platform"})


@pytest.mark.parametrize("call, word", [
    (lambda m: ik(m, [0.1, 0.2]), "X"),
    (lambda m: constraints(m, [0.1, 0.2, 0.3], [1.0, -1.0, 1.0]), "rho"),
    (lambda m: jacobians(m, [0.1, 0.2, np.nan], [1.0, 1.0, 1.0]), "X"),
    (lambda m: dk_all_scan(m, [[1.0, 1.0, np.inf]]), "rho"),
    (lambda m: dk_all_scan(m, [1.0, 1.0, 1.0], n_phi=0), "n_phi"),
    (lambda m: det_j(m, "abc"), "X"),
    (lambda m: follow(m, [[1.0, 1.0, 1.0]], [0.0, 0.0]), "X0"),
    (lambda m: cusp_points(m, -1.0), "rho1"),
    (lambda m: assembly_mode_change_path(m, cusp=99), "cusp"),
    (lambda m: ik(None, [0.0, 0.0, 0.0]), "model"),
])
def test_invalid_inputs_name_the_argument(rpr, call, word):
    with pytest.raises(SolverInputError, match=word):
        call(rpr)


# ------------------------------------------------------------------ kinematics
def test_ik_constraints_round_trip_any_batch_shape(rpr, rng):
    X = poses(rng, 600).reshape(20, 30, 3)
    rho = ik(rpr, X)
    assert rho.shape == (20, 30, 3) and np.all(rho > 0)
    assert np.max(np.abs(constraints(rpr, X, rho))) < 1e-13
    assert np.all(np.abs(constraints(rpr, X, rho * 1.01)) > 1e-6)
    np.testing.assert_array_equal(ik(rpr, X[3, 4]), rho[3, 4])


def test_jacobians_match_finite_differences(rpr, rng):
    X, rho = poses(rng, 200), rng.uniform(0.5, 3.0, (200, 3))
    J, K = jacobians(rpr, X, rho)
    h = 1e-6
    for c in range(3):
        e = h * np.eye(3)[c]
        dX = (constraints(rpr, X + e, rho) - constraints(rpr, X - e, rho)) / (2 * h)
        drho = (constraints(rpr, X, rho + e) - constraints(rpr, X, rho - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, c], dX, atol=1e-8)
        np.testing.assert_allclose(K[:, :, c], drho, atol=1e-8)
    np.testing.assert_allclose(det_j(rpr, X), np.linalg.det(J), rtol=1e-12, atol=1e-12)
    assert np.all(K[:, [0, 1, 0, 2, 1, 2], [1, 0, 2, 0, 2, 1]] == 0)


# ------------------------------------------------------------------ dense-scan DK
def test_scan_finds_the_pose_and_only_true_solutions(rpr, rng):
    X = poses(rng, 400)
    sol, count = dk_all_scan(rpr, ik(rpr, X))
    assert sol.shape == (400, 6, 3) and count.shape == (400,)
    assert np.all(nearest(sol, X) < 1e-9)
    real = ~np.isnan(sol[..., 0])
    np.testing.assert_array_equal(real.sum(axis=1), count)
    assert np.all(real[:, :-1] >= real[:, 1:])                        # NaN padding at the end
    F = constraints(rpr, np.where(real[..., None], sol, 0.0), np.broadcast_to(ik(rpr, X)[:, None], sol.shape))
    assert np.max(np.abs(F[real])) <= 1e-9
    assert set(np.unique(count)) <= {2, 4, 6} and {2, 4, 6} <= set(np.unique(count))   # parity
    assert all(np.all(np.diff(S[:k, 2]) > 0) for S, k in zip(sol, count))   # sorted by phi
    assert np.all(np.abs(sol[real][:, 2]) <= np.pi)


def test_scan_agrees_with_multistart_newton(rpr, rng):
    """Random joints (some out of reach): the same number of solutions as Newton from 3000 starts."""
    rho = rng.uniform(0.2, 3.5, (12, 3))
    sol, count = dk_all_scan(rpr, rho)
    for q, k, S in zip(rho, count, sol):
        X = np.column_stack([rng.uniform(-4, 4, (3000, 2)), rng.uniform(-np.pi, np.pi, 3000)])
        for _ in range(80):
            F = constraints(rpr, X, q)
            with np.errstate(all="ignore"):
                dX = np.linalg.solve(jacobians(rpr, X, q)[0], -F[..., None])[..., 0]
            X = np.nan_to_num(X + dX / np.clip(np.abs(dX).max(1, keepdims=True) / 0.3, 1, None))
        X = X[np.max(np.abs(constraints(rpr, X, q)), axis=1) < 1e-11]
        assert np.all(nearest(np.broadcast_to(S, (len(X), 6, 3)), X) < 1e-7)   # nothing the scan missed
        assert all(np.min(pose_distance(X, s)) < 1e-7 for s in S[:k])           # nothing it made up


def test_scan_separates_close_pairs_near_a_singularity(rpr, rng):
    """Joints of a pose eps from det J = 0 (along the null vector): both merging solutions are found."""
    X = poses(rng, 200)
    phi = X[:, 2:] + np.linspace(0.0, 2 * np.pi, 721)                 # first sign change of det J in phi
    d = det_j(rpr, np.concatenate([np.broadcast_to(X[:, None, :2], phi.shape + (2,)), phi[..., None]], -1))
    flip = np.sign(d[:, :-1]) != np.sign(d[:, 1:])
    X, k, d = X[flip.any(1)], flip.argmax(1)[flip.any(1)], d[flip.any(1)]
    a, b = phi[flip.any(1), k], phi[flip.any(1), k + 1]
    for _ in range(60):
        c = 0.5 * (a + b)
        left = np.sign(det_j(rpr, np.column_stack([X[:, :2], c]))) == np.sign(d[np.arange(len(k)), k])
        a, b = np.where(left, c, a), np.where(left, b, c)
    Xs = np.column_stack([X[:, :2], a])                               # singular poses
    v = np.linalg.svd(jacobians(rpr, Xs, np.ones(3))[0])[2][:, -1]    # null vectors
    assert len(Xs) >= 150
    for eps in (1e-3, 1e-4, 1e-5):
        sol, count = dk_all_scan(rpr, ik(rpr, Xs + eps * v))
        assert np.all(nearest(sol, Xs + eps * v) < 1e-7)
        close = pose_distance(sol, Xs[:, None, :]) < 3 * eps          # the pose and its partner ~ Xs - eps v
        np.testing.assert_array_equal(close.sum(axis=1), 2)


# ------------------------------------------------------------------ cusps and the mode change
def test_cusps_of_the_published_slice(rpr, cusps):
    assert len(cusps.joints) == 6
    np.testing.assert_allclose(cusps.joints[:, 0], ZEIN_RHO1)
    np.testing.assert_allclose(ik(rpr, cusps.poses), cusps.joints, atol=1e-12)
    assert np.all(np.abs(det_j(rpr, cusps.poses)) < 1e-12)           # |det J| ~ 1 m^4/rad elsewhere
    np.testing.assert_allclose(np.linalg.norm(cusps.tangent, axis=1), 1.0)
    np.testing.assert_allclose(cusps.joints[3], [1.498, 1.79885469, 2.64461833], atol=1e-7)   # regression


@pytest.mark.parametrize("r", [1e-4, 1e-5])
def test_three_solutions_merge_at_each_cusp(rpr, cusps, r):
    """r m from the cusp on its tangent: inside the wedge three solutions lie within ~sqrt(r) of the
    cusp pose (one ~r away, the pair ~sqrt(r) away), outside one."""
    for q, Xc, t in zip(*cusps):
        sol, count = dk_all_scan(rpr, q + np.outer([1.0, -1.0], np.r_[0.0, r * t]))
        near = pose_distance(sol, Xc) < 4 * np.sqrt(r)
        assert near.sum(axis=1).tolist() == [3, 1]
        assert count[0] == count[1] + 2
    sol, count = dk_all_scan(rpr, cusps.joints)                       # at the cusp itself: one (triple) root
    assert np.all(nearest(sol, cusps.poses) < 1e-4)


def test_loop_around_a_cusp_changes_assembly_mode_without_a_singularity(rpr, change):
    rho, P = change.rho, change.poses
    np.testing.assert_array_equal(rho[0], rho[-1])
    np.testing.assert_allclose(rho[:, 0], ZEIN_RHO1)
    rad = np.linalg.norm(rho[:, 1:] - change.cusp[1:], axis=1)
    np.testing.assert_allclose(rad, rad[0], rtol=1e-12)
    winding = np.sum(np.diff(np.unwrap(np.arctan2(*(rho[:, 1:] - change.cusp[1:]).T[::-1]))))
    assert abs(abs(winding) - 2 * np.pi) < 1e-9                       # once around the cusp
    assert np.max(np.abs(constraints(rpr, P, rho))) < 1e-9
    assert np.max(np.abs(np.diff(P, axis=0))) < 0.01                  # a continuous motion
    assert np.all(np.sign(change.det_j) == np.sign(change.det_j[0]))
    assert change.min_abs_det > 0.3 * abs(change.det_j[0])
    np.testing.assert_allclose(det_j(rpr, P), change.det_j)
    assert pose_distance(change.start, change.end) > 0.5              # another assembly mode
    sol, count = dk_all_scan(rpr, rho[0])
    assert nearest(sol, change.start) < 1e-9 and nearest(sol, change.end) < 1e-9
    back, ok = follow(rpr, rho[::-1], change.end)                     # and the way back
    assert ok.all() and pose_distance(back[-1], change.start) < 1e-9


def test_same_loop_away_from_the_cusp_changes_nothing(rpr, cusps, change):
    t = cusps.tangent[np.argmin(np.abs(cusps.joints - change.cusp).sum(axis=1))]
    radius = np.linalg.norm(change.rho[0, 1:] - change.cusp[1:])
    for off in (-0.08, 0.08):
        loop = change.rho + np.r_[0.0, off * np.array([-t[1], t[0]])]
        sol, count = dk_all_scan(rpr, loop[0])
        for X in sol[:count]:
            P, ok = follow(rpr, loop, X)
            assert ok.all() and pose_distance(P[-1], X) < 1e-9
    assert radius < 0.08


def test_coarse_sampling_of_the_loop(rpr, change):
    """Newton from the previous pose follows the loop sampled every 30 deg; every 45 deg it jumps."""
    for N, same in ((13, True), (25, True), (9, False)):
        idx = np.linspace(0, len(change.rho) - 1, N).round().astype(int)
        P, ok = follow(rpr, change.rho[idx], change.start)
        assert (pose_distance(P[-1], change.end) < 1e-9) == same
