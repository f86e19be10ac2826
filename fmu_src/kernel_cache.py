"""Compiled kernels of an FMU's bundled packages: shipped in the FMU, cached on disk by its content.

Part of the FMU runtime (bundled into every FMU): it imports the standard library only (numba is
patched when it is imported, never imported here).

The problem.  An FMU carries its own copies of ``solver`` and ``dynamics`` under ``resources/``.
A host that has not imported those packages itself runs the copies, and every host extracts the
FMU into a fresh temporary folder.  numba's ``cache=True`` keeps compiled kernels next to the
source (``__pycache__``) or, with ``NUMBA_CACHE_DIR``, in a folder named after the source's
*directory path*, and stamps them with the source file's mtime and size: all new for every
extraction, so every process compiled the kernels again (35 s and more for the DK FMU).

What numba's cache keys on (numba 0.68, ``numba/core/caching.py``): one index per function and
Python version (``<module>.<qualname>-<line>.py<XY>.nbi``, data in ``....<n>.nbc``); it starts with
numba's version and the locator's *source stamp* (numba's: mtime and size; either differing reads
as empty); an entry's key is (signature, the codegen's (target triple, CPU name, CPU features),
SHA-256 of the function's bytecode and of its closure variables).

Two places, one key.  :func:`fmu_src.kernel_locator.install` puts one more cache locator in front of
numba's (``BundleLocator``).  It answers only for source files inside an FMU's ``resources/`` folder
(recognized by pythonfmu's ``slavemodule.txt``).  Their *key* is the SHA-256 of the names and
bytes of every ``.py`` file in the packages of that folder that hold kernels (``solver``,
``dynamics``; not the slave script at the top, this runtime ``fmu_src``, ``pythonfmu`` or ``pythonfmu3``: kernels
never import them, so FMUs of one code that differ in a start value or in the runtime share
kernels): the same content finds its kernels wherever it is extracted, any change to a module of
those packages (a kernel's machine code holds its callees from other files) gets a new key.  The key is also
the index's source stamp, in place of numba's mtime and size, so extraction dates do not matter.

1. *Shipped* (read only): ``resources/kernels/<folder inside resources>/``, numba's index and data
   files written at build time (:mod:`cosim.fmus.kernels`) by a process with
   ``NUMBA_CPU_NAME=generic`` (machine code for any x86-64 CPU), and ``resources/kernels/
   manifest.json`` (numba and Python versions, machine, key, compile seconds per kernel).  numba's
   index keys an entry on the signature, the bytecode and the *codegen's* (target triple, CPU
   name, CPU features); the host's CPU is not ``generic``, so a shipped entry is looked up with the
   generic CPU in the key.  Generic code is plain x86-64 (what the CPU runs is the object code,
   loaded as it is), so it runs on any x86-64 CPU, slower only by the vector extensions it does not use.
   A kernel not found there is looked up in the shipped kernels of the process's other live FMUs
   whose copies of its kernel folders are the same bytes (:func:`fmu_src.kernel_locator.shipped_folders`):
   Python imports ``solver`` once per process, so the DK FMU after the plant runs the plant's copy.
2. *User cache* (written): ``<root>/<key>/<folder inside resources>``, ``root`` being
   ``$NUMBA_CACHE_DIR`` if set, else ``fmu-kernels`` under the project's one cache root (the rule
   of :func:`solver.cache_dir`: ``$RRR_DK_CACHE``, else ``$XDG_CACHE_HOME/rrr-dk``, else
   ``~/.cache/rrr-dk``; written out here because the runtime must not import :mod:`solver`, which
   imports numba, before numba is patched).  Kernels compiled on this machine (a signature or a
   numba version the FMU did not ship) go there, for this CPU.  numba looks here first, then in the
   shipped folder.  If the root cannot be written (another user's, a read-only home), a folder of
   the process's own under the temporary folder takes its place (removed at exit).

Never on the host's thread.  When the shipped kernels cannot serve this process at all (other
numba, Python or machine, none shipped, other code), :func:`attach` has them compiled at
instantiation in a child process of the same interpreter (:mod:`fmu_src.kernel_warmup`), which the
host process then loads from the user cache: numba's compiler recurses deeply and overflows the small
stacks of host threads.  A kernel still found in neither place (a signature the warm-up did not
reach) is compiled in process and announced: its name and an estimate (the manifest's build-time
seconds) go to the log of the FMU instance that runs it (pythonfmu's ``log``, the host's logger) and
to the Python logger ``fmu_src.<ModelName>`` (stderr): ``compiling <kernel>, about N s``.  Only the
outermost compile is announced (numba compiles the callees inside it).  pythonfmu hands an
instance's log to the host when the FMI call returns (stderr has it at once).

numba's side (the locator, the shipped lookup, the announcements, the patch) is
:mod:`fmu_src.kernel_locator`; this module holds the keys, the bundles, the manifest and the
attached slaves.  Old keys are never deleted (a few MB each).
"""
from __future__ import annotations

