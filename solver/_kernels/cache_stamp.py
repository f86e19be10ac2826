"""numba's on-disk cache of the kernels, stamped with the content of every kernel module.

numba's ``cache=True`` stamps a kernel's cache entry with its *own* source file (numba 0.68: the
SHA-256 of that file).  A kernel's cached machine code holds the kernels it calls (numba links them
in) and the module constants it reads (the packed arrays' offsets of :mod:`.layout`, the core of
:mod:`.kinematics` and :mod:`.linalg`) from other files: after a change to one of those, an unchanged file's cached machine code is loaded
with the old constants baked in (a ``git pull`` that changed only ``layout.py``; a CI cache kept
between runs; seen as "cannot assign slice of shape (0,) from input of shape (3,)" in a kernel
that wrote a pack of the old size).

:func:`stamp_by_content` puts one locator in front of numba's own ones (behind any other
project's locators, such as the FMU runtime's, which answer for the copies inside an FMU).  For a
source file inside one of the given kernel folders it takes the place numba would have chosen
(``$NUMBA_CACHE_DIR``, ``__pycache__``, the user-wide cache) and stamps it with the SHA-256 of
the names and bytes of every ``.py`` file in its folder: any change to any kernel module
recompiles every kernel once, and an unchanged tree keeps its cache wherever it is checked out.
A folder's key also covers the folders its kernels depend on (``depends_on``).  The key is
computed once per folder and process (about a millisecond).
"""
from __future__ import annotations

import hashlib
import os

#: marks the locator class this module adds (one per process, whatever the folders)
_MARKER = "_rrr_dk_content_stamp"
#: kernel folder (absolute, with a trailing separator) -> the folders its key covers (itself first)
_FOLDERS: dict[str, tuple[str, ...]] = {}
_KEYS: dict[str, str] = {}                 # kernel folder -> its content key, once computed


def content_key(folders) -> str:
    """SHA-256 (hex, 24 digits) of the names and bytes of the ``.py`` files directly in ``folders``.

    Parameters
    ----------
    folders : iterable of str
        Folders of kernel modules (not searched recursively; ``__pycache__`` is not read).

    Returns
    -------
    str
        The key; the same files with the same bytes give the same key in any location.
    """
    h = hashlib.sha256()
    for folder in folders:
        base = os.path.basename(os.path.dirname(os.path.abspath(folder).rstrip(os.sep)))
        for name in sorted(os.listdir(folder)):
            if name.endswith(".py"):
                with open(os.path.join(folder, name), "rb") as f:
                    h.update(f"{base}/{name}".encode() + b"\0" + f.read() + b"\0")
    return h.hexdigest()[:24]


def _folder_of(py_file: str) -> str | None:
    """The registered kernel folder ``py_file`` is directly in, or None."""
    folder = os.path.join(os.path.dirname(os.path.abspath(py_file)), "")
    return folder if folder in _FOLDERS else None


def _key(folder: str) -> str:
    if folder not in _KEYS:
        _KEYS[folder] = content_key(_FOLDERS[folder])
    return _KEYS[folder]


def _locator_class(caching, impl):
    class ContentStampedLocator(caching._CacheLocator):
        """numba's own locator for a kernel file (its place), stamped with the kernel tree's key."""

        def __init__(self, inner, folder):
            self._inner = inner
            self._folder = folder

        def ensure_cache_path(self):
            self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_source_stamp(self):
            return "kernels-" + _key(self._folder)

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        def __getattr__(self, name):          # _py_file and the like, for numba's warnings
            return getattr(self._inner, name)

        @classmethod
        def from_function(cls, py_func, py_file):
            folder = _folder_of(py_file)
            if folder is None:
                return None
            classes = impl._locator_classes
            for other in classes[classes.index(cls) + 1:]:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, folder)
            return None

    setattr(ContentStampedLocator, _MARKER, True)
    return ContentStampedLocator


def stamp_by_content(folder: str, depends_on=()) -> None:
    """Stamp the numba cache entries of the kernels defined in ``folder`` with a content key.

    Call it before the first ``@njit(cache=True)`` of ``folder`` runs (numba picks a kernel's
    locator when it is decorated): from the kernel package's ``__init__``.  With a numba whose
    cache internals differ, numba's own stamps stay (the cache is an optimization).

    Parameters
    ----------
    folder : str
        A folder of kernel modules (the ``.py`` files directly in it).
    depends_on : sequence of str
        The kernel folders whose kernels and constants those of ``folder`` use (their content is
        part of the key: ``dynamics/_kernels`` depends on ``solver/_kernels``).
    """
    path = os.path.join(os.path.abspath(folder), "")
    _FOLDERS[path] = (path,) + tuple(os.path.join(os.path.abspath(d), "") for d in depends_on)
    _KEYS.pop(path, None)
    try:
        from numba.core import caching
    except ImportError:                       # no numba, no kernels
        return
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None or not hasattr(caching, "_CacheLocator"):
        return
    classes = impl._locator_classes
    if any(getattr(c, _MARKER, False) for c in classes):
        return
    # behind any non-numba locator already there (the FMU runtime's answers for FMU bundles)
    at = next((i for i, c in enumerate(classes) if c.__module__.startswith("numba.")), len(classes))
    classes.insert(at, _locator_class(caching, impl))
