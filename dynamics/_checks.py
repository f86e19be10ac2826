"""Argument checks shared by the public functions of :mod:`dynamics` (before any kernel runs)."""
from __future__ import annotations

import numpy as np

from solver import Manipulator, SolverInputError, as_array, ik
from solver.checks import check_instance
from solver.kinematics import check_model

from .errors import DynamicsError, outside_text
from .parameters import DynamicParameters

_F8 = np.dtype(np.float64)


def check_pair(params, model):
    """:class:`SolverInputError` unless ``params`` is a :class:`DynamicParameters` and ``model`` a
    :class:`solver.Manipulator` (:func:`solver.checks.check_instance`, the one type check)."""
    if not isinstance(params, DynamicParameters):     # isinstance first: the fast path of every call
        check_instance("params", params, DynamicParameters, "a DynamicParameters")
    if not isinstance(model, Manipulator):
        check_model(model)


def broadcast(**arrays):
    """Broadcast the leading dimensions of (..., k) arrays, naming them on failure."""
    try:
        lead = np.broadcast_shapes(*(a.shape[:-1] for a in arrays.values()))
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in arrays.items())
        raise SolverInputError(f"{', '.join(arrays)}: leading dimensions do not broadcast: {shapes}") from None
    return [np.broadcast_to(a, lead + a.shape[-1:]) for a in arrays.values()]


def ik_or_raise(model, X, posture):
    """``solver.ik(model, X, posture)``; :class:`DynamicsError` if a pose has no solution."""
    q = ik(model, X, posture)
    bad = np.isnan(q[..., 0])
    if np.any(bad):
        raise DynamicsError(outside_text(posture, np.asarray(X)[bad][:3].tolist()), "outside")
    return q


def posture_bits(posture) -> int:
    """``posture - 1`` (the elbow bits) for a plain integer posture 1..8, else -1."""
    if (type(posture) is int or isinstance(posture, np.integer)) and 1 <= posture <= 8:
        return int(posture) - 1
    return -1


def is_single(arrays, n=3) -> bool:
    """True if every array is a float64 ndarray of shape ``(n,)`` (the single-configuration path,
    whose argument checks the kernel does).  Memory layout is not checked: numba compiles (once,
    then caches) a variant of a kernel for read-only or strided arguments when it first meets one.
    """
    for a in arrays:
        if type(a) is not np.ndarray or a.shape != (n,) or a.dtype is not _F8:
            return False
    return True


def as_rows(a, n):
    """A fresh C-contiguous float64 copy of ``a`` (..., k) as ``(n, k)`` rows."""
    return np.array(a, dtype=np.float64, order="C").reshape(n, a.shape[-1])


def task_args(params, model, X, posture, **more):
    """Checked, broadcast ``X`` and ``more`` arrays, and the motor angles of ``X`` in ``posture``."""
    check_pair(params, model)
    arrays = {"X": as_array("X", X)}
    arrays.update({k: as_array(k, v) for k, v in more.items()})
    out = broadcast(**arrays)
    return out, ik_or_raise(model, out[0], posture)
