"""numba's side of the FMUs' kernel cache (:mod:`fmu_src.kernel_cache` holds the keys and the bundles).

Part of the FMU runtime (bundled into every FMU): it imports the standard library only (numba is
patched when it is imported, never imported here).

:func:`install` puts ``BundleLocator`` in front of numba's cache locators: for a source file inside
an FMU's ``resources/`` folder it stamps the cache with the bundle's key and places the user cache
under it (:mod:`fmu_src.kernel_cache`, "Two places, one key").  numba's ``Cache._load_overload`` is
wrapped to look in the shipped kernels (:func:`shipped_folders`: the bundle's own, then those of the
process's other live FMUs of the same kernel code) and to announce a kernel found nowhere before it
is compiled (:func:`_announce`: once, the outermost compile only, to the host's logger of the
instance that runs it).

:func:`install` runs when :mod:`fmu_src.table_slave` is imported, before a slave imports its
packages: if numba is already imported it patches it at once, otherwise when
``numba.core.caching`` is first imported (a ``sys.meta_path`` hook that removes itself).  Source
files outside FMUs are left to numba's locators.
"""
from __future__ import annotations

import importlib.abc
import os
import sys

from .kernel_cache import (_BUNDLES, _KEYS, _SLAVES, BUNDLE_MARK, GENERIC_CPU, SHIPPED, _same_kernels, _scratch_root,
                           _send, _slave_for, bundle_key, bundle_of, cache_root, manifest, shipped_problem)

__all__ = ["install", "shipped_folders"]

_MARKER = "_rrr_dk_bundle_locator"        # set on our locator class: installed once per process
_ANNOUNCED: set = set()                   # (resources, kernel) announced once per process
_DEPTH = [0]                              # numba compilations in progress (callees compile inside)


def _locator_class(caching):
    """numba's locator base class extended into :class:`BundleLocator` (built once numba is there)."""

    class BundleLocator(caching._CacheLocator):
        """numba cache locator for the modules of an FMU bundle (see the module docstring)."""

        def __init__(self, py_func, py_file, resources, root):
            self.resources = resources
            self.kernel = f"{py_func.__module__}.{py_func.__qualname__}"
            self._lineno = py_func.__code__.co_firstlineno
            self._key = bundle_key(resources)
            self.inside = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), resources)
            self._cache_path = os.path.join(root, self._key, self.inside)
            self.shipped = os.path.join(resources, SHIPPED, self.inside)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return self._key                 # the content's key, not the extracted file's mtime

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            resources = bundle_of(py_file) if os.path.isfile(py_file) else _gone_bundle(py_file)
            if resources is None:
                return None
            for root in (lambda: str(cache_root()), _scratch_root):
                try:
                    self = cls(py_func, py_file, resources, root())
                    self.ensure_cache_path()
                    return self
                except OSError:
                    continue                 # not writable: the next place
            return None                      # numba's locators (in the extracted folder)

    setattr(BundleLocator, _MARKER, True)
    return BundleLocator


def _gone_bundle(py_file: str) -> str | None:
    """The resources folder of ``py_file`` when the file is gone but its folder was seen in an FMU bundle
    whose key this process knows, else None (fmpy's ``simulate_fmu`` deletes each extraction after its
    run, and a kernel made later from such a module, a fast lane's compiled step, is still that bundle's)."""
    resources = _BUNDLES.get(os.path.dirname(os.path.abspath(py_file)))
    return resources if resources is not None and resources in _KEYS else None


def shipped_folders(locator):
    """``(folder, source stamp)`` of the shipped kernels to look in for ``locator``'s kernel, in order.

    First its bundle's own.  Then the same folder in the other live bundles (:func:`_live_bundles`)
    whose copies of the kernel's folders are the same bytes (:func:`_same_kernels`).  Python
    imports ``solver`` and ``dynamics`` once per process, from the first FMU that brings them: the
    DK FMU run after the plant runs the plant's ``solver``, whose shipped kernels are the plant's, and
    an FMU run after an earlier one's extraction was deleted runs modules of a folder that is gone.
    Each FMU ships the kernels its own runs call, so they are found in its own bundle.
    """
    if os.path.isdir(locator.shipped):
        yield locator.shipped, locator.get_source_stamp()
    seen = {locator.resources}
    for resources in _live_bundles():
        if resources in seen:
            continue
        seen.add(resources)
        folder = os.path.join(resources, SHIPPED, locator.inside)
        try:
            if os.path.isdir(folder) and _same_kernels(locator.inside, locator.resources, resources):
                yield folder, bundle_key(resources)
        except OSError:                      # a bundle being deleted while it is read: not a source
            continue


