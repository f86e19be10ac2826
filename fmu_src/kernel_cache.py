"""Compiled kernels of an FMU's bundled packages, cached on disk by the FMU's content.

Part of the FMU runtime (bundled into every FMU): it imports the standard library only (numba is
patched when it is imported, never imported here).

The problem.  An FMU carries its own copies of ``solver`` and ``dynamics`` under ``resources/``.
A host that has not imported those packages itself runs the copies, and every host extracts the
FMU into a fresh temporary folder.  numba's ``cache=True`` keeps compiled kernels next to the
source (``__pycache__``) or, with ``NUMBA_CACHE_DIR``, in a folder named after the source's
*directory path*: both are new for every extraction, so every process (every batch worker, every
``fmpy.simulate_fmu`` run) compiled the kernels again, seconds per FMU.

The cache.  :func:`install` puts one more cache locator in front of numba's
(:class:`BundleLocator`).  It answers only for source files inside an FMU's ``resources/`` folder
(recognized by pythonfmu's ``slavemodule.txt``) and keeps their kernels in
``<root>/<key>/<folder inside resources>``, where ``key`` is the SHA-256 of every ``.py`` file of
that ``resources/`` folder (names and bytes): the same FMU content finds its kernels wherever it
is extracted, and any change to any bundled module (a kernel inlines its callees from other
files) gets a new folder.  ``root`` is ``$NUMBA_CACHE_DIR`` if set, else ``fmu-kernels`` under the
project's one cache root (the rule of :func:`solver.cache_dir`: ``$RRR_DK_CACHE``, else
``$XDG_CACHE_HOME/rrr-dk``, else ``~/.cache/rrr-dk``; written out here because the runtime must not
import :mod:`solver`, which imports numba, before numba is patched); if it cannot be
written numba's own locators take over (compile per extraction, as before).  Source files outside
FMUs are left to numba's locators.  Old keys are never deleted (a few MB each).

:func:`install` runs when :mod:`fmu_src.table_slave` is imported, before a slave imports its
packages: if numba is already imported it patches it at once, otherwise when
``numba.core.caching`` is first imported (a ``sys.meta_path`` hook that removes itself).
"""
from __future__ import annotations

import hashlib
import importlib.abc
import os
import sys
from pathlib import Path

__all__ = ["install", "cache_root", "bundle_of", "bundle_key", "BUNDLE_MARK"]

#: the file pythonfmu writes at the top of an FMU's resources folder
BUNDLE_MARK = "slavemodule.txt"
_MARKER = "_rrr_dk_bundle_locator"        # set on our locator class: installed once per process
_KEYS: dict[str, str] = {}                # resources folder -> key (one hash per folder and process)
_BUNDLES: dict[str, str | None] = {}      # source folder -> its resources folder (None: not in an FMU)


def cache_root() -> Path:
    """Where the kernels of FMU bundles go: ``$NUMBA_CACHE_DIR``, else ``<cache root>/fmu-kernels`` (the
    module docstring; a test holds the root to :func:`solver.cache_dir`)."""
    explicit = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if explicit:
        return Path(explicit)
    root = os.environ.get("RRR_DK_CACHE", "").strip()
    if root:
        return Path(root).expanduser().resolve() / "fmu-kernels"
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base).resolve() / "rrr-dk" / "fmu-kernels"


def bundle_of(py_file: str) -> str | None:
    """The FMU ``resources/`` folder ``py_file`` belongs to (holding :data:`BUNDLE_MARK`), or None.

    Looks at most 6 folders up (``resources/solver/_kernels/x.py`` is 2 below); one answer per
    folder and process.
    """
    start = os.path.dirname(os.path.abspath(py_file))
    if start not in _BUNDLES:
        found, folder = None, start
        for _ in range(6):
            if os.path.isfile(os.path.join(folder, BUNDLE_MARK)):
                found = folder
                break
            parent = os.path.dirname(folder)
            if parent == folder:
                break
            folder = parent
        _BUNDLES[start] = found
    return _BUNDLES[start]


def bundle_key(resources: str) -> str:
    """SHA-256 (hex, 24 digits) of the names and bytes of every ``.py`` file under ``resources``."""
    key = _KEYS.get(resources)
    if key is None:
        h = hashlib.sha256()
        base = Path(resources)
        for path in sorted(base.rglob("*.py")):
            h.update(path.relative_to(base).as_posix().encode() + b"\0")
            h.update(path.read_bytes() + b"\0")
        key = _KEYS[resources] = h.hexdigest()[:24]
    return key


def _locator_class(caching):
    """numba's locator base class extended into :class:`BundleLocator` (built once numba is there)."""

    class BundleLocator(caching._CacheLocator):
        """numba cache locator for the modules of an FMU bundle (see the module docstring)."""

        def __init__(self, py_func, py_file, resources):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._key = bundle_key(resources)
            inside = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), resources)
            self._cache_path = str(cache_root() / self._key / inside)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            # the folder is already keyed by the bundle's content: the key is the stamp (numba's own
            # stamp, mtime and size in older versions, changes with every extraction)
            return self._key

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            resources = bundle_of(py_file) if os.path.isfile(py_file) else None
            if resources is None:
                return None
            try:
                self = cls(py_func, py_file, resources)
                self.ensure_cache_path()
            except OSError:
                return None                  # not writable: numba's locators (in the extracted folder)
            return self

    setattr(BundleLocator, _MARKER, True)
    return BundleLocator


def _patch(caching) -> None:
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None or not hasattr(caching, "_CacheLocator"):
        return                               # an unknown numba: its own locators
    classes = impl._locator_classes
    if not any(getattr(c, _MARKER, False) for c in classes):
        classes.insert(0, _locator_class(caching))


class _PatchOnImport(importlib.abc.MetaPathFinder):
    """Patches ``numba.core.caching`` right after it is executed, then leaves ``sys.meta_path``."""

    def find_spec(self, name, path, target=None):
        if name != "numba.core.caching":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        for finder in sys.meta_path:
            spec = finder.find_spec(name, path, target) if hasattr(finder, "find_spec") else None
            if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
                spec.loader = _PatchingLoader(spec.loader)
                return spec
        return None


class _PatchingLoader(importlib.abc.Loader):
    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        try:
            _patch(module)
        except Exception:  # noqa: BLE001 - the cache is an optimization, never a failure
            pass

    def __getattr__(self, name):                # get_source, get_filename... for tracebacks
        return getattr(self._loader, name)


def install() -> None:
    """Put :class:`BundleLocator` in front of numba's cache locators (now or when numba is imported)."""
    caching = sys.modules.get("numba.core.caching")
    if caching is not None:
        try:
            _patch(caching)
        except Exception:  # noqa: BLE001 - the cache is an optimization, never a failure
            pass
        return
    if not any(getattr(f, _MARKER, False) for f in sys.meta_path):
        hook = _PatchOnImport()
        setattr(hook, _MARKER, True)
        sys.meta_path.insert(0, hook)
