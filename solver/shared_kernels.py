"""Kernels compiled once: the solver in this process loads the generic-CPU kernels an FMU build compiled.

An FMU ships its kernels compiled for any x86-64 CPU (``NUMBA_CPU_NAME=generic``): the build runs
the FMU in a child process that compiles them into the *generic store*,
``cache_dir("fmu-kernels-generic")/<model>/<key>/`` (:mod:`cosim.fmus.kernels`; ``key`` the content
key of the FMU's bundled ``solver`` and ``dynamics``, :func:`fmu_src.kernel_cache.key_of`).  A process
that then runs the FMUs with its own ``solver`` (``python -m cosim``, the batch workers, the tests)
used to compile the same kernels again, for its own CPU, because numba's cache keys an entry on the
CPU it was compiled for: minutes on a first run.

:func:`install` adds one fallback to numba's cache lookup, for the project's own kernels only (those
whose cache the content-stamped locator of :mod:`solver._kernels.cache_stamp` keeps): when numba finds
no entry for this CPU, the entry compiled for the generic CPU is looked up in the generic store,
and used when found.  A store folder serves only while every file the FMU bundled is byte for byte
the file of this process's packages (the build records their SHA-256, ``files.json``; a kernel
holds the machine code of callees from other files, so one changed file retires the folder);
numba's own index then checks the function's bytecode and signature as for any entry.  Nothing is written: a kernel found
nowhere compiles for this CPU into numba's cache as before, and later lookups find it there first.

The price: generic machine code does not use the CPU's vector extensions.  The kernels are scalar
code on 3-vectors, where that was measured as noise (docs/benchmarks.md, ``first_run``).
``RRR_DK_SHARED_KERNELS=0`` in the environment turns the fallback off.

The FMUs a process runs are a second source (:func:`serve_from_fmu`): an extracted FMU's
``resources/kernels/`` holds the same generic kernels, keyed and recorded the same way (its manifest
names the key; the bundled files themselves are the record).  A batch worker on another machine
receives the FMUs, not the store: from them it loads the kernels its own ``solver`` needs instead of
compiling them (the project's FMU driver registers every FMU it extracts, :func:`cosim.unit.extracted`:
the closed loop and the batch; an FMU whose sources differ from its manifest's key is refused).
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

__all__ = ["install", "served", "serve_from_fmu", "ENV", "GENERIC_CPU", "FILES"]

#: The environment variable that turns the fallback off (``0``).
ENV = "RRR_DK_SHARED_KERNELS"
#: The CPU name of the generic store's entries (``fmu_src.kernel_cache.GENERIC_CPU``).
GENERIC_CPU = "generic"
#: The record of a store folder: ``{path relative to resources: SHA-256 of the bundled file}``.
FILES = "files.json"
_MARK = "_rrr_dk_shared_kernels"
_served: list[str] = []                      # the kernels this process took from the store (their file base)
_records: dict = {}                          # a store record's path -> ((mtime_ns, size), its files or None)
_hashes: dict[str, str | None] = {}          # a file of this process's packages -> its SHA-256 (None: missing)
_fmu_sources: dict = {}                      # an extracted FMU's resources folder -> (kernels folder, key, files)
#: what an FMU's ``resources`` folder holds: its shipped kernels, their manifest, the packages left out of the key
_SHIPPED, _MANIFEST, _NO_KERNELS = "kernels", "manifest.json", ("fmu_src", "pythonfmu", "pythonfmu3")


def served() -> list[str]:
    """The kernels (numba's cache file base names) this process loaded from the generic store."""
    return list(_served)


def serve_from_fmu(resources) -> bool:
    """Let the generic kernels an extracted FMU ships (``<resources>/kernels/``) serve this process's misses,
    as the store's do: only kernels of files the FMU bundled byte for byte as this process has them.

    Parameters
    ----------
    resources : str or Path
        The extracted FMU's ``resources`` folder.

    Returns
    -------
    bool
        True when the FMU ships generic kernels with a readable manifest whose key its bundled sources
        give (registered once per folder).
    """
    resources = Path(resources)
    if str(resources) in _fmu_sources:
        return True
    try:
        manifest = json.loads((resources / _SHIPPED / _MANIFEST).read_text())
        key = manifest["key"]
        if manifest.get("cpu") != GENERIC_CPU or not isinstance(key, str):
            return False
        # the key by the FMU runtime's rule (fmu_src.kernel_cache.key_of, which the math may not import; the
        # tests check that an FMU as built passes): names and bytes of the kernel packages' sources, sorted
        sources = sorted((p.relative_to(resources).as_posix(), p) for p in resources.rglob("*.py"))
        files, whole = {}, hashlib.sha256()
        for name, path in sources:
            if "/" in name and name.split("/")[0] not in _NO_KERNELS:
                data = path.read_bytes()
                files[name] = hashlib.sha256(data).hexdigest()
                whole.update(name.encode() + b"\0")
                whole.update(data + b"\0")
    except (OSError, ValueError, KeyError, TypeError):
        return False
    if whole.hexdigest()[:24] != key:           # sources edited after the build: its kernels are of other code
        return False
    _fmu_sources[str(resources)] = (resources / _SHIPPED, key, files)
    return True


def _store_folders() -> list:
    """The generic store's folders with their records: [(folder, key, {rel: sha256})].

    Looked up at every miss (a miss compiles for seconds at least; the lookup lists a few folders), so
    a store that an FMU build fills while this process runs serves the process's later misses; a
    record is parsed again only when its file changed."""
    from .cache import cache_dir                 # at the first miss: no folder is made before one is needed

    found = [source for source in _fmu_sources.values() if source[0].is_dir()]
    try:
        records = sorted(Path(cache_dir("fmu-kernels-generic")).glob(f"*/*/{FILES}"))
    except OSError:
        return found
    for record in records:
        try:
            st = record.stat()
            stamp = (st.st_mtime_ns, st.st_size)
            kept = _records.get(str(record))
            if kept is None or kept[0] != stamp:
                kept = _records[str(record)] = (stamp, _read_record(record))
        except OSError:
            continue
        if kept[1] is not None:
            found.append((record.parent, record.parent.name, kept[1]))
    return found


def _read_record(record: Path) -> dict | None:
    """The files a store record lists, {rel: sha256}; None if it is not such a JSON object."""
    try:
        files = json.loads(record.read_text())
    except ValueError:
        return None
    return files if isinstance(files, dict) else None


def _package_root(py_file: str) -> Path:
    """The folder that holds ``py_file``'s top-level package (the resources folder's counterpart)."""
    folder = Path(py_file).resolve().parent
    while (folder.parent / "__init__.py").is_file():
        folder = folder.parent
    return folder.parent if (folder / "__init__.py").is_file() else folder


def _sha256(path: Path) -> str | None:
    key = str(path)
    if key not in _hashes:
        try:
            _hashes[key] = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError:
            _hashes[key] = None
    return _hashes[key]


def _serving(py_file: str):
    """(folder, key, rel) of the store folders that can serve kernels of ``py_file``."""
    base = _package_root(py_file)
    rel = Path(py_file).resolve().relative_to(base).as_posix()
    for folder, key, files in _store_folders():
        if rel in files and all(_sha256(base / name) == digest for name, digest in files.items()):
            yield folder, key, rel


def _load_generic(cache, caching, sig, target_context):
    """The generic store's entry of ``sig`` for ``cache`` (a numba ``Cache`` of a project kernel), or None."""
    py_file = getattr(cache._impl.locator, "_py_file", None)
    if not py_file:
        return None
    sig_key, (triple, _cpu, _features), code = cache._index_key(sig, target_context.codegen())
    for folder, key, rel in _serving(py_file):
        files = caching.IndexDataCacheFile(cache_path=str(folder / os.path.dirname(rel)),
                                           filename_base=cache._impl.filename_base, source_stamp=key)
        data = files.load((sig_key, (triple, GENERIC_CPU, ""), code))
        if data is not None:
            _served.append(cache._impl.filename_base)
            return cache._impl.rebuild(target_context, data)
    return None


def install() -> None:
    """Add the fallback to numba's cache lookup (once per process; not with ``RRR_DK_SHARED_KERNELS=0``, nor
    with a numba whose cache internals differ: the cache is an optimization)."""
    if os.environ.get(ENV, "1").strip() == "0":
        return
    try:
        from numba.core import caching
    except ImportError:                       # no numba, no kernels
        return
    from ._kernels.cache_stamp import _MARKER as STAMPED      # the class mark of the project's locator

    if not (hasattr(caching, "Cache") and hasattr(caching, "IndexDataCacheFile")):
        return
    original = caching.Cache._load_overload
    if getattr(original, _MARK, False):
        return

    def _load_overload(self, sig, target_context):
        data = original(self, sig, target_context)
        if data is not None or not self._enabled or not getattr(getattr(self._impl, "locator", None), STAMPED, False):
            return data
        try:
            return _load_generic(self, caching, sig, target_context)
        except Exception:  # noqa: BLE001 - an unreadable store entry: compile, as without the store
            return None

    setattr(_load_overload, _MARK, True)
    caching.Cache._load_overload = _load_overload
