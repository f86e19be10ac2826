"""The robot as built (solver.geometry_tolerance, Tracker(geometry_tolerance=...)): certain and pose_bound
hold for every robot within the geometric tolerance, not for the model alone."""
from __future__ import annotations

import numpy as np
import pytest

from solver import Manipulator, Tracker, TrackerError, cached_map, dk_all, ik
from solver._kernels import layout as _lay
from solver._kernels.exclusion import leg_misses
from solver._kernels.krawczyk import W_SIZE, W_TOT, krawczyk
from solver.geometry_tolerance import built_robot, elbow_margin, geometry_tolerance, joint_equivalent
from solver.robot import ROBOTS, load_robot
from solver.rpr import RPR_HOME_POSE, RPR_WORK_BOUNDS, RPRManipulator

PAPER = Manipulator.paper()
IRREGULAR = load_robot(ROBOTS / "irregular-3rrr.toml").model
TOL = 5e-5


def ellipse(n=300, centre=(0.5, 0.2887), a=0.1, b=0.08, phi=0.2):
    t = np.linspace(0, 2 * np.pi, n)
    return np.stack([centre[0] + a * np.cos(t), centre[1] + b * np.sin(t), phi * np.sin(2 * t)], -1)


def track(tracker, X, q):
    start = tracker.reset(X[0], q[0])
    out = [(X[0], start.certain, start.pose_bound)]
    for k in range(1, len(q)):
        Xk, info = tracker.step(q[k])
        out.append((Xk, info.certain, info.pose_bound))
    return out


def silent(out, X_true):
    """Certain steps whose pose box misses the true pose (x, y, wrapped phi)."""
    bad = 0
    for (X, certain, bound), Xt in zip(out, X_true):
        d = np.abs(X - Xt)
        d[2] = abs(np.angle(np.exp(1j * (X[2] - Xt[2]))))
        bad += bool(certain and np.any(d > bound))
    return bad


@pytest.mark.parametrize("model", [PAPER, IRREGULAR], ids=["paper", "irregular"])
def test_the_model_reaches_every_as_built_pose_within_the_joint_width(model):
    """The reduction itself: for robots drawn inside the tolerance (uniform and corners) and poses in a box,
    the model's inverse kinematics of the built robot's pose (same posture) lies within
    joint_equivalent of the built robot's joints."""
    rng = np.random.default_rng(7)
    tol = geometry_tolerance(model, 2e-4)
    X0 = np.array(load_robot(ROBOTS / ("paper-3rrr.toml" if model is PAPER else "irregular-3rrr.toml")).home_pose)
    half = np.array([0.02, 0.02, 0.05])
    for trial in range(20):
        built = built_robot(model, 2e-4, rng, corner=trial % 2 == 1)
        X = X0 + rng.uniform(-1, 1, (200, 3)) * half
        for posture in (1, 2):
            q_built = ik(built, X, posture)
            q_model = ik(model, X, posture)
            ok = np.all(np.isfinite(q_built), axis=1)
            eps = joint_equivalent(model, tol, X0 - half, X0 + half, np.nanmin(q_built[ok], 0), np.nanmax(q_built[ok], 0))
            gap = np.abs(np.angle(np.exp(1j * (q_model[ok] - q_built[ok]))))
            assert np.isfinite(eps) and np.all(gap <= eps), (trial, posture, gap.max(), eps)
            k = int(np.argmax(ok))                 # over one pose's box the width is not wildly loose
            tight = joint_equivalent(model, tol, X[k], X[k], q_built[k], q_built[k])
            assert gap[0].max() <= tight and (trial % 2 == 0 or gap[0].max() > 0.05 * tight)


def test_the_width_is_infinite_at_a_straight_elbow_and_exact_for_the_3rpr():
    tol = geometry_tolerance(PAPER, TOL)
    m = PAPER
    direction = np.array([0.6, 0.8])           # leg 1 stretched: platform joint at full reach
    joint = m.motors[0] + direction * (m.l1[0] + m.l2[0])
    X = np.array([*(joint - m.platform[0]), 0.0])
    assert elbow_margin(m, X, X, [np.arctan2(0.8, 0.6)] * 3, [np.arctan2(0.8, 0.6)] * 3)[0] == 0.0
    assert joint_equivalent(m, tol, X, X, [np.arctan2(0.8, 0.6), 0, 0], [np.arctan2(0.8, 0.6), 0, 0]) == np.inf
    rpr = RPRManipulator.zein_wenger_chablat()
    t = geometry_tolerance(rpr, 1e-4)
    X = np.asarray(RPR_HOME_POSE)
    assert joint_equivalent(rpr, t, X, X, [1, 1, 1], [1, 1, 1]) == pytest.approx(2 * np.sqrt(2) * 1e-4)


