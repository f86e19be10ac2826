"""IK in 8 postures, all six DK solutions, J and K: properties that could fail."""
import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.optimize import brentq, minimize_scalar

from solver import (Manipulator, SolverInputError, constraints, dk_all, ik, jacobians,
                    order_solutions, posture_of, singularity_measures)
from solver._kernels.direct_kinematics import elim
from solver.direct_kinematics import kernel_constants
from conftest import pose_distance, random_poses

EXAMPLE = np.array([0.8, 0.0, np.deg2rad(15.0)])   # posture 1, six real solutions


def contains(sol, X, tol):
    d = np.where(sol.real, pose_distance(sol.poses.real, np.asarray(X)[..., None, :]), np.inf)
    return d.min(axis=-1) <= tol


# ------------------------------------------------------------------ IK / DK round trip
@pytest.mark.parametrize("posture", range(1, 9))
def test_round_trip_10000_poses_per_posture(model, posture):
    rng = np.random.default_rng(posture)
    X = random_poses(rng, 40000)
    q = ik(model, X, posture)
    X, q = X[~np.isnan(q[:, 0])][:10000], q[~np.isnan(q[:, 0])][:10000]
    assert len(X) == 10000
    assert np.all(posture_of(model, X, q) == posture)
    assert np.all(np.abs(constraints(model, X, q)) < 1e-12)
    sol = dk_all(model, q)
    assert np.all(contains(sol, X, 1e-9))


def test_ik_postures_have_the_documented_elbow_signs(model):
    X = np.array([0.5, 0.3, 0.2])
    for j in range(1, 9):
        q = ik(model, X, j)
        D = model.motors + 0.6 * np.column_stack([np.cos(q), np.sin(q)])
        from solver import platform_points
        A = platform_points(model, X)
        a, b = D - model.motors, A - D
        s = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        assert j == 1 + sum(int(s[i] < 0) << i for i in range(3))


def test_ik_is_nan_outside_the_tool_space_and_broadcasts_postures(model):
    X = np.array([[0.5, 0.3, 0.0], [3.0, 3.0, 0.0]])
    q = ik(model, X, 1)
    assert np.all(np.isfinite(q[0])) and np.all(np.isnan(q[1]))
    qs = ik(model, np.broadcast_to(X[0], (8, 3)), np.arange(1, 9))
    for j in range(8):
        np.testing.assert_array_equal(qs[j], ik(model, X[0], j + 1))


def test_real_solutions_satisfy_the_constraints_and_come_in_pairs(model):
    rng = np.random.default_rng(7)
    q = np.concatenate([rng.uniform(-np.pi, np.pi, (50000, 3)),
                        ik(model, random_poses(rng, 50000), rng.integers(1, 9, 50000))])
    q = q[~np.isnan(q[:, 0])]
    sol = dk_all(model, q)
    F = constraints(model, np.where(sol.real[..., None], sol.poses.real, 0.0), q[:, None, :])
    assert np.max(np.abs(np.where(sol.real[..., None], F, 0.0))) <= 1e-10
    assert np.all(np.abs(sol.poses.real[sol.real][:, 2]) <= np.pi)
    # away from singularities (every real solution well conditioned) the count is even
    t1 = singularity_measures(model, np.where(sol.real[..., None], sol.poses.real, 0.0),
                              q[:, None, :]).type1
    regular = np.all(np.where(sol.real, t1, 1.0) > 1e-6, axis=1)
    assert regular.mean() > 0.99
    assert set(np.unique(sol.n_real[regular])) <= {0, 2, 4, 6}
    assert {0, 2, 4, 6} <= set(np.unique(sol.n_real))
    assert not np.any(np.isnan(sol.poses[sol.real]))


def test_a_joint_vector_with_six_real_solutions(model):
    q = ik(model, EXAMPLE, 1)
    sol = dk_all(model, q, rule="real-phi")
    assert sol.n_real == 6
    P = sol.real_poses()
    assert np.max(np.abs(constraints(model, P, q))) < 1e-14
    d = pose_distance(P[:, None, :], P[None, :, :]) + np.eye(6)
    assert d.min() > 0.05                                      # six distinct assembly modes
    assert contains(sol, EXAMPLE, 1e-12)
    assert np.all(np.diff(P[:, 2]) > 0)                        # numbered by phi (rule real-phi)
    ref = scan_solutions(model, q)
    assert len(ref) == 6
    assert pose_distance(ref[:, None, :], P[None, :, :]).min(axis=1).max() < 1e-9


