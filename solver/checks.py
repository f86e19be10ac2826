"""Argument checking shared by every public function of :mod:`solver` (public: other packages use it too).

One helper turns an argument into a float array of the expected trailing
shape and says exactly what was wrong otherwise ("q: expected (..., 3), got
(4,)").  The exceptions subclass :class:`ValueError` so that callers who catch
``ValueError`` keep working.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["SolverInputError", "GeometryError", "as_array", "check_posture", "check_instance", "Bound",
           "check_number"]


class SolverInputError(ValueError):
    """An argument has the wrong shape, a non-finite entry or an invalid value."""


class GeometryError(ValueError):
    """A manipulator geometry is invalid (non-positive lengths, degenerate triangles...)."""


def check_instance(name: str, value, types, expected: str):
    """``value`` if it is an instance of ``types`` (a type or a tuple of types), else raise.

    The one type check of the packages' models (a manipulator, dynamic parameters, gains...).

    Parameters
    ----------
    name : str
        Argument name used in the error message.
    value : object
        The argument.
    types : type or tuple of type
        The accepted types.
    expected : str
        What was expected, for the message (``"a Manipulator"``).

    Raises
    ------
    SolverInputError
        ``"<name>: expected <expected>, got <type name>"``.
    """
    if not isinstance(value, types):
        raise SolverInputError(f"{name}: expected {expected}, got {type(value).__name__}")
    return value


def _shape_text(trailing: tuple[int, ...]) -> str:
    inner = ", ".join(str(n) for n in trailing)
    return f"(..., {inner})" if trailing else "(...)"


def _preview(a: np.ndarray) -> str:
    flat = a.ravel()
    text = np.array2string(flat[:6], precision=6, separator=", ")
    return text[:-1] + ", ...]" if flat.size > 6 else text


def as_array(name: str, value, trailing: tuple[int, ...] = (3,), *, finite: bool = True,
             dtype=np.float64) -> np.ndarray:
    """Convert ``value`` to an array of shape ``(..., *trailing)`` or raise.

    Parameters
    ----------
    name : str
        Argument name used in the error message.
    value : array_like
        The argument.
    trailing : tuple of int
        Required trailing dimensions, e.g. ``(3,)`` for poses or joint vectors.
    finite : bool
        Reject NaN and infinite entries.
    dtype : numpy dtype
        Target dtype (float64 by default; complex input is refused for float).

    Raises
    ------
    SolverInputError
        If the array cannot be converted, has the wrong trailing shape, or holds
        non-finite entries while ``finite`` is true.
    """
    try:
        arr = np.asarray(value)
    except Exception as exc:  # pragma: no cover - exotic objects
        raise SolverInputError(f"{name}: cannot convert {type(value).__name__} to an array ({exc})") from exc
    if arr.dtype == object or arr.dtype.kind in "USV":
        raise SolverInputError(f"{name}: expected a numeric array {_shape_text(trailing)}, got dtype {arr.dtype}")
    if np.dtype(dtype).kind == "f" and arr.dtype.kind == "c":
        raise SolverInputError(f"{name}: expected real numbers, got complex dtype {arr.dtype}")
    n = len(trailing)
    if arr.ndim < n or tuple(arr.shape[arr.ndim - n:]) != tuple(trailing):
        raise SolverInputError(f"{name}: expected shape {_shape_text(trailing)}, got {arr.shape}")
    arr = arr.astype(dtype, copy=False)
    if finite and not np.all(np.isfinite(arr)):
        raise SolverInputError(
            f"{name}: expected finite numbers, got non-finite entries in {_preview(arr)}")
    return arr


def check_posture(posture) -> np.ndarray:
    """Return ``posture`` as an int array with every entry in 1..8, or raise.

    Raises
    ------
    SolverInputError
        If an entry is not an integer in 1..8.
    """
    arr = np.asarray(posture)
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise SolverInputError(f"posture: expected an integer in 1..8, got {posture!r}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr) & (arr == np.round(arr))):
        raise SolverInputError(f"posture: expected an integer in 1..8, got {posture!r}")
    iarr = arr.astype(np.int64)
    if np.any((iarr < 1) | (iarr > 8)):
        raise SolverInputError(f"posture: expected an integer in 1..8, got {posture!r}")
    return iarr


class Bound(NamedTuple):
    """What a scalar option may be (a row of an options table, :func:`check_number`).

    Attributes
    ----------
    integer : bool
        An integer (a bool is not one), else a real number (finite).
    low : float
        The least value.
    open : bool
        ``low`` itself is refused (> low), else allowed (>= low).
    none : bool
        None is allowed (an option that is off).
    unit : str
        The unit, for the message ("rad", "s"; "" for none).
    """

    integer: bool = False
    low: float = 0.0
    open: bool = True
    none: bool = False
    unit: str = ""

    def describe(self) -> str:
        what = "an integer" if self.integer else "a number"
        unit = f" ({self.unit})" if self.unit else ""
        return f"{what}{unit} {'>' if self.open else '>='} {self.low:g}" + (" or None" if self.none else "")


def check_number(name: str, value, bound: Bound, error=SolverInputError):
    """``value`` as a Python float or int (or None) if it is what ``bound`` allows, else raise ``error``
    (a ValueError subclass) with ``"<name>: expected <what>, got <value>"``.

    The one check of the options tables (:class:`solver.options.TrackerOptions`...).
    """
    if value is None and bound.none:
        return None
    ok = isinstance(value, (int, np.integer)) if bound.integer else isinstance(value, (int, float, np.integer,
                                                                                         np.floating))
    if ok and not isinstance(value, (bool, np.bool_)):
        v = int(value) if bound.integer else float(value)
        if math.isfinite(v) and (v > bound.low if bound.open else v >= bound.low):
            return v
    raise error(f"{name}: expected {bound.describe()}, got {value!r}")
