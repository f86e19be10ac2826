"""The one cache of map tensors, shared by every command (``python -m solver build``,
``build_fmu.py``, the benchmarks, the figures).

The cache folder is ``solver.cache_dir("maps")``: ``$RRR_DK_CACHE/maps`` if that variable is
set, else ``$XDG_CACHE_HOME/rrr-dk/maps``, else ``~/.cache/rrr-dk/maps``, wherever the
command runs (:mod:`solver.cache`); a ``cache_dir`` argument puts it elsewhere.  Every
build says where it writes.

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

from . import progress as _progress
from .cache import cache_dir as _cache_root
from .direct_kinematics import dk_all
from .grid import DEFAULT_STEP, default_grid
from .kinematics import ik
from .manipulator import Manipulator
from .mapfile import MapTensorFileError
from .maptensor import MapTensor
from .ordering import DEFAULT_RULE

__all__ = ["LABELLING_SOURCES", "NODES_PER_SECOND", "COMPILE_SECONDS", "default_cache_dir", "labelling_digest",
           "map_name", "map_path", "cached_map", "warm_up"]

#: Labelling rate of procedure 1 once its kernels are compiled, nodes/s: the build time a build announces.
#: Measured with ``python -m solver build`` (posture 1 at 10 mm, 2 deg: 5.6 million nodes) on 2 cores shared
#: with other jobs: 100,000 nodes/s at the start, 64,000 nodes/s over the whole build (88 s).
NODES_PER_SECOND = 100_000
#: Seconds to compile procedure 1's kernels the first time (numba caches them on disk after that);
#: measured with an empty numba cache on 2 cores shared with other jobs: 26 s and 38 s.
COMPILE_SECONDS = 40
#: The solver sources that decide a map's labels (geometry, IK, DK and its numbering, procedure 1).
LABELLING_SOURCES = ("checks.py", "manipulator.py", "manipulators.py", "rpr.py", "angles.py", "kinematics.py",
                     "direct_kinematics.py", "ordering.py", "grid.py", "maptensor.py", "_kernels/layout.py",
                     "_kernels/linalg.py", "_kernels/kinematics.py", "_kernels/direct_kinematics.py",
                     "_kernels/ordering.py", "_kernels/maptensor.py")


def default_cache_dir() -> Path:
    """The map cache folder when none is given: ``solver.cache_dir("maps")`` (see the module docstring)."""
    return _cache_root("maps")


def warm_up(model: Manipulator, posture: int = 1, rule: str = DEFAULT_RULE, progress: bool | None = None) -> float:
    """Load procedure 1's compiled kernels (IK and all DK solutions), compiling them on the first run.

    numba compiles a kernel at its first call and keeps it in its disk cache; loading from there
    takes a fraction of a second, compiling about :data:`COMPILE_SECONDS`.  A line on stderr says
    so only when it takes longer than 2 s (:func:`solver.progress.phase` with ``after``).

    Parameters
    ----------
    model : Manipulator
    posture : int
        A posture of ``model`` (the kernels are the same for all).
    rule : str
        An ordering rule.
    progress : bool, optional
        As in :func:`cached_map`.

    Returns
    -------
    float
        The wall time, s.
    """
    with _progress.phase("loading the compiled kernels", f"the first run compiles them: about {COMPILE_SECONDS} s, "
                         f"once; numba keeps them in its disk cache", enabled=progress, after=2.0) as ph:
        X = np.zeros((1, 3))
        ik(model, X, posture)
        dk_all(model, X, rule=rule)
    return ph.seconds


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
             cache_dir=None) -> Path:
    """The cache file of a map: ``cache_dir / map_name(...)`` (``cache_dir`` default :func:`default_cache_dir`)."""
    return Path(default_cache_dir() if cache_dir is None else cache_dir) / map_name(model, posture, rule, step)


def cached_map(model: Manipulator, posture: int, rule: str = DEFAULT_RULE, step=DEFAULT_STEP,
               cache_dir=None, *, progress: bool | None = None, log=None) -> MapTensor:
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
    cache_dir : str or Path, optional
        The cache folder (created if missing); default :func:`default_cache_dir`.
    progress : bool, optional
        A build says so on stderr: a line when it starts (what, where to, about how long), a
        progress bar, a line with its time (:mod:`solver.progress`); None: the process default.
    log : callable, optional
        Called with one line saying whether the map was reused or built (file, nodes, size),
        preceded by the reason when a cached file is rebuilt; default: those lines go to stderr
        with the progress output.
    """
    say = log if log is not None else (lambda text: _progress.note(text, progress))
    path = map_path(model, posture, rule, step, cache_dir)
    bounds, shape = default_grid(model, step)
    mt = _load_cached(path, model, posture, rule, bounds, shape, say)
    built = mt is None
    if built:
        nodes = int(np.prod(shape))
        what = (f"building map tensor posture {int(posture)} at {step[0] * 1e3:g} mm, "
                f"{float(np.rad2deg(step[2])):g} deg")
        eta = max(1, round(nodes / NODES_PER_SECOND))
        detail = f"{nodes:,} nodes into {path.parent}; about {eta} s"
        warm_up(model, posture, rule, progress)
        with _progress.phase(what, detail, enabled=progress) as ph:
            mt = MapTensor.build(model, posture, bounds=bounds, shape=shape, rule=rule, progress=progress)
            mt.save(path)
            ph.summary = f"{nodes / mt.build_seconds:,.0f} nodes/s"
    say(f"map posture {int(posture)}: {'built' if built else 'reused'} {path} "
        f"({mt.shape[0]} x {mt.shape[1]} x {mt.shape[2]} nodes, {path.stat().st_size / 1e3:.0f} kB)")
    return mt


def _load_cached(path, model, posture, rule, bounds, shape, say):
    """The map in ``path`` if it checks out and holds the requested grid, else None (saying why)."""
    if not path.is_file():
        return None
    try:
        mt = MapTensor.load(path, model=model, posture=posture)
    except MapTensorFileError as exc:
        say(f"{path}: unusable cached map ({exc}); rebuilding")
        return None
    if mt.rule == rule and tuple(mt.shape) == shape and np.allclose(mt.bounds, bounds, rtol=0, atol=1e-12):
        return mt
    say(f"{path}: cached map does not match the requested grid; rebuilding")
    return None
