"""The root of the project's disk caches: one folder, one rule (numba's own cache of the in-process
kernels stays in ``__pycache__`` beside the sources).

:func:`cache_dir` answers where cached files go: ``$RRR_DK_CACHE`` if set, else
``$XDG_CACHE_HOME/rrr-dk``, else ``~/.cache/rrr-dk`` (on every platform), with one
subfolder per kind of file.  The map cache (:mod:`solver.mapcache`) keeps its maps in
``cache_dir("maps")``; the FMUs' compiled kernels ``fmu-kernels/`` (:mod:`fmu_src.kernel_cache`),
a batch's FMU copies on a node ``fmus/`` (:mod:`cosim.batch.fmu_files`) and the designed gains
``designed-gains.json`` (:mod:`dynamics.control`).  Nothing is created until a cache writes.
"""
from __future__ import annotations

import os
from pathlib import Path

from .checks import SolverInputError

__all__ = ["CACHE_ENV", "cache_dir"]

#: The environment variable that moves every cache of the project (a folder; ``~`` is expanded).
CACHE_ENV = "RRR_DK_CACHE"


def cache_dir(*parts: str) -> Path:
    """The cache root, or a folder below it.

    Parameters
    ----------
    *parts : str
        Subfolder names below the root, e.g. ``cache_dir("maps")``.

    Returns
    -------
    Path
        An absolute path (not created): ``$RRR_DK_CACHE``, else ``$XDG_CACHE_HOME/rrr-dk``,
        else ``~/.cache/rrr-dk``, joined with ``parts``.

    Raises
    ------
    SolverInputError
        A part that is empty, absolute or goes up (``..``): the result must stay below the root.
    """
    for part in parts:
        if not isinstance(part, str) or not part or Path(part).is_absolute() or ".." in Path(part).parts:
            raise SolverInputError(f"parts: expected relative folder names below the cache root, got {part!r}")
    explicit = os.environ.get(CACHE_ENV, "").strip()
    if explicit:
        root = Path(explicit).expanduser()
    else:
        base = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join(os.path.expanduser("~"), ".cache")
        root = Path(base) / "rrr-dk"
    return root.resolve().joinpath(*parts)