import atexit
import hashlib
import json
import logging
import os
import platform
import shutil
import sys
import tempfile
import weakref
from pathlib import Path

__all__ = ["attach", "cache_root", "bundle_of", "bundle_key", "key_of", "kernel_files", "shipped_problem", "manifest",
           "BUNDLE_MARK", "SHIPPED", "MANIFEST", "GENERIC_CPU", "NO_KERNELS"]

#: the file pythonfmu writes at the top of an FMU's resources folder
BUNDLE_MARK = "slavemodule.txt"
#: the folder of the shipped kernels inside ``resources/`` and their manifest in it
SHIPPED = "kernels"
MANIFEST = "manifest.json"
#: the CPU name the shipped kernels are compiled for (``NUMBA_CPU_NAME``; no CPU features)
GENERIC_CPU = "generic"
_KEYS: dict[str, str] = {}                # resources folder -> key (one hash per folder and process)
_FOLDER_KEYS: dict[str, dict] = {}        # resources folder -> {folder inside: key of the .py files directly in it}
_BUNDLES: dict[str, str | None] = {}      # source folder -> its resources folder (None: not in an FMU)
_MANIFESTS: dict[str, dict] = {}          # resources folder -> its manifest ({} when none)
_SLAVES: list = []                        # weak references to the attached slave instances
_SCRATCH: list[str] = []                  # this process's own writable folder, when the root is not


def cache_root() -> Path:
    """Where the kernels of FMU bundles go: ``$NUMBA_CACHE_DIR``, else ``<cache root>/fmu-kernels`` (the
    module docstring; a test holds the root to :func:`solver.cache_dir`)."""
    explicit = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if explicit:
        return Path(os.path.abspath(explicit))      # the child compiling for this process runs elsewhere
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


#: the packages of a bundle that hold no kernel and are left out of its key: this runtime, pythonfmu (FMI 2.0)
#: and pythonfmu3 (FMI 3.0)
NO_KERNELS = ("fmu_src", "pythonfmu", "pythonfmu3")


def kernel_files(files) -> list:
    """The pairs of ``files`` (``(path relative to resources, bytes)``) a key covers, sorted: the ``.py``
    files of the packages that hold kernels (the slave script at the top and the packages
    :data:`NO_KERNELS` are left out, see the module docstring)."""
    return [(name, data) for name, data in sorted(files)
            if name.endswith(".py") and "/" in name and name.split("/")[0] not in NO_KERNELS]


def key_of(files) -> str:
    """The key of ``files``, ``(path relative to resources, bytes)`` pairs: SHA-256 (hex, 24 digits) of
    the names and bytes of :func:`kernel_files`."""
    h = hashlib.sha256()
    for name, data in kernel_files(files):
        h.update(name.encode() + b"\0")
        h.update(data + b"\0")
    return h.hexdigest()[:24]


#: the packages whose kernels FMUs ship (in their ``_kernels`` folders), each importing only those before
#: it (``solver`` never imports ``dynamics``): a kernel of one is the same machine code in any bundle whose
#: copies of its folder and of those folders before it are the same bytes
KERNEL_ORDER = ("solver", "dynamics")


def bundle_key(resources: str) -> str:
    """The key (:func:`key_of`) of the FMU bundle in the folder ``resources`` (one hash per folder and process)."""
    key = _KEYS.get(resources)
    if key is None:
        base = Path(resources)
        files = [(p.relative_to(base).as_posix(), p.read_bytes()) for p in base.rglob("*.py")]
        key = _KEYS[resources] = key_of(files)
        folders = {name.rpartition("/")[0] for name, _ in kernel_files(files)}
        _FOLDER_KEYS[resources] = {folder: key_of(f for f in files if f[0].rpartition("/")[0] == folder)
                                   for folder in folders}
    return key


def _same_kernels(inside: str, resources: str, other: str) -> bool:
    """Whether the kernels of the folder ``inside`` (relative to ``resources``) are the same code in the
    bundle ``other``: the same bytes in that folder and in the kernel folders of the packages it
    imports (:data:`KERNEL_ORDER`; ``tests/test_kernel_stamp.py`` holds the kernel folders to importing
    nothing else of the project).  It compares the two bundles' copies: in a process that imported
    ``solver`` from an FMU of another build than ``dynamics`` (FMUs of two versions of this code), a
    ``dynamics`` kernel's callees are not the copies compared; numba's user cache keyed by the bundle
    has the same limit."""
    inside = inside.replace(os.sep, "/")
    package = inside.split("/")[0]
    before = KERNEL_ORDER[:KERNEL_ORDER.index(package)] if package in KERNEL_ORDER else ()
    bundle_key(other)
    mine, theirs = _FOLDER_KEYS.get(resources, {}), _FOLDER_KEYS[other]
    return all(mine.get(f) is not None and mine.get(f) == theirs.get(f)
               for f in (inside, *(f"{p}/_kernels" for p in before)))