# ------------------------------------------------------------------ independent cross-check
def scan_solutions(model, q, n=20001):
    """Real DK solutions by a dense scan over phi with bracketing (no sextic involved).

    For each phi, P lies on the circles |P - C_i(phi)| = l2_i with
    C_i = D_i - R(phi) b_i.  Intersecting circles 1 and 2 gives two branches
    P+-(phi); the roots of g(phi) = |P+-(phi) - C_3|^2 - l2_3^2 are bracketed on
    the grid (and at the branch end points, found by bisection) and refined by
    Brent's method; a local minimum of |g| without a sign change is split at
    the extremum of g, so two roots closer than the grid spacing are not lost.
    """
    q = np.asarray(q, float)
    D = model.motors + model.l1[:, None] * np.column_stack([np.cos(q), np.sin(q)])
    b, l2 = model.platform, model.l2

    def branch(phi, sign):
        phi = np.asarray(phi, float)
        c, s = np.cos(phi)[..., None], np.sin(phi)[..., None]
        C = D - np.stack([c * b[:, 0] - s * b[:, 1], s * b[:, 0] + c * b[:, 1]], axis=-1)
        d = C[..., 1, :] - C[..., 0, :]
        dist = np.hypot(d[..., 0], d[..., 1])
        a = (l2[0] ** 2 - l2[1] ** 2 + dist ** 2) / (2 * dist)
        disc = l2[0] ** 2 - a ** 2
        h = np.sqrt(np.maximum(disc, 0.0))
        e = d / dist[..., None]
        P = C[..., 0, :] + a[..., None] * e + sign * h[..., None] * np.stack([-e[..., 1], e[..., 0]], -1)
        g = np.sum((P - C[..., 2, :]) ** 2, axis=-1) - l2[2] ** 2
        return g, P, disc

    Dl, bl, l2l = D.tolist(), b.tolist(), [float(v) for v in l2]

    def branch1(phi, sign):
        """``branch`` at one phi in plain floats (the refinements call it hundreds of times)."""
        c, s = math.cos(phi), math.sin(phi)
        C = [(Dl[i][0] - (c * bl[i][0] - s * bl[i][1]), Dl[i][1] - (s * bl[i][0] + c * bl[i][1])) for i in range(3)]
        dx, dy = C[1][0] - C[0][0], C[1][1] - C[0][1]
        dist = math.hypot(dx, dy)
        a = (l2l[0] ** 2 - l2l[1] ** 2 + dist ** 2) / (2 * dist)
        disc = l2l[0] ** 2 - a ** 2
        h = math.sqrt(max(disc, 0.0))
        ex, ey = dx / dist, dy / dist
        P = (C[0][0] + a * ex - sign * h * ey, C[0][1] + a * ey + sign * h * ex)
        return (P[0] - C[2][0]) ** 2 + (P[1] - C[2][1]) ** 2 - l2l[2] ** 2, P, disc

    phis = np.linspace(-np.pi, np.pi, n)
    _, _, disc = branch(phis, 1.0)
    valid = disc >= 0
    # branch end points: refine the valid/invalid transitions by bisection
    ends = []
    for i in np.nonzero(valid[:-1] != valid[1:])[0]:
        lo, hi = (phis[i], phis[i + 1]) if valid[i] else (phis[i + 1], phis[i])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if branch1(mid, 1.0)[2] >= 0:
                lo = mid
            else:
                hi = mid
        ends.append(lo)
    grid = np.sort(np.concatenate([phis[valid], ends]))
    out = []
    h = phis[1] - phis[0]
    for sign in (1.0, -1.0):
        g, _, _ = branch(grid, sign)
        gap = np.diff(grid) > 2 * h                            # an invalid stretch between samples
        brackets = [(grid[i], grid[i + 1]) for i in
                    np.nonzero(((g[:-1] == 0) | (g[:-1] * g[1:] < 0)) & ~gap)[0]]
        # |g| has a local minimum without a sign change: two roots closer than the grid may
        # hide in [grid[i-1], grid[i+1]]; the extremum of g splits them
        i = np.arange(1, len(grid) - 1)
        cand = i[(g[i - 1] * g[i] > 0) & (g[i] * g[i + 1] > 0) & ~gap[i - 1] & ~gap[i]
                 & (np.abs(g[i]) < np.abs(g[i - 1])) & (np.abs(g[i]) <= np.abs(g[i + 1]))]
        for i in cand:
            gg = lambda p, sg=sign, s0=float(np.sign(g[i])): s0 * branch1(p, sg)[0]
            m = minimize_scalar(gg, bounds=(grid[i - 1], grid[i + 1]), method="bounded",
                                options={"xatol": 1e-14})
            if m.fun < 0:
                brackets += [(grid[i - 1], m.x), (m.x, grid[i + 1])]
        for a, c in brackets:
            r = brentq(lambda p: branch1(p, sign)[0], a, c, xtol=1e-15, rtol=1e-15)
            P = branch1(r, sign)[1]
            out.append([P[0], P[1], r])
    out = np.array(out).reshape(-1, 3)
    # a root at phi = +-pi appears at both ends of the grid
    keep = [i for i in range(len(out))
            if not any(pose_distance(out[i], out[j]) < 1e-9 for j in range(i))]
    return out[keep]


