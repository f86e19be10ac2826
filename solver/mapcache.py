"""The one cache of map tensors, shared by every command (``python -m solver build``,
``build_fmu.py``, the benchmarks, the figures).

A map is keyed by geometry, posture, ordering rule, node spacing and the code that
labels it; its file is ``<cache_dir>/<map_name(...)>``::

    map_posture<j>_<rule>_<x step>mm_<phi step>deg_<geometry>_<code>.npz

``<geometry>`` is the first 8 hex digits of :meth:`Manipulator.digest`, ``<code>`` those of
:func:`labelling_digest` (the sources that decide the labels), so a map made for another
geometry or by other code is never reused; numbers are written with ``p`` for the decimal
point (``2p5mm``), and a y step other than the x step as ``<x>x<y>mm``.  The grid is
:func:`solver.grid.default_grid` at that spacing.
"""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numpy as np

from .grid import DEFAULT_STEP, default_grid
from .manipulator import Manipulator
from .mapfile import MapTensorFileError
from .maptensor import MapTensor
from .ordering import DEFAULT_RULE

__all__ = ["DEFAULT_CACHE_DIR", "LABELLING_SOURCES", "labelling_digest", "map_name", "map_path", "cached_map"]

#: Where the commands keep their maps unless told otherwise (relative to the working folder).
DEFAULT_CACHE_DIR = Path("build") / "maps"
#: The solver sources that decide a map's labels (geometry, IK, DK and its numbering, procedure 1).
LABELLING_SOURCES = ("checks.py", "manipulator.py", "kinematics.py", "direct_kinematics.py", "ordering.py",
                     "grid.py", "maptensor.py", "_kernels/layout.py", "_kernels/linalg.py",
                     "_kernels/kinematics.py", "_kernels/direct_kinematics.py", "_kernels/ordering.py")


@functools.cache
def labelling_digest() -> str:
    """SHA-256 (hex) of :data:`LABELLING_SOURCES`: a cached map built by other code is not reused."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in LABELLING_SOURCES:
        h.update(name.encode() + b"\0" + (root / name).read_bytes())
    return h.hexdigest()


def _number(v: float) -> str:
    return f"{v:.6g}".replace(".", "p")


def map_name(model: Manipulator, posture: int, rule: str = DEFAULT_RULE, step=DEFAULT_STEP) -> str:
    """The cache file name of a map (see the module docstring)."""
    mm_x, mm_y, deg = step[0] * 1e3, step[1] * 1e3, float(np.rad2deg(step[2]))
    xy = _number(mm_x) if mm_x == mm_y else f"{_number(mm_x)}x{_number(mm_y)}"
    return (f"map_posture{int(posture)}_{rule}_{xy}mm_{_number(deg)}deg_"
            f"{model.digest()[:8]}_{labelling_digest()[:8]}.npz")


def map_path(model: Manipulator, posture: int, rule: str = DEFAULT_RULE, step=DEFAULT_STEP,
             cache_dir=DEFAULT_CACHE_DIR) -> Path:
    """The cache file of a map: ``cache_dir / map_name(...)``."""
    return Path(cache_dir) / map_name(model, posture, rule, step)


def cached_map(model: Manipulator, posture: int, rule: str = DEFAULT_RULE, step=DEFAULT_STEP,
               cache_dir=DEFAULT_CACHE_DIR, *, progress: bool = False, log=None) -> MapTensor:
    """The map tensor of ``posture`` at node spacing ``step`` (m, m, rad): from the cache if its file
    checks out and holds the requested grid, else built (procedure 1) and saved there.

    Parameters
    ----------
    model : Manipulator
    posture : int
        Posture 1..8.
    rule : str
        Ordering rule.
    step : (float, float, float)
        Node spacing, m, m, rad.
    cache_dir : str or Path
        The cache folder (created if missing).
    progress : bool
        Print a build progress line to stderr.
    log : callable, optional
        Called with one line saying whether the map was reused or built (file, nodes, size),
        preceded by the reason when a cached file is rebuilt.
    """
    say = log if log is not None else (lambda text: None)
    path = map_path(model, posture, rule, step, cache_dir)
    bounds, shape = default_grid(model, step)
    mt, built = None, False
    if path.is_file():
        try:
            mt = MapTensor.load(path, model=model, posture=posture)
            if not (mt.rule == rule and tuple(mt.shape) == shape
                    and np.allclose(mt.bounds, bounds, rtol=0, atol=1e-12)):
                say(f"{path}: cached map does not match the requested grid; rebuilding")
                mt = None
        except MapTensorFileError as exc:
            say(f"{path}: unusable cached map ({exc}); rebuilding")
    if mt is None:
        mt = MapTensor.build(model, posture, bounds=bounds, shape=shape, rule=rule, progress=progress)
        mt.save(path)
        built = True
    say(f"map posture {int(posture)}: {'built' if built else 'reused'} {path} "
        f"({mt.shape[0]} x {mt.shape[1]} x {mt.shape[2]} nodes, {path.stat().st_size / 1e3:.0f} kB)")
    return mt
