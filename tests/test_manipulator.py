import numpy as np
import pytest

from solver import GeometryError, Manipulator, dk_all, ik, platform_points
from conftest import pose_distance


def test_paper_geometry_follows_conventions(model):
    np.testing.assert_allclose(model.motors, [[0, 0], [1, 0], [0.5, np.sqrt(3) / 2]])
    np.testing.assert_allclose(model.l1, 0.6)
    np.testing.assert_allclose(model.l2, 0.6)
    np.testing.assert_allclose(model.platform_radius, 0.3 / np.sqrt(3))
    angles = np.rad2deg(np.arctan2(model.platform[:, 1], model.platform[:, 0])) % 360
    np.testing.assert_allclose(angles, [210, 330, 90])
    # at phi = 0 each platform side is parallel to the matching base side
    A = platform_points(model, [0.5, 0.3, 0.0])
    for i, j in ((0, 1), (1, 2), (2, 0)):
        a, m = A[j] - A[i], model.motors[j] - model.motors[i]
        assert abs(a[0] * m[1] - a[1] * m[0]) < 1e-15
        assert a @ m > 0


@pytest.mark.parametrize("kwargs, word", [
    (dict(l1=[0.6, -0.1, 0.6]), "l1"),
    (dict(l2=[0.6, 0.6, 0.0]), "l2"),
    (dict(l2=[0.6, np.nan, 0.6]), "l2"),
    (dict(motors=[[0, 0], [1, 0], [2, 0]]), "motors"),
    (dict(motors=[[0, 0], [1, 0]]), "motors"),
    (dict(platform=[[0, 0], [0.1, 0.1], [0.2, 0.2]]), "platform"),
    (dict(platform=np.zeros((3, 2))), "platform"),
    (dict(platform="abc"), "platform"),
])
def test_invalid_geometry_is_refused_with_the_argument_named(model, kwargs, word):
    base = dict(motors=model.motors, l1=model.l1, l2=model.l2, platform=model.platform)
    base.update(kwargs)
    with pytest.raises(GeometryError, match=word) as info:
        Manipulator(**base)
    assert isinstance(info.value, ValueError)


def test_model_is_frozen_and_serialisable(model):
    with pytest.raises(AttributeError):
        model.l1 = np.ones(3)
    with pytest.raises(ValueError):
        model.l1[0] = 1.0
    again = Manipulator.from_dict(model.to_dict())
    assert again == model and again.digest() == model.digest() and hash(again) == hash(model)
    other = Manipulator.symmetric(base_side=1.0, l1=0.6, l2=0.61, platform_side=0.3)
    assert other != model and other.digest() != model.digest()
    with pytest.raises(GeometryError, match="platform"):
        Manipulator.from_dict({k: v for k, v in model.to_dict().items() if k != "platform"})


def test_scalar_link_lengths_broadcast():
    m = Manipulator(motors=[[0, 0], [1, 0], [0.5, 0.8]], l1=0.5, l2=0.7,
                    platform=[[-0.1, -0.05], [0.1, -0.05], [0.0, 0.1]])
    np.testing.assert_array_equal(m.l1, [0.5, 0.5, 0.5])


def test_an_asymmetric_geometry_round_trips(rng):
    """Nothing in the kinematics assumes the paper's symmetry."""
    m = Manipulator(motors=[[0.0, 0.0], [1.2, 0.1], [0.4, 0.9]], l1=[0.55, 0.6, 0.7],
                    l2=[0.65, 0.5, 0.6], platform=[[-0.12, -0.05], [0.15, -0.08], [0.02, 0.11]],
                    name="asymmetric")
    X = np.column_stack([rng.uniform(0, 1.2, 20000), rng.uniform(-0.2, 1.0, 20000),
                         rng.uniform(-np.pi, np.pi, 20000)])
    tested = 0
    for j in range(1, 9):
        q = ik(m, X, j)
        ok = ~np.isnan(q[:, 0])
        sol = dk_all(m, q[ok])
        d = np.where(sol.real, pose_distance(sol.poses.real, X[ok][:, None, :]), np.inf)
        assert np.all(d.min(axis=1) < 1e-9)
        tested += ok.sum()
    assert tested > 10000
