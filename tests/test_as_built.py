"""The robot as built (solver.geometry_tolerance, Tracker(geometry_tolerance=...)): certain and pose_bound
hold for every robot within the geometric tolerance, not for the model alone."""
from __future__ import annotations

import numpy as np
import pytest

from solver import Manipulator, Tracker, TrackerError, cached_map, ik
from solver.geometry_tolerance import elbow_margin, geometry_tolerance, joint_equivalent
from solver.robot import ROBOTS, load_robot
from solver.rpr import RPR_HOME_POSE, RPRManipulator

PAPER = Manipulator.paper()
IRREGULAR = load_robot(ROBOTS / "irregular-3rrr.toml").model
TOL = 5e-5


def as_built(model, tol, rng, corner=False):
    """A robot drawn inside the tolerance box of ``model``: uniform, or at one of the box's corners."""
    d = model.to_dict()
    for key in ("motors", "platform", "l1", "l2"):
        a = np.asarray(d[key], float)
        d[key] = (a + tol * (rng.choice([-1.0, 1.0], a.shape) if corner else rng.uniform(-1, 1, a.shape))).tolist()
    d["name"] = model.name + "-as-built"
    return Manipulator.from_dict(d)


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
        built = as_built(model, 2e-4, rng, corner=trial % 2 == 1)
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
        built = as_built(PAPER, TOL, rng, corner=True)
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

