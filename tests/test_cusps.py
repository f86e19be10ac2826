"""The cusp finder (solver.cusps): cusps of the type-2 singular surface in a sampled tool space."""
from __future__ import annotations

import numpy as np
import pytest

from experiments.rpr_cusps import cusp_points
from solver import Manipulator, SolverInputError, default_bounds, jacobians, ik
from solver.cusps import coinciding_modes, find_cusps
from solver.grid import grid_shape
from solver.rpr import RPR_HOME_POSE, ZEIN_RHO1, RPRManipulator

RPR = RPRManipulator.zein_wenger_chablat()


def _det(model, X, posture):
    return np.linalg.det(jacobians(model, X, ik(model, X, posture))[0])


def test_three_dk_solutions_meet_at_the_known_cusps_of_the_3rpr_and_one_at_a_regular_pose():
    cusps = cusp_points(RPR, ZEIN_RHO1)
    counts = coinciding_modes(RPR, 1, cusps.poses, 1e-3)
    assert np.sum(counts == 3) >= 5 and set(counts.tolist()) <= {0, 3}
    assert coinciding_modes(RPR, 1, [RPR_HOME_POSE], 1e-3).tolist() == [1]


def test_the_finder_finds_a_known_cusp_of_the_3rpr_and_each_point_it_returns_is_a_cusp():
    """A 0.3 m box about cusp 1 of the slice: found; every returned pose is singular (det J = 0 to 1e-9
    of the box's typical det J) and three DK solutions meet there."""
    c = cusp_points(RPR, ZEIN_RHO1).poses[1]
    bounds = np.array([[c[0] - 0.15, c[0] + 0.15], [c[1] - 0.15, c[1] + 0.15], [c[2] - 0.15, c[2] + 0.15]])
    scan = find_cusps(RPR, 1, bounds, (16, 16, 16))
    assert scan.count >= 1 and scan.singular_points > scan.count
    typical = np.median(np.abs(_det(RPR, np.array(np.meshgrid(*[np.linspace(*b, 5) for b in bounds])).reshape(3, -1).T, 1)))
    assert np.all(np.abs(_det(RPR, scan.poses, 1)) < 1e-9 * typical)
    assert np.all(coinciding_modes(RPR, 1, scan.poses, 1e-3) == 3)


def test_the_paper_3rrr_has_cusp_curves_and_each_reported_point_is_one():
    """The paper's robot is non-cuspidal in the paper's sense (its RR legs), yet its singular surface has
    cusp curves: the finder reports them, each confirmed by three coinciding DK solutions; without the
    confirmation it flags at least as many cells."""
    model = Manipulator.paper()
    step = (0.04, 0.04, np.deg2rad(6.0))
    bounds = default_bounds(model, step)
    shape = grid_shape(bounds, step)
    scan = find_cusps(model, 1, bounds, shape)
    raw = find_cusps(model, 1, bounds, shape, confirm=False)
    assert 0 < scan.count <= raw.count and scan.cells == (shape[0] - 1) * (shape[1] - 1) * shape[2]
    assert np.all(coinciding_modes(model, 1, scan.poses, 1e-3) >= 3)
    assert np.all(np.isfinite(ik(model, scan.poses, 1)))


def test_a_regular_region_has_no_cusp():
    """A small box about the paper's home pose, far from singularities: no singular point, no cusp."""
    X = np.array([0.5, 0.2887, 0.0])
    bounds = np.stack([X - 0.02, X + 0.02], axis=1)
    scan = find_cusps(Manipulator.paper(), 1, bounds, (6, 6, 6))
    assert scan.count == 0 and scan.singular_points == 0


@pytest.mark.parametrize("bounds, shape, name", [
    (np.zeros((2, 2)), (4, 4, 4), "bounds"),
    ([[0, 1], [0, 1], [1, 0]], (4, 4, 4), "bounds"),
    ([[0, 1], [0, 1], [0, 1]], (4, 1, 4), "shape"),
])
def test_bad_grids_are_refused_by_name(bounds, shape, name):
    with pytest.raises(SolverInputError, match=name):
        find_cusps(Manipulator.paper(), 1, bounds, shape)