def test_the_sextic_roots_match_the_companion_matrix(rng):
    """``roots6`` (Aberth-Ehrlich in real arithmetic) against numpy's companion-matrix eigenvalues on
    random real sextics: separated roots to 1e-9 of their modulus; a close pair (1e-6 apart) to
    within the pair's conditioning (about sqrt(eps) of the scale)."""
    from solver._kernels.direct_kinematics import roots6
    for trial in range(300):
        half = rng.normal(size=3) + 1j * rng.normal(size=3)
        if trial % 3 == 0:
            half[1] = half[0] + 1e-6
        want = np.concatenate([half, half.conj()])
        coef = np.real(np.poly(want)) * rng.uniform(0.1, 10.0)
        got = roots6(coef)
        ref = np.roots(coef)
        assert np.all(np.isfinite(got))
        gap = np.abs(got[:, None] - ref[None, :]).min(axis=1)
        tol = 1e-9 * (1 + np.abs(ref).max()) if trial % 3 else 1e-5 * (1 + np.abs(ref).max())
        assert gap.max() <= tol, (trial, gap.max())
        # each root once: the nearest pairs match one to one
        assert len(set(np.abs(got[:, None] - ref[None, :]).argmin(axis=1))) == 6 or trial % 3 == 0


def test_dense_scan_cross_check_on_1000_joint_vectors(model):
    rng = np.random.default_rng(11)
    q = ik(model, random_poses(rng, 3000), rng.integers(1, 9, 3000))
    q = np.concatenate([q[~np.isnan(q[:, 0])][:700], rng.uniform(-np.pi, np.pi, (300, 3))])
    assert len(q) == 1000
    sol = dk_all(model, q)
    counts = {}
    for k in range(len(q)):
        ref = scan_solutions(model, q[k])
        mine = sol.poses[k][sol.real[k]].real
        assert len(ref) == len(mine), (k, q[k], ref, mine)
        if len(ref):
            d = pose_distance(ref[:, None, :], mine[None, :, :])
            assert np.all(d.min(axis=1) <= 1e-9) and np.all(d.min(axis=0) <= 1e-9), (k, d)
        counts[len(ref)] = counts.get(len(ref), 0) + 1
    assert set(counts) >= {0, 2, 4}


# ------------------------------------------------------------------ the elimination itself
def test_eliminant_has_no_fourth_harmonic(model, rng):
    """The e^{+-4 i phi} terms cancel identically (isotropic vectors), so the degree is 6."""
    k = kernel_constants(model)
    for q in rng.uniform(-np.pi, np.pi, (20, 3)):
        D = model.motors + 0.6 * np.column_stack([np.cos(q), np.sin(q)])
        phis = 2 * np.pi * np.arange(16) / 16
        f = []
        for p in phis:
            d, nx, ny, ux, uy, k0, *_ = elim(np.cos(p), np.sin(p), D, k["b"], k["l2sq"])
            f.append(nx * nx + ny * ny + 2 * d * (nx * ux + ny * uy) + d * d * k0)
        a = np.abs(np.fft.fft(f)) / 16
        assert a[4] <= 1e-13 * a.max() and a[5:12].max() <= 1e-13 * a.max()
        assert a[3] > 1e-6 * a.max()                 # genuinely degree 3 in e^{i phi}