def legs(model, tol=None):
    """The kernels' leg arguments: M, l1, the legs (l2^2 and, for a tolerance, the offset bounds), b."""
    M, l1, l2sq = model.circle_legs()
    if tol is not None:
        l2sq = np.concatenate([l2sq, geometry_tolerance(model, tol).offset_bound()])
    return M, l1, l2sq, np.array(model.platform)


def model_residual(model, X, q):
    """The model's constraints F_i = |B_i(X) - D_i(q_i)|^2 - l2_i^2 (N, 3) at poses X and joints q (N, 3)."""
    c, s = np.cos(X[:, 2]), np.sin(X[:, 2])
    out = np.empty((len(X), 3))
    for i in range(3):
        bx, by = model.platform[i]
        B = np.stack([X[:, 0] + c * bx - s * by, X[:, 1] + s * bx + c * by], -1)
        D = model.motors[i] + model.l1[i] * np.stack([np.cos(q[:, i]), np.sin(q[:, i])], -1)
        out[:, i] = np.sum((B - D) ** 2, -1) - model.l2[i] ** 2
    return out


@pytest.mark.parametrize("model", [PAPER, IRREGULAR], ids=["paper", "irregular"])
def test_the_model_constraints_close_within_the_slack_at_every_as_built_pose(model):
    """The slack the tracker carries (solver.as_built): at a built robot's pose and joints the model's
    constraints lie within sigma_i = e_i (2 l2_i + e_i), and robots at the corners come close to it."""
    rng = np.random.default_rng(17)
    tol = geometry_tolerance(model, 2e-4)
    e = tol.offset_bound()
    sigma = e * (2.0 * model.l2 + e)
    X0 = np.array(load_robot(ROBOTS / ("paper-3rrr.toml" if model is PAPER else "irregular-3rrr.toml")).home_pose)
    worst = np.zeros(3)
    for trial in range(20):
        built = built_robot(model, 2e-4, rng, corner=trial % 2 == 1)
        X = X0 + rng.uniform(-1, 1, (300, 3)) * np.array([0.05, 0.05, 0.3])
        for posture in (1, 4, 8):
            q = ik(built, X, posture)
            ok = np.all(np.isfinite(q), axis=1)
            F = np.abs(model_residual(model, X[ok], q[ok]))
            assert np.all(F <= sigma), (trial, posture, (F / sigma).max())
            worst = np.maximum(worst, F.max(0))
    assert np.all(worst > 0.25 * sigma), worst / sigma


def test_leg_exclusion_holds_where_the_elbow_cosine_is_least():
    """A leg with l1 > l2 (the example robot's first): over radii about sqrt(l1^2 - l2^2) the elbow's cosine
    is least inside the range, not at its ends; a pose box there still reaches the joints its poses have."""
    M, l1, l2sq, b = legs(IRREGULAR)
    rs = np.sqrt(l1[0] ** 2 - l2sq[0])
    assert rs > 0.1
    x = M[0, 0] + rs - b[0, 0]                       # B_0 on the x-axis from M_0 at the least cosine's radius
    y = M[0, 1] - b[0, 1]
    box = np.array([x - 0.01, x + 0.01, y - 1e-7, y + 1e-7, 0.0, 0.0])
    for sign, posture in ((1.0, 1), (-1.0, 2)):
        q = ik(IRREGULAR, np.array([[x, y, 0.0]]), posture)[0, 0]
        if not np.isfinite(q):
            q = ik(IRREGULAR, np.array([[x, y, 0.0]]), 3 - posture)[0, 0]
        assert np.isfinite(q)
        assert not leg_misses(box, 0, sign, q, q, M, l1, l2sq, b), (sign, q)


