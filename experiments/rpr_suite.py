"""The trajectory benchmark of the 3-RPR: its near-singular circles and its cusp loops.

* Circles that pass 20, 5 and 1 mm from a singular curve (det J = 0) without
  crossing it, found as for the 3-RRR (:func:`experiments.suite.near_singular_circle`)
  about three seed poses of the cuspidal geometry.
* Loops in joint space around cusp points (:func:`experiments.rpr_cusps.assembly_mode_change_path`):
  the legs 2 and 3 go round a circle of 2 cm about a cusp of the slice
  ``rho1 = 1.498`` m and come back to where they started, while the platform comes
  back in *another* assembly mode without meeting a singularity.  Continuity
  along the path, not the joints, decides the pose; Newton from the previous pose
  follows it only while the samples are dense enough.

Every path is a :class:`experiments.suite.SuitePath` (posture 1, the only one), so the
3-RRR's benchmark code runs it unchanged (``bench/bench_rpr.py``).
"""
from __future__ import annotations

import numpy as np

from solver.rpr import ZEIN_RHO1, RPRManipulator
from solver.trajectories import circle_path

from .rpr_cusps import assembly_mode_change_path
from .suite import CLEARANCES, SAMPLINGS, SuitePath, make_path, near_singular_circle

__all__ = ["rpr_suite", "cusp_loop_path", "RPR_SEEDS", "LOOP_CUSPS", "LOOP_SAMPLINGS"]

#: (centre m, phi deg) seeds of the near-singular circles (regular poses of the cuspidal 3-RPR).
RPR_SEEDS = (((0.8, 0.2), 0.0), ((1.0, 0.5), -60.0), ((1.2, 0.0), 90.0))
#: Cusps of the slice rho1 = 1.498 m (:func:`experiments.rpr_cusps.cusp_points` order) looped at 2 cm.
LOOP_CUSPS = (1, 2, 3, 4, 5)
#: Samples per loop.
LOOP_SAMPLINGS = (1000, 100, 30, 12, 9, 7, 6, 5)
#: Radius of the loops in (rho2, rho3), m.
LOOP_RADIUS = 0.02


def cusp_loop_path(model: RPRManipulator, cusp: int, n: int, radius: float = LOOP_RADIUS, fine=None) -> SuitePath:
    """The loop about cusp ``cusp`` sampled at ``n + 1`` points (the last at the start joints).

    The poses are the branch followed from the start by fine continuation (1441 points per loop,
    :func:`experiments.rpr_cusps.assembly_mode_change_path`), taken at the samples.  The difficulty ratio is
    that of :func:`experiments.suite.make_path`, over the steps of the open path.  ``fine``: that
    loop, if already computed.
    """
    if fine is None:
        fine = assembly_mode_change_path(model, ZEIN_RHO1, cusp=cusp, radius=radius, n=1441)
    idx = np.round(np.linspace(0, len(fine.rho) - 1, n + 1)).astype(int)
    return make_path(model, f"rpr-cusp{cusp}-loop/{n}", 1, fine.poses[idx], q=fine.rho[idx], closed=False)


def rpr_suite(model: RPRManipulator | None = None, samplings=SAMPLINGS,
              loop_samplings=LOOP_SAMPLINGS) -> list[SuitePath]:
    """The 3-RPR suite: near-singular circles at every sampling, then the cusp loops."""
    model = RPRManipulator.zein_wenger_chablat() if model is None else model
    paths = []
    for centre, phd in RPR_SEEDS:
        for clearance in CLEARANCES:
            radius, _ = near_singular_circle(model, 1, centre, phd, clearance)
            for n in samplings:
                X = circle_path(n, centre, radius, np.deg2rad(phd))
                name = f"rpr-{centre[0]:g},{centre[1]:g},{phd:g}deg-near-sing-{clearance * 1e3:g}mm/{n}"
                paths.append(make_path(model, name, 1, X))
    for cusp in LOOP_CUSPS:
        fine = assembly_mode_change_path(model, ZEIN_RHO1, cusp=cusp, radius=LOOP_RADIUS, n=1441)
        for n in loop_samplings:
            paths.append(cusp_loop_path(model, cusp, n, fine=fine))
    return paths