def manifest(resources: str) -> dict:
    """The manifest of the kernels shipped in ``resources`` (``{}`` when it has none or it is unreadable)."""
    if resources not in _MANIFESTS:
        try:
            with open(os.path.join(resources, SHIPPED, MANIFEST), encoding="utf-8") as f:
                _MANIFESTS[resources] = json.load(f)
        except (OSError, ValueError):
            _MANIFESTS[resources] = {}
    return _MANIFESTS[resources]


def shipped_problem(resources: str) -> str | None:
    """Why the kernels shipped in ``resources`` cannot serve this process (None: they can)."""
    info = manifest(resources)
    if not info:
        return "the FMU carries no compiled kernels"
    here = {"numba": _numba_version() or info.get("numba"),
            "python": "%d.%d" % sys.version_info[:2], "machine": platform.machine().lower()}
    for what, value in here.items():
        if info.get(what) != value:
            return f"its compiled kernels are for {what} {info.get(what)}, this process has {value}"
    if info.get("key") != bundle_key(resources):
        return "its compiled kernels are for other code than the modules it carries"
    if not any(f.endswith(".nbi") for _, _, files in os.walk(os.path.join(resources, SHIPPED)) for f in files):
        return "its kernel folder holds no compiled kernel"
    return None


def _numba_version() -> str | None:
    """The numba this process runs: the imported module's version, else the installed distribution's
    (a slave may import its kernels only in ``setup()``, after this is asked); None if there is none."""
    numba = sys.modules.get("numba")
    if numba is not None:
        return getattr(numba, "__version__", None)
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:                      # pragma: no cover - Python < 3.8
        return None
    try:
        return version("numba")
    except PackageNotFoundError:
        return None


def _scratch_root() -> str:
    """This process's own cache folder under the temporary folder (made once, removed at exit)."""
    if not _SCRATCH:
        _SCRATCH.append(tempfile.mkdtemp(prefix="rrr-dk-kernels-"))
        atexit.register(shutil.rmtree, _SCRATCH[0], True)
    return _SCRATCH[0]


def _slave_for(resources: str):
    """The live attached slave of ``resources`` (the latest), else the latest live one, else None."""
    alive = [s for s in (ref() for ref in _SLAVES) if s is not None]
    _SLAVES[:] = [weakref.ref(s) for s in alive]
    same = [s for s in alive if getattr(s, "resources", None) == resources]
    return (same or alive or [None])[-1]


def _send(slave, resources: str, msg: str) -> None:
    """``msg`` to the host's logger through the slave's pythonfmu log, and to the Python logger."""
    name = type(slave).__name__ if slave is not None else os.path.basename(os.path.dirname(resources))
    logging.getLogger(f"fmu_src.{name}").warning("%s", msg)
    if slave is not None and hasattr(slave, "log"):
        try:
            slave.log(msg.replace("%", "%%"))
        except Exception:  # noqa: BLE001 - a log must never fail the call
            pass


def _has_kernel_packages(resources: str) -> bool:
    """Whether the bundle in ``resources`` has a package that may hold kernels (not :data:`NO_KERNELS`)."""
    return any(os.path.isfile(os.path.join(resources, e, "__init__.py")) for e in os.listdir(resources)
               if e not in NO_KERNELS)


def _hosts_own_packages(resources: str) -> bool:
    """Whether this process imported ``solver`` or ``dynamics`` from elsewhere than ``resources`` (the FMU
    then runs those, with their own kernels, never its bundled ones)."""
    inside = os.path.join(os.path.abspath(resources), "")
    return any(not os.path.abspath(getattr(sys.modules[name], "__file__", None) or inside).startswith(inside)
               for name in ("solver", "dynamics") if name in sys.modules)


def attach(slave) -> str | None:
    """Send the compile announcements of ``slave``'s FMU to ``slave`` (a pythonfmu slave, weakly held) and
    say why the kernels it ships cannot serve this process (None: they can, or the slave runs the host's
    own packages, or none of an FMU).  Called before ``setup()``; the caller has them compiled in a child
    process then (:func:`fmu_src.kernel_warmup.ensure`)."""
    resources = getattr(slave, "resources", None)
    if not resources or not os.path.isdir(resources):
        return None
    _SLAVES[:] = [ref for ref in _SLAVES if ref() is not None] + [weakref.ref(slave)]
    if not _has_kernel_packages(resources) or _hosts_own_packages(resources):
        return None
    return shipped_problem(resources)
