"""The honest start, compiled: the DK solution nearest an approximate initial pose, proved the only
one the robot can be in.

The caller knows the robot's pose only roughly: within ``r0`` (3,) of ``X0``, the *start region*
``R = X0 +- r0``, at joints within ``tol`` of the reading ``q0``.  :func:`certify_start` proves, for
the DK solution ``Xs`` of ``q0`` in ``R``:

1. the tube of the joint box ``Q0 = q0 +- tol`` about ``Xs`` (:func:`.tube.tube_test`): one solution
   per joint vector, within the pose bound;
2. a Krawczyk box ``B`` about ``Xs`` (:func:`.krawczyk.krawczyk`) holds exactly one solution for
   every joint vector of ``Q0``, and the tube's solutions lie in it;
3. ``B`` holds ``R``, or else every pose of ``R`` whose inverse kinematics in any of the eight
   postures lands in ``Q0`` lies in ``B`` (:func:`.exclusion.posture_preimage_in`).

Where no Krawczyk box holds the needle's hull (an ill-conditioned start), the joint box is split and
fat tubes hold the sub-needles' hulls instead (:func:`.exclusion.tube_exclusion`).

So the robot's pose, in ``R`` at joints in ``Q0``, is the tube's solution: the tracker starts
certain, with the tube as its first.
"""
from __future__ import annotations

from numba import njit

from .reacquisition import hull_inside
from .exclusion import EXCLUSION_COVERS, posture_preimage_in, tube_exclusion
from .kinematics import geometry
from .krawczyk import W_SIZE, krawczyk
from .linalg import wrap
from .scratch import floats
from .tube import TUBE_K, TUBE_X, spread, tube_test

#: Codes of :func:`certify_start`.
START_PROVED, START_NO_TUBE, START_NOT_UNIQUE = 0, 1, 2


@njit(cache=True)
def certify_start(X0, r0, Xs, q0, tol, max_boxes, model_pack, tubes):
    """The proof of the module docstring for the solution ``Xs`` (3,) of the joints ``q0`` (3,) (rad, read
    within ``tol``), the robot within ``r0`` (3,) of ``X0`` (3,) (m, m, rad).  Writes the cover of
    tubes (MAX_COVER, TUBE_SIZE) and returns (START_PROVED, START_NO_TUBE: no tube about ``Xs``, a
    singularity within the joint box, or START_NOT_UNIQUE: another pose of the start region may
    reach the joints; the number of tubes)."""
    M, l1, l2sq, b = geometry(model_pack)
    t = floats(3)
    t[:] = tol
    region = floats(6)
    for r in range(3):
        region[2 * r], region[2 * r + 1] = X0[r] - r0[r], X0[r] + r0[r]
    none = floats(3)
    none[:] = 0.0
    whole = tube_test(Xs, q0, t, none, M, l1, l2sq, b, tubes[0])
    w = floats(W_SIZE)
    box = floats(6)
    rho = floats(3)
    if whole:                                             # one Krawczyk box holds R and the needle
        c = tubes[0, TUBE_X:TUBE_X + 3].copy()
        for r in range(3):
            d = c[r] - X0[r]
            if r == 2:
                d = wrap(d)
            hull = tubes[0, TUBE_K + r] + spread(tubes[0], r, tol)
            rho[r] = max(abs(d) + r0[r], 2.0 * hull) * (1.0 + 1e-6) + 1e-12
        if krawczyk(c, rho, q0, none, none, 0.0, 0.0, t, M, l1, b, l2sq, w):
            box[:3], box[3:] = c, rho
            if hull_inside(tubes[0], tol, box):
                return START_PROVED, 1
    for attempt in range(1, len(EXCLUSION_COVERS) + 1):   # the needles' hulls, by parts of the joint box
        n = tube_exclusion(Xs, q0, tol, 0, 8, region, max_boxes, attempt, M, l1, l2sq, b, tubes)
        if n > 0:
            return START_PROVED, n
    if not (whole and tube_test(Xs, q0, t, none, M, l1, l2sq, b, tubes[0])):
        return START_NO_TUBE, 0
    c = tubes[0, TUBE_X:TUBE_X + 3].copy()
    for _ in range(40):                                   # the largest box about Xs that Krawczyk proves
        for r in range(3):
            rho[r] *= 0.5
        if krawczyk(c, rho, q0, none, none, 0.0, 0.0, t, M, l1, b, l2sq, w):
            break
    else:
        return START_NOT_UNIQUE, 0
    box[:3], box[3:] = c, rho
    if not hull_inside(tubes[0], tol, box):
        return START_NOT_UNIQUE, 0
    for posture_bits in range(8):
        if posture_preimage_in(c, rho, q0, tol, posture_bits, region, M, l1, l2sq, b, max_boxes) <= 0:
            return START_NOT_UNIQUE, 0
    return START_PROVED, 1