@pytest.mark.parametrize("model", [PAPER, IRREGULAR], ids=["paper", "irregular"])
def test_leg_exclusion_never_drops_an_as_built_pose(model):
    """The exclusion's leg test with the slack: for robots at the corners of a 2e-4 m box, each pose's box
    reaches the built robot's joints in the built robot's posture, including near straight elbows, where
    the model's elbow at those joints may be the other one (asin(e / rho) in the test)."""
    rng = np.random.default_rng(23)
    M, l1, l2sq, b = legs(model, 2e-4)
    flipped = 0
    for trial in range(10):
        built = built_robot(model, 2e-4, rng, corner=True)
        i = trial % 3
        for posture in (1, 2, 5, 8):
            sign = 1.0 - 2.0 * (((posture - 1) >> i) & 1)
            # poses whose built leg i is nearly straight (its platform joint a micrometre or less from full
            # reach: the elbow within about 1e-3 rad of straight) and others (up to 2 cm from it)
            d = np.concatenate([rng.uniform(0, 1e-6, 40), rng.uniform(0, 2e-2, 20)])
            a = rng.uniform(0, 2 * np.pi, 60)
            far = built.motors[i] + (built.l1[i] + built.l2[i] - d)[:, None] * np.stack([np.cos(a), np.sin(a)], -1)
            phi = rng.uniform(-0.5, 0.5, 60)
            c, s = np.cos(phi), np.sin(phi)
            bx, by = built.platform[i]
            X = np.stack([far[:, 0] - (c * bx - s * by), far[:, 1] - (s * bx + c * by), phi], -1)
            bx, by = model.platform[i]
            q = ik(built, X, posture)
            for k in np.flatnonzero(np.isfinite(q[:, i])):
                half = rng.uniform(1e-6, 1e-3)
                box = np.array([X[k, 0] - half, X[k, 0] + half, X[k, 1] - half, X[k, 1] + half,
                                X[k, 2] - 1e-3, X[k, 2] + 1e-3])
                assert not leg_misses(box, i, sign, q[k, i], q[k, i], M, l1, l2sq, b), (trial, posture, k)
                D = model.motors[i] + model.l1[i] * np.array([np.cos(q[k, i]), np.sin(q[k, i])])
                B = X[k, :2] + np.array([c[k] * bx - s[k] * by, s[k] * bx + c[k] * by])
                u = D - model.motors[i]
                flipped += np.sign(u[0] * (B - M[i])[1] - u[1] * (B - M[i])[0]) != sign
    assert flipped > 0                              # the test reached the model's other elbow


def test_krawczyk_with_the_slack_holds_the_as_built_pose():
    """Krawczyk's test over a joint box with the slack: its proven box holds the pose of robots at the
    corners of the tolerance whose joints lie in the box; without the slack it does not always."""
    rng = np.random.default_rng(29)
    X0 = np.array([0.5, 0.2887, 0.1])
    M, l1, l2sq6, b = legs(PAPER, TOL)
    eps = np.full(3, 1e-5)
    rho = np.full(3, 2e-3)
    q0 = ik(PAPER, X0[None], 1)[0]
    w = np.empty(W_SIZE)
    none = np.zeros(3)
    assert krawczyk(X0, rho, q0, none, none, 0.0, 0.0, eps, M, l1, b, l2sq6, w)
    with_slack = w[W_TOT:W_TOT + 3].copy()
    assert krawczyk(X0, rho, q0, none, none, 0.0, 0.0, eps, M, l1, b, l2sq6[:3], w)
    without = w[W_TOT:W_TOT + 3].copy()
    outside = 0
    for _ in range(40):
        built = built_robot(PAPER, TOL, rng, corner=True)
        sols = dk_all(built, q0)                       # the built robot's pose at the joints q0
        Xb = np.array([p.real for p, r in zip(sols.poses, sols.real) if r])
        Xb = Xb[np.argmin(np.abs(Xb - X0).sum(1))]
        d = np.abs(Xb - X0)
        assert np.all(d <= with_slack), (d, with_slack)
        outside += bool(np.any(d > without))
    assert outside > 0


def test_a_zero_tolerance_changes_nothing_bit_for_bit():
    mt = cached_map(PAPER, 1)
    X = ellipse(120)
    q = ik(PAPER, X, 1)
    rng = np.random.default_rng(3)
    for jt, qq in ((0.0, q), (1e-4, q + 3e-5 * rng.standard_normal(q.shape))):
        a = track(Tracker(PAPER, mt, joint_tolerance=jt), X, qq)
        b = track(Tracker(PAPER, mt, joint_tolerance=jt, geometry_tolerance=0.0), X, qq)
        c = track(Tracker(PAPER, mt, joint_tolerance=jt, geometry_tolerance={"length": 0.0}), X, qq)
        for (x1, c1, b1), (x2, c2, b2), (x3, c3, b3) in zip(a, b, c):
            assert np.array_equal(x1, x2) and np.array_equal(x1, x3) and c1 == c2 == c3
            assert np.array_equal(b1, b2) and np.array_equal(b1, b3)


