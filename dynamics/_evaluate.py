"""How the public functions of :mod:`dynamics` run the compiled kernels (private).

Each public term runs one batch kernel of :mod:`dynamics._kernels.rows` over rows ``(n, 3)``.  A
single configuration (float64 arrays of shape (3,)) is a batch of one and skips the numpy
argument checks, which the kernel replaces by its own (finite inputs, inverse kinematics, loop
closure, non-singular matrices); other inputs are checked and broadcast first.  A refusal raises
:class:`dynamics.DynamicsError` (:func:`dynamics.errors.refused`).  The packs of the model, the
parameters and the gains are the explicit data of :mod:`dynamics._packs` (built once per object).
"""
from __future__ import annotations

import math

import numpy as np

from solver import as_array

from ._checks import as_rows, broadcast, check_pair, ik_or_raise, is_single, posture_bits
from ._kernels import control as _control, rows as _rows
from ._kernels.layout import MASS
from .errors import refused
from .geometry import ASSEMBLY_TOL
from ._packs import arm_pack, bodies_pack, gains_pack


def _rows_of(arrays):
    """``(lead, n, rows)``: the leading shape, the row count and the (n, 3) rows of ``arrays``
    broadcast together (a single configuration's arrays (3,) are reshaped in place by the callers,
    the path every 1 ms call takes)."""
    b = np.broadcast_arrays(*arrays)
    lead = b[0].shape[:-1]
    n = math.prod(lead)
    return lead, n, [as_rows(a, n) for a in b]


def _result(mode, lead, n):
    """Result array ``lead + (3, 3)`` (mass matrices) or ``lead + (3,)`` and its (n, k) row view."""
    k = 9 if mode == MASS else 3
    out = np.empty(lead + ((3, 3) if k == 9 else (3,)))
    return out, out.reshape(n, k)


# ----------------------------------------------------------------------------- task space
def evaluate_task(params, model, mode, posture, arrays: dict, q=None, single=None, bits=None):
    """Task-space term ``mode`` of checked ``arrays`` (``X``, then ``dX``, then ``tau`` or ``ddX``).

    ``q`` (the motor angles) is read if given, else computed by the kernel's inverse kinematics
    in ``posture`` (a plain integer; ``bits``: its elbow bits if known).
    """
    vals = tuple(arrays.values())
    X = vals[0]
    dX = vals[1] if len(vals) > 1 else X        # unused by the modes without it
    U = vals[2] if len(vals) > 2 else X
    if q is None:
        bits = posture_bits(posture) if bits is None else bits
    else:
        bits = -1
    if single is None:
        single = is_single((X, dX, U) if q is None else (X, dX, U, q))
    if single:
        lead, n = (), 1
        X, dX, U = X.reshape(1, 3), dX.reshape(1, 3), U.reshape(1, 3)
        q = np.empty((1, 3)) if q is None else q.reshape(1, 3)
    elif q is None:
        lead, n, (X, dX, U) = _rows_of((X, dX, U))
        q = np.empty((n, 3))
    else:
        lead, n, (X, dX, U, q) = _rows_of((X, dX, U, q))
    out, rows = _result(mode, lead, n)
    code = _rows.task_batch(arm_pack(model), bodies_pack(params), X, dX, U, q, bits, mode, rows)
    if code:
        raise refused(code, arrays, model=model, posture=posture, lead=lead)
    return out


def task_term(params, model, mode, posture, **arrays):
    """A public task-space function: ``arrays`` are its arguments in order, ``X`` first."""
    check_pair(params, model)
    bits = posture_bits(posture)
    if bits >= 0 and is_single(arrays.values()):
        return evaluate_task(params, model, mode, posture, arrays, None, True, bits)
    arrays = dict(zip(arrays, broadcast(**{k: as_array(k, v) for k, v in arrays.items()})))
    q = ik_or_raise(model, arrays["X"], posture) if bits < 0 else None
    return evaluate_task(params, model, mode, posture, arrays, q, False, bits)


# ----------------------------------------------------------------------------- joint space
def evaluate_joint(params, model, mode, arrays: dict, check=True, single=None):
    """Joint-space term ``mode`` of checked ``arrays`` (``q``, ``X`` and, as the mode needs,
    ``dq`` and ``tau`` or ``ddq``); ``check``: refuse a pose that does not close the loops."""
    q = arrays["q"]
    rows_in = (q, arrays.get("dq", q), arrays["X"], arrays.get("tau", arrays.get("ddq", q)))
    if single or (single is None and is_single(rows_in)):
        lead, n = (), 1
        rows_in = (rows_in[0].reshape(1, 3), rows_in[1].reshape(1, 3), rows_in[2].reshape(1, 3),
                   rows_in[3].reshape(1, 3))
    else:
        lead, n, rows_in = _rows_of(rows_in)
    out, rows = _result(mode, lead, n)
    code = _rows.joint_batch(arm_pack(model), bodies_pack(params), *rows_in, ASSEMBLY_TOL if check else math.inf,
                             mode, rows)
    if code:
        raise refused(code, arrays, model=model, lead=lead)
    return out


def joint_term(params, model, mode, **arrays):
    """A public joint-space function: ``arrays`` are its arguments in order."""
    check_pair(params, model)
    single = is_single(arrays.values())
    if not single:
        arrays = dict(zip(arrays, broadcast(**{k: as_array(k, v) for k, v in arrays.items()})))
    return evaluate_joint(params, model, mode, arrays, True, single)


def evaluate_computed_torque(params, model, gains, arrays: dict, single=None):
    """The computed-torque law of checked ``arrays`` (``q, dq, X, q_d, dq_d, ddq_d``)."""
    rows_in = tuple(arrays.values())
    if single or (single is None and is_single(rows_in)):
        lead, n = (), 1
        rows_in = [a.reshape(1, 3) for a in rows_in]
    else:
        lead, n, rows_in = _rows_of(rows_in)
    out = np.empty(lead + (3,))
    code = _control.computed_torque_batch(arm_pack(model), bodies_pack(params), gains_pack(gains), *rows_in,
                                       ASSEMBLY_TOL, out.reshape(n, 3))
    if code:
        raise refused(code, arrays, model=model, lead=lead)
    return out
