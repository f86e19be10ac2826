"""The DK FMU's embedded map tensors: read and checked at instantiation (:func:`load_maps`).

Part of the FMU runtime (bundled into the DK FMUs): the manifest ``resources/maps/manifest.json``
lists each map's posture, file, size and SHA-256; a map missing, truncated, modified, unreadable or of
another geometry than the others is refused with a :class:`solver.MapTensorFileError` naming it.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from solver import MapTensor, MapTensorFileError

__all__ = ["load_maps"]


def load_maps(folder: Path, owner: str):
    """``({posture: MapTensor}, model)`` of the manifest in ``folder`` (``resources/<maps>``); ``owner``
    names the slave in the messages.  Raises MapTensorFileError on anything that does not check out."""
    where = f"{owner}: embedded map tensors ({folder})"
    manifest = folder / "manifest.json"
    try:
        entries = json.loads(manifest.read_text())["maps"]
    except FileNotFoundError:
        raise MapTensorFileError(f"{where}: resources/{folder.name}/manifest.json is missing "
                                 "(FMU not built by build_fmu.py, or damaged)") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise MapTensorFileError(f"{where}: unreadable manifest.json ({type(exc).__name__}: {exc})") from None
    if not entries:
        raise MapTensorFileError(f"{where}: manifest.json lists no map")
    maps, model = {}, None
    for entry in entries:
        try:
            posture, name, size, sha = int(entry["posture"]), str(entry["file"]), entry["bytes"], entry["sha256"]
        except (KeyError, TypeError, ValueError) as exc:
            raise MapTensorFileError(f"{where}: malformed manifest entry {entry!r} ({exc})") from None
        path = folder.parent / name
        if not path.is_file():
            raise MapTensorFileError(f"{where}: the map of posture {posture}, resources/{name}, is missing")
        data = path.read_bytes()
        digest = hashlib.sha256(data).hexdigest()
        if len(data) != size or digest != sha:
            raise MapTensorFileError(
                f"{where}: the map of posture {posture}, resources/{name}, is truncated or modified: "
                f"{len(data)} bytes, sha256 {digest[:16]}...; the build recorded {size} bytes, "
                f"sha256 {str(sha)[:16]}...")
        try:
            mt = MapTensor.load(path, posture=posture)
        except MapTensorFileError as exc:
            raise MapTensorFileError(f"{where}: {exc}") from None
        if model is not None and mt.model.digest() != model.digest():
            raise MapTensorFileError(f"{where}: the maps were built for different geometries")
        model = mt.model
        maps[posture] = mt
    return maps, model
