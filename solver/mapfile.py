"""The map tensor file: a versioned, checksummed compressed ``.npz``.

``save_map`` writes the int8 labels and a JSON metadata record: format version, geometry
(and its SHA-256 digest), posture, bounds, shape, ordering rule, library version, build
statistics (counts, no wall times) and the SHA-256 of the labels.  The file is
deterministic: the same map gives the same bytes (fixed zip entry times, sorted keys), so
an FMU that embeds it is reproducible.  ``read_map`` refuses an unknown format version,
a checksum mismatch, a truncated or foreign file, and a geometry or posture other than the
expected one, with a message that says which.  :meth:`solver.MapTensor.save` and
:meth:`solver.MapTensor.load` are these two functions.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from .manipulator import Manipulator
from .manipulators import manipulator_from_dict
from .ordering import ORDERING_RULES

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "MapTensorFileError", "labels_checksum", "metadata", "save_map",
           "read_map"]

#: What the metadata's ``format`` field says.
FORMAT_NAME = "rrr-dk map tensor"
#: Version of the map file format; the loader refuses any other.
FORMAT_VERSION = 1
#: The time stamp of every zip entry (the earliest a zip file can hold): no wall time in the file.
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


class MapTensorFileError(ValueError):
    """A map tensor file cannot be used: unreadable, tampered, foreign geometry, wrong version."""


def labels_checksum(labels) -> str:
    """SHA-256 of int8 labels in C order."""
    return hashlib.sha256(np.ascontiguousarray(labels, dtype=np.int8).tobytes()).hexdigest()


def metadata(mt) -> dict:
    """The metadata record of a :class:`solver.MapTensor`."""
    from . import __version__
    return {"format": FORMAT_NAME, "format_version": FORMAT_VERSION,
            "library_version": __version__, "geometry": mt.model.to_dict(),
            "geometry_sha256": mt.model.digest(), "posture": mt.posture,
            "bounds": mt.bounds.tolist(), "shape": list(mt.shape), "rule": mt.rule,
            "rule_description": ORDERING_RULES[mt.rule], "labels_dtype": "int8",
            "labels_sha256": labels_checksum(mt.labels), "stats": mt.stats}


def save_map(mt, path) -> Path:
    """Write a :class:`solver.MapTensor` to a compressed ``.npz`` file with its metadata; returns the path.

    The bytes depend on the map only (entries in a fixed order with a fixed time stamp).  The
    file appears complete or not at all (written beside it, then renamed).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = json.dumps(metadata(mt), sort_keys=True)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, array in (("labels", np.ascontiguousarray(mt.labels)), ("metadata", np.array(meta))):
            member = io.BytesIO()
            np.lib.format.write_array(member, array, allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.compress_type, info.external_attr = zipfile.ZIP_DEFLATED, 0o644 << 16
            zf.writestr(info, member.getvalue())
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")        # one per process: concurrent saves do not collide
    tmp.write_bytes(buf.getvalue())
    tmp.replace(path)
    return path


def read_map(path, model: Manipulator | None = None, posture: int | None = None) -> dict:
    """Read a map file written by :func:`save_map`, refusing anything that does not check out.

    Parameters
    ----------
    path : str or Path
    model : Manipulator, optional
        If given, the file's geometry must be this one.
    posture : int, optional
        If given, the file's posture must be this one.

    Returns
    -------
    dict
        The :class:`solver.MapTensor` fields (``model``, ``posture``, ``bounds``, ``shape``,
        ``rule``, ``labels`` read-only, ``stats``).

    Raises
    ------
    MapTensorFileError
        Missing, truncated or foreign file; unknown format version; labels
        whose SHA-256 differs from the recorded one; another geometry or posture.
    """
    path = Path(path)
    labels, meta = _read_arrays(path)
    version = meta.get("format_version")
    if meta.get("format") != FORMAT_NAME or version != FORMAT_VERSION:
        raise MapTensorFileError(f"{path}: format version {version!r} of {meta.get('format')!r}, but this library "
                                 f"reads only version {FORMAT_VERSION} of {FORMAT_NAME!r}; build the map again "
                                 f"(python -m solver build, or delete the file: solver.cached_map rebuilds it)")
    if labels.dtype != np.int8 or list(labels.shape) != list(meta.get("shape", [])):
        raise MapTensorFileError(f"{path}: labels {labels.dtype} {labels.shape} do not match the "
                                 f"metadata shape {meta.get('shape')}")
    digest = labels_checksum(labels)
    if digest != meta.get("labels_sha256"):
        raise MapTensorFileError(f"{path}: labels checksum {digest[:16]}... does not match the recorded "
                                 f"{str(meta.get('labels_sha256'))[:16]}... (file modified or corrupted)")
    file_model = _file_model(path, meta, model)
    if posture is not None and int(posture) != meta.get("posture"):
        raise MapTensorFileError(f"{path}: built for posture {meta.get('posture')}, expected {posture}")
    if meta.get("rule") not in ORDERING_RULES:
        raise MapTensorFileError(f"{path}: unknown ordering rule {meta.get('rule')!r}")
    if labels.size and (labels.min() < 0 or labels.max() > 6):
        raise MapTensorFileError(f"{path}: labels outside 0..6")
    labels.setflags(write=False)
    return {"model": model if model is not None else file_model, "posture": int(meta["posture"]),
            "bounds": np.asarray(meta["bounds"], dtype=float), "shape": tuple(meta["shape"]), "rule": meta["rule"],
            "labels": labels, "stats": meta.get("stats", {})}


def _read_arrays(path: Path):
    """The labels array and the metadata record of a map file (:class:`MapTensorFileError` if unreadable)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if "labels" not in data.files or "metadata" not in data.files:
                raise MapTensorFileError(f"{path}: not a map tensor file (arrays {data.files})")
            return np.array(data["labels"]), json.loads(str(data["metadata"]))
    except MapTensorFileError:
        raise
    except FileNotFoundError:
        raise MapTensorFileError(f"{path}: no such map tensor file") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise MapTensorFileError(f"{path}: unreadable or truncated map tensor file ({exc})") from None


def _file_model(path: Path, meta: dict, model: Manipulator | None) -> Manipulator:
    """The geometry a file records, checked against its digest and against ``model`` if given."""
    try:
        file_model = manipulator_from_dict(meta["geometry"])
    except (KeyError, ValueError) as exc:
        raise MapTensorFileError(f"{path}: invalid geometry record ({exc})") from None
    if file_model.digest() != meta.get("geometry_sha256"):
        raise MapTensorFileError(f"{path}: geometry record does not match its recorded digest")
    if model is not None and model.digest() != file_model.digest():
        raise MapTensorFileError(f"{path}: built for geometry {file_model.name!r} "
                                 f"({file_model.digest()[:12]}), expected {model.name!r} "
                                 f"({model.digest()[:12]})")
    return file_model