def _live_bundles():
    """The FMU resources folders of this process that still exist, the latest first: those of the attached
    slaves, then those on ``sys.path`` (pythonfmu puts an FMU's there to import its slave module, whose
    import may already call kernels, before the slave is attached)."""
    attached = [getattr(ref(), "resources", None) for ref in reversed(_SLAVES)]
    for resources in attached + [p for p in reversed(sys.path) if isinstance(p, str)]:
        if resources and os.path.isfile(os.path.join(resources, BUNDLE_MARK)):
            yield resources


def _load_shipped(cache, caching, sig, target_context):
    """The shipped entry of ``sig`` for ``cache`` (a numba ``Cache`` of a bundle kernel), or None."""
    key = None
    for folder, stamp in shipped_folders(cache._impl.locator):    # lazily: the bundle's own folder first
        if key is None:                      # (a build's warm-up has no folder: the key costs a pickle)
            sig_key, (triple, _cpu, _features), code = cache._index_key(sig, target_context.codegen())
            key = (sig_key, (triple, GENERIC_CPU, ""), code)
        files = caching.IndexDataCacheFile(cache_path=folder, filename_base=cache._impl.filename_base,
                                           source_stamp=stamp)
        data = files.load(key)
        if data is not None:
            return cache._impl.rebuild(target_context, data)
    return None


def _patched_load(original, caching):
    """numba's ``Cache._load_overload`` that also looks in the shipped folder and announces a compile."""

    def _load_overload(self, sig, target_context):
        data = original(self, sig, target_context)
        locator = getattr(self._impl, "locator", None)
        if data is not None or not getattr(locator, _MARKER, False) or not self._enabled:
            return data
        try:
            data = _load_shipped(self, caching, sig, target_context)
        except Exception:  # noqa: BLE001 - an unreadable shipped entry: compile, as without it
            data = None
        if data is None:
            _announce(locator.resources, locator.kernel)
        return data

    _load_overload._rrr_dk_original = original
    return _load_overload


def _patch(caching) -> None:
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None or not hasattr(caching, "_CacheLocator") or not hasattr(caching, "IndexDataCacheFile"):
        return                               # an unknown numba: its own locators
    classes = impl._locator_classes
    if any(getattr(c, _MARKER, False) for c in classes):
        return
    classes.insert(0, _locator_class(caching))
    caching.Cache._load_overload = _patched_load(caching.Cache._load_overload, caching)
    try:
        from numba.core import event

        class _CompileDepth(event.Listener):
            """Counts the compilations in progress (:data:`_DEPTH`): callees compile inside a caller."""

            def on_start(self, ev):
                _DEPTH[0] += 1

            def on_end(self, ev):
                _DEPTH[0] -= 1

        event.register("numba:compile", _CompileDepth())
    except Exception:  # noqa: BLE001 - without it every compile (callees too) is announced
        pass


def _announce(resources: str, kernel: str) -> None:
    """Say that ``kernel`` of the FMU in ``resources`` is compiled now (once; outermost compile only)."""
    if _DEPTH[0] > 0 or (resources, kernel) in _ANNOUNCED:
        return
    _ANNOUNCED.add((resources, kernel))
    info = manifest(resources)
    seconds = info.get("seconds", {}).get(kernel) or info.get("total_seconds")
    about = f"about {max(1, round(seconds))} s" if seconds else "about a minute (no estimate in the FMU)"
    _send(_slave_for(resources), resources, f"compiling {kernel} (and the kernels it calls), {about}: "
                                            f"{shipped_problem(resources) or 'a signature the FMU did not ship'}")


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
