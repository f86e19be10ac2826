"""What a build says about the maps it embeds: their border volume and the cusps of their tool space.

The paper's procedure 1 needs a grid fine enough for the basic regions; the tracker works harder where
procedure 2 finds more than one label. A build therefore reports, per embedded map:

* its **border volume** (:meth:`solver.MapTensor.border_fraction`: the share of reachable nodes near a
  label border), warned above :data:`COARSE_BORDER` (a finer ``--resolution`` helps);
* the **cusps** its tool space holds (:func:`solver.cusps.map_cusps`: grid cells crossed by a cusp curve
  of the type-2 singular surface, each confirmed by three coinciding DK solutions), warned when there
  are any: three assembly modes meet there, and a path around one changes assembly mode without meeting
  a singularity (the paper assumes none; the tracker's certificates do not).
"""
from __future__ import annotations

from solver import MapTensor
from solver.cusps import map_cusps

__all__ = ["COARSE_BORDER", "report_maps"]

#: The border volume (share of a map's reachable nodes near a label border, where procedure 2 finds more
#: than one label) above which a build warns that its map is too coarse for the robot: the paper's robot
#: at 10 mm / 2 deg has 29 % (posture 1), at 40 mm / 6 deg 76 %.
COARSE_BORDER = 0.5


def report_maps(maps: dict, log) -> None:
    """Say each embedded map's border volume and cusps (``maps``: posture -> map file; ``log``: one
    line per call); warn when a map is coarser than :data:`COARSE_BORDER` allows or its tool space holds
    cusps."""
    cusps = {}
    for posture in sorted(maps):
        mt = MapTensor.load(maps[posture])
        share = mt.border_fraction()
        scan = map_cusps(mt)
        cusps[posture] = scan
        log(f"map posture {posture}: border volume {100 * share:.0f} % of the reachable nodes "
            f"({mt.model.name}; the paper's robot at 10 mm / 2 deg: 29 %); {scan.count} cusp cells "
            f"of {scan.cells} ({scan.singular_points} points of the singular surface sampled)")
        if share > COARSE_BORDER:
            log(f"warning: map posture {posture} is coarse for {mt.model.name!r}: {100 * share:.0f} % of its reachable "
                f"nodes lie near a label border (more than {100 * COARSE_BORDER:.0f} %); the tracker works harder "
                "near borders: a finer --resolution makes its regions wider than its cells")
    held = {p: s for p, s in cusps.items() if s.count}
    if held:
        p, first = next(iter(held.items()))
        x, y, phi = first.poses[0]
        counts = ", ".join(f"posture {p}: {s.count}" for p, s in held.items())
        log(f"warning: the sampled workspace holds cusps of the singular surface ({counts} cells; the first "
            f"at x = {x:.4f} m, y = {y:.4f} m, phi = {phi:.4f} rad in posture {p}): three assembly modes meet "
            "there and a path around one changes assembly mode without a singularity (docs/robots.md, "
            "'Cusps'); the tracker does not assume their absence")