def test_phi_equal_pi_is_found(model):
    """tan(phi/2) is infinite at phi = pi; the shifted substitution never loses that root."""
    for X in ([0.5, 0.3, np.pi], [0.45, 0.25, -np.pi], [0.52, 0.33, np.pi - 1e-12]):
        for j in range(1, 9):
            q = ik(model, X, j)
            if np.isnan(q[0]):
                continue
            sol = dk_all(model, q)
            assert contains(sol, X, 1e-10), (X, j)
            phi = sol.poses.real[sol.real][:, 2]
            assert np.all((phi > -np.pi) & (phi <= np.pi))


def delta_of_pose(model, X, posture):
    """Delta of the 2x2 solve at the true solution: (L2 - L1) x (L3 - L1), L_i = A_i - D_i."""
    from solver import elbow_points, platform_points
    q = ik(model, X, posture)
    L = platform_points(model, X) - elbow_points(model, q)
    u, v = L[1] - L[0], L[2] - L[0]
    return u[0] * v[1] - u[1] * v[0]


def test_singular_two_by_two_solve_gives_the_twin_solutions(model):
    """Where Delta = 0 two real solutions share phi; both are found, no NaN."""
    phis = np.linspace(-np.pi, np.pi, 361)
    for x, y, post in ((0.5, 0.3, 1), (0.4, 0.4, 1), (0.6, 0.2, 2), (0.5, 0.3, 3), (0.3, 0.5, 5)):
        vals = np.array([delta_of_pose(model, [x, y, p], post) for p in phis])
        hits = np.nonzero(np.isfinite(vals[:-1] * vals[1:]) & (vals[:-1] * vals[1:] < 0))[0]
        if len(hits):
            i = hits[0]
            break
    else:
        pytest.fail("no pose with Delta = 0 found")
    phi0 = brentq(lambda p: delta_of_pose(model, [x, y, p], post), phis[i], phis[i + 1], xtol=1e-16)
    X = np.array([x, y, phi0])
    q = ik(model, X, post)
    sol = dk_all(model, q)
    assert not np.any(np.isnan(sol.poses[sol.real]))
    assert contains(sol, X, 1e-9)
    P = sol.real_poses()
    twins = P[np.abs(P[:, 2] - phi0) < 1e-6]
    assert len(twins) == 2 and np.hypot(*(twins[0, :2] - twins[1, :2])) > 1e-3
    assert np.max(np.abs(constraints(model, P, q))) < 1e-12


def singular_pose(model, x=0.5, y=0.3, posture=1):
    """A pose on the type-1 singularity (det J = 0) along phi at fixed (x, y)."""
    def detj(p):
        X = np.array([x, y, p])
        return np.linalg.det(jacobians(model, X, ik(model, X, posture))[0])
    phis = np.linspace(-np.pi, np.pi, 721)
    v = np.array([detj(p) for p in phis])
    i = next(i for i in range(720) if np.isfinite(v[i] * v[i + 1]) and v[i] * v[i + 1] < 0)
    return np.array([x, y, brentq(detj, phis[i], phis[i + 1], xtol=1e-16)])


def test_two_solutions_merge_where_det_j_vanishes(model):
    """On a joint path ending on the singularity the two merging solutions both have det J -> 0."""
    Xs = singular_pose(model)
    qs = ik(model, Xs, 1)
    sol_s = dk_all(model, qs)
    assert not np.any(np.isnan(sol_s.poses[sol_s.real]))
    assert contains(sol_s, Xs, 1e-6)
    # approach from the side where the pair is real
    J, K = jacobians(model, Xs, qs)
    n = np.linalg.svd(J)[0][:, -1]                        # left null vector of J
    dq = np.linalg.solve(K, n)                            # moves F along n: splits the double root
    dq /= np.linalg.norm(dq)
    side = max((1.0, -1.0), key=lambda sg: dk_all(model, qs + sg * 1e-4 * dq).n_real)
    dets, gaps = [], []
    for eps in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        q = qs + side * eps * dq
        sol = dk_all(model, q)
        P = sol.real_poses()
        near = P[np.argsort(pose_distance(P, Xs))[:2]]
        dj = [abs(np.linalg.det(jacobians(model, p, q)[0])) for p in near]
        dets.append(max(dj))
        gaps.append(pose_distance(near[0], near[1]))
    # both decay like sqrt(eps): three decades over six decades of eps
    assert np.all(np.diff(dets) < 0) and dets[-1] < 3e-3 * dets[0]
    assert np.all(np.diff(gaps) < 0) and gaps[-1] < 3e-3 * gaps[0]