def test_a_robot_at_the_corners_is_never_silently_wrong_where_the_model_alone_is():
    """The ellipse read exactly from robots at corners of a 5e-5 m box: the tracker without the tolerance
    vouches for a pose box that misses the built robot's pose (a silent error); with it, none does and
    the tracker stays certain."""
    mt = cached_map(PAPER, 1)
    X = ellipse(300)
    rng = np.random.default_rng(11)
    nominal_silent = 0
    for trial in range(3):
        built = built_robot(PAPER, TOL, rng, corner=True)
        q = ik(built, X, 1)
        without = track(Tracker(PAPER, mt, joint_tolerance=1e-4), X, q)
        nominal_silent += silent(without, X)
        out = track(Tracker(PAPER, mt, joint_tolerance=1e-4, geometry_tolerance=TOL), X, q)
        assert silent(out, X) == 0
        assert sum(c for _, c, _ in out) >= 0.95 * len(out)
    assert nominal_silent > 0


@pytest.mark.parametrize("value, expected", [
    (-1e-5, "geometry_tolerance: expected a half-width in m, a finite number >= 0, got -1e-05"),
    (float("nan"), "finite number >= 0"),
    (0.07, "at most a tenth of the shortest link, 0.06 m"),
    ({"length": 1e-5, "l3": 1e-5}, "unknown field(s) ['l3']"),
    ({"l1": -1.0}, "geometry_tolerance.l1"),
    ("5e-5", "got '5e-5'"),
])
def test_bad_tolerances_are_refused_by_name(value, expected):
    with pytest.raises(TrackerError, match="geometry_tolerance") as info:
        Tracker(PAPER, cached_map(PAPER, 1), geometry_tolerance=value)
    assert expected in str(info.value) and isinstance(info.value, ValueError)


def test_the_robot_description_carries_its_tolerance():
    import tomllib
    from solver.robot import robot_from_dict
    data = tomllib.loads((ROBOTS / "irregular-3rrr.toml").read_text())
    data["tolerance"] = {"length": 5e-5, "l1": 1e-4}
    robot = robot_from_dict(data)
    assert dict(robot.tolerance.widths) == {"motors": 5e-5, "l1": 1e-4, "l2": 5e-5, "platform": 5e-5}
    tracker = Tracker(robot.model, cached_map(robot.model, robot.home_posture, step=(0.04, 0.04, np.deg2rad(6))),
                      geometry_tolerance=robot.tolerance)
    assert tracker.geometry_tolerance == robot.tolerance



def test_a_3rpr_as_built_is_tracked_with_its_exact_joint_width():
    """The 3-RPR carries its tolerance as the joint width e (solver.as_built.joint_width): the cusp loop read
    exactly from robots at the corners of a 1e-5 m box is never silently wrong with the tolerance, and
    the model alone is."""
    from experiments.rpr_suite import cusp_loop_path
    from solver import MapTensor
    rpr = RPRManipulator.zein_wenger_chablat()
    mt = MapTensor.build(rpr, 1, bounds=RPR_WORK_BOUNDS, shape=(46, 41, 60))
    path = cusp_loop_path(rpr, 1, 60)
    rng = np.random.default_rng(31)
    nominal_silent = 0
    for _ in range(3):
        built = built_robot(rpr, 1e-5, rng, corner=True)
        q = ik(built, path.X)
        nominal_silent += silent(track(Tracker(rpr, mt, joint_tolerance=1e-6), path.X, q), path.X)
        tracker = Tracker(rpr, mt, joint_tolerance=1e-6, geometry_tolerance=1e-5)
        assert tracker._params[_lay.PARAM_JOINT_TOL] == pytest.approx(1e-6 + 2 * np.sqrt(2) * 1e-5)
        out = track(tracker, path.X, q)
        assert silent(out, path.X) == 0
        assert sum(c for _, c, _ in out) >= 0.5 * len(out)
    assert nominal_silent > 0


def test_the_tool_space_reacquisition_searches_holds_every_built_robots(model):
    """The box re-acquisition searches (the reach of legs e_i longer, solver.as_built.reach_model) holds the
    whole tool space of every robot built within the tolerance: corners of the tolerance box, 0.5 mm."""
    from solver import default_bounds
    from solver.as_built import reach_model
    from solver.geometry_tolerance import built_robot, geometry_tolerance

    tol = geometry_tolerance(model, 5e-4)
    searched = default_bounds(reach_model(model, tol), step=(1e-4, 1e-4, 1e-4))
    assert np.all(searched[:2, 0] < default_bounds(model, step=(1e-4, 1e-4, 1e-4))[:2, 0])
    rng = np.random.default_rng(45)
    for _ in range(12):
        built = default_bounds(built_robot(model, 5e-4, rng, corner=True), step=(1e-4, 1e-4, 1e-4))
        assert np.all(built[:2, 0] >= searched[:2, 0]) and np.all(built[:2, 1] <= searched[:2, 1])
    assert reach_model(model, geometry_tolerance(model, 0.0)) is model
