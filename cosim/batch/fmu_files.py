"""The FMU files of a batch: their identity (:func:`fmu_spec`, SHA-256) and their copies on a node.

``path`` transfer: tasks carry the absolute paths and the SHA-256 of each file; a worker checks the
hash of what it finds at that path (a stale copy on a node is an error, not a silently different
result).  ``bytes`` transfer: the client scatters the three files once to every worker; the first
task on a node writes them with :func:`materialize` to ``$RRR_DK_FMU_CACHE`` or
``<tmp>/rrr-dk-fmus/<sha256>/<Name>.fmu`` (atomic rename, hash checked), shared by the worker
processes of that node; no shared file system is needed.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from cosim import FMU_NAMES

from .sweep import ConfigError

__all__ = ["sha256_file", "fmu_spec", "cache_root", "materialize"]


def sha256_file(path) -> str:
    """SHA-256 (hex) of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fmu_spec(fmus: dict) -> dict:
    """``{name: {"path": absolute path, "sha256": ..., "size": bytes}}`` of the three FMU files."""
    spec = {}
    for name in FMU_NAMES:
        if name not in fmus:
            raise ConfigError(f"no {name} FMU given")
        p = Path(fmus[name]).resolve()
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such FMU")
        spec[name] = {"path": str(p), "sha256": sha256_file(p), "size": p.stat().st_size}
    return spec


def cache_root() -> Path:
    """Where a node keeps FMU files received as bytes: ``$RRR_DK_FMU_CACHE`` or ``<tmp>/rrr-dk-fmus``."""
    return Path(os.environ.get("RRR_DK_FMU_CACHE") or Path(tempfile.gettempdir()) / "rrr-dk-fmus")


def materialize(name: str, sha: str, data: bytes) -> Path:
    """Write ``data`` to ``<cache>/<sha>/<name>.fmu`` once (atomic, hash checked); its path."""
    target = cache_root() / sha / f"{name}.fmu"
    if target.is_file() and target.stat().st_size == len(data):
        return target
    if hashlib.sha256(data).hexdigest() != sha:
        raise RuntimeError(f"{name}: the bytes received do not match their SHA-256 {sha[:12]}...")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