# ------------------------------------------------------------------ Jacobians
def test_jacobians_match_finite_differences(model, rng):
    X = random_poses(rng, 2000)
    j = rng.integers(1, 9, 2000)
    q = ik(model, X, j)
    X, q = X[~np.isnan(q[:, 0])][:200], q[~np.isnan(q[:, 0])][:200]
    J, K = jacobians(model, X, q)
    h = 1e-6
    for c in range(3):
        e = np.zeros(3)
        e[c] = h
        dFX = (constraints(model, X + e, q) - constraints(model, X - e, q)) / (2 * h)
        dFq = (constraints(model, X, q + e) - constraints(model, X, q - e)) / (2 * h)
        assert np.max(np.abs(dFX - J[..., c])) <= 1e-6 * np.max(np.abs(J))
        assert np.max(np.abs(dFq - K[..., c])) <= 1e-6 * np.max(np.abs(K))
    assert np.all(K[..., 0, 1] == 0) and np.all(K[..., 2, 0] == 0)


def test_velocity_model_predicts_the_motion(model):
    """J dX + K dq = 0 along a true motion: dX = -J^-1 K dq to first order."""
    X0 = np.array([0.5, 0.3, 0.2])
    X1 = X0 + np.array([1e-6, -2e-6, 3e-6])
    q0, q1 = ik(model, X0, 3), ik(model, X1, 3)
    J, K = jacobians(model, X0, q0)
    pred = X0 - np.linalg.solve(J, K @ (q1 - q0))
    assert np.max(np.abs(pred - X1)) < 1e-10


def test_singularity_measures(model):
    Xs = singular_pose(model)
    qs = ik(model, Xs, 1)
    m = singularity_measures(model, Xs, qs)
    assert m.type1 < 1e-8 and abs(m.det_J) < 1e-8
    assert m.type2 > 0.1
    # a stretched leg: type 2
    X = np.array([0.5, 0.3, 0.0])
    A0 = X[:2] + model.platform[0]
    q = np.array([np.arctan2(A0[1], A0[0]) + 0.0, 1.0, 2.0])
    d = np.hypot(*A0)
    X2 = X.copy()
    X2[:2] += (A0 / d) * (1.2 - d)                          # leg 1 fully stretched
    q2 = ik(model, X2, 1)
    assert singularity_measures(model, X2, q2).type2 < 1e-6
    far = singularity_measures(model, EXAMPLE, ik(model, EXAMPLE, 1))
    assert 0.05 < far.type1 <= 1 and 0.05 < far.type2 <= 1


# ------------------------------------------------------------------ numbering
def test_numbering_is_deterministic_and_rules_reorder_the_same_set(model, rng):
    q = ik(model, random_poses(rng, 3000), 1)
    q = q[~np.isnan(q[:, 0])]
    a, b = dk_all(model, q, rule="real-phi"), dk_all(model, q, rule="real-phi")
    np.testing.assert_array_equal(a.poses, b.poses)
    lit = dk_all(model, q, rule="literal")
    again = order_solutions(lit.poses, lit.real, "real-phi")
    np.testing.assert_array_equal(again.real, a.real)
    np.testing.assert_allclose(again.poses, a.poses, atol=1e-12)
    # real-phi: real ones first, phi ascending
    first = np.cumsum(~a.real, axis=1) == 0
    assert np.all(first == a.real)
    phi = np.where(a.real, a.poses.real[..., 2], 0.0)
    assert np.all(np.diff(phi, axis=1)[a.real[:, 1:]] > 0)
    # aspect (the default): det J >= 0 in slots 1-3, < 0 in slots 4-6, each by phi
    asp = dk_all(model, q)
    P = np.where(asp.real[..., None], asp.poses.real, 0.0)
    det = np.linalg.det(jacobians(model, P, q[:, None, :])[0])
    assert np.all((det[:, :3] >= 0) | ~asp.real[:, :3]) and np.all((det[:, 3:] < 0) | ~asp.real[:, 3:])
    assert np.all(asp.n_real == a.n_real)
    np.testing.assert_array_equal(np.sum(asp.real[:, :3], 1), np.sum(asp.real[:, 3:], 1))


def test_single_call_equals_batch_row(model, rng):
    q = ik(model, random_poses(rng, 200), 2)
    q = q[~np.isnan(q[:, 0])]
    batch = dk_all(model, q)
    for k in range(0, len(q), 17):
        one = dk_all(model, q[k])
        np.testing.assert_array_equal(one.poses, batch.poses[k])
        np.testing.assert_array_equal(one.real, batch.real[k])
    big = np.tile(q, (30, 1))                               # the parallel path
    par = dk_all(model, big)
    np.testing.assert_array_equal(par.poses[:len(q)], batch.poses)
    assert dk_all(model, q.reshape(-1, 1, 3)).poses.shape == (len(q), 1, 6, 3)


# ------------------------------------------------------------------ property-based
poses = st.tuples(st.floats(0.0, 1.0), st.floats(-0.2, 0.9), st.floats(-np.pi, np.pi))


@given(X=poses, posture=st.integers(1, 8))
def test_property_round_trip(model, X, posture):
    X = np.array(X)
    q = ik(model, X, posture)
    assume(not np.isnan(q[0]))
    assume(singularity_measures(model, X, q).type1 > 1e-6)
    sol = dk_all(model, q)
    assert contains(sol, X, 1e-9)
    assert posture_of(model, X, q) == posture


@given(X=poses, posture=st.integers(1, 8), turns=st.lists(st.integers(-3, 3), min_size=3, max_size=3))
def test_property_joint_angles_modulo_two_pi(model, X, posture, turns):
    q = ik(model, np.array(X), posture)
    assume(not np.isnan(q[0]))
    a = dk_all(model, q)
    b = dk_all(model, q + 2 * np.pi * np.array(turns))
    # the same set of poses (the numbering may differ only where phi sits on the +-pi wrap)
    assert a.n_real == b.n_real
    pa, pb = a.poses[a.real].real, b.poses[b.real].real
    if len(pa):
        d = pose_distance(pa[:, None, :], pb[None, :, :])
        assert d.min(axis=1).max() < 1e-9 and d.min(axis=0).max() < 1e-9


@given(shape=st.sampled_from([(), (2,), (4,), (3, 2), (2, 4), (0,)]))
def test_property_wrong_shapes_are_named(model, shape):
    bad = np.zeros(shape)
    for fn, arg in ((lambda v: dk_all(model, v), "q"), (lambda v: ik(model, v, 1), "X"),
                    (lambda v: jacobians(model, v, np.zeros(3)), "X")):
        with pytest.raises(SolverInputError, match=rf"{arg}: expected shape \(\.\.\., 3\), got"):
            fn(bad)


@given(pos=st.integers(0, 2), val=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_property_non_finite_input_is_refused(model, pos, val):
    q = np.array([0.1, 0.2, 0.3])
    q[pos] = val
    with pytest.raises(SolverInputError, match="q: expected finite numbers"):
        dk_all(model, q)
    with pytest.raises(SolverInputError, match="X: expected finite"):
        ik(model, q, 1)


@pytest.mark.parametrize("posture", [0, 9, -1, 1.5, "1", True, None, [1, 12]])
def test_bad_posture(model, posture):
    with pytest.raises(SolverInputError, match="posture: expected an integer in 1..8"):
        ik(model, [0.5, 0.3, 0.0], posture)


def test_other_bad_arguments(model):
    with pytest.raises(SolverInputError, match="rule: expected one of"):
        dk_all(model, [0, 0, 0], rule="alphabetical")
    with pytest.raises(SolverInputError, match="model: expected a Manipulator"):
        dk_all("paper", [0, 0, 0])
    with pytest.raises(SolverInputError, match="q: expected real numbers"):
        dk_all(model, np.array([0, 0, 1j]))
    with pytest.raises(SolverInputError, match="q: expected a numeric array"):
        dk_all(model, ["a", "b", "c"])
    with pytest.raises(SolverInputError, match="posture: expected a shape broadcastable"):
        ik(model, np.zeros((4, 3)), [1, 2])
    assert isinstance(SolverInputError("x"), ValueError)
