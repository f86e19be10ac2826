"""The classic fourth-order Runge-Kutta step, written once.

:func:`make_rk4_step` wraps a right-hand side ``rhs(ctx, t, x, slot) -> (status, dxdt)`` (status
0: accepted; ``dxdt`` written into ``slot`` or any other array) into one RK4 step.  The step is
plain Python that numba also compiles:

* compiled around the task-space right-hand side (:func:`dynamics._kernels.rows.task_rhs_row`):
  :func:`rk4_task_step`, looped by :func:`rk4_task` (:func:`dynamics.rk4` on a task-space
  right-hand side with held torques) and by the plant step (:mod:`dynamics._kernels.steps`);
* run as Python around any callable ``f(t, x)`` by :func:`dynamics.integrate.rk4_step`.

Both execute the same operations in the same order, so the results agree to the last bit.  The
vectors are ufunc results: compiled, written into preallocated arrays (``stages``, a tuple of
``RK4_STAGES`` arrays, :func:`stages_of`), so the step allocates nothing; in Python, new arrays
(:data:`PYTHON_STAGES`).  The derivatives are never written to and every stage state is its own
array, so a Python ``f`` may return (or keep) its input.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .base import code
from .layout import OK, RK4_ACC, RK4_STAGES, RK4_K1, RK4_K2, RK4_K3, RK4_K4, RK4_TMP, RK4_X2, RK4_X3, RK4_X4
from .rows import new_workspace, task_rhs_row

_mul, _add = np.multiply, np.add          # (module globals: the Python step looks them up faster)


def make_rk4_step(rhs):
    """The RK4 step around ``rhs``: ``step(ctx, t, x, h, out, stages) -> (status, out)``.

    ``out`` receives the state at ``t + h`` (it may be ``x`` itself).  If ``rhs`` refuses a stage,
    the step returns that status and ``out`` holds the stage state it refused.  In Python,
    ``out`` and the entries of ``stages`` may be None (:data:`PYTHON_STAGES`): the ufuncs then
    allocate their results, as array expressions do.
    """
    def rk4_step(ctx, t, x, h, out, stages):
        half = 0.5 * h
        st, k1 = rhs(ctx, t, x, stages[RK4_K1])
        if st != OK:
            out[:] = x
            return st, out
        x2 = _mul(k1, half, stages[RK4_X2])
        x2 = _add(x, x2, x2)
        st, k2 = rhs(ctx, t + half, x2, stages[RK4_K2])
        if st != OK:
            out[:] = x2
            return st, out
        x3 = _mul(k2, half, stages[RK4_X3])
        x3 = _add(x, x3, x3)
        st, k3 = rhs(ctx, t + half, x3, stages[RK4_K3])
        if st != OK:
            out[:] = x3
            return st, out
        x4 = _mul(k3, h, stages[RK4_X4])
        x4 = _add(x, x4, x4)
        st, k4 = rhs(ctx, t + h, x4, stages[RK4_K4])
        if st != OK:
            out[:] = x4
            return st, out
        acc = _mul(k2, 2.0, stages[RK4_ACC])      # x + h/6 (k1 + 2 k2 + 2 k3 + k4), left to right
        acc = _add(k1, acc, acc)
        tmp = _mul(k3, 2.0, stages[RK4_TMP])
        acc = _add(acc, tmp, acc)
        acc = _add(acc, k4, acc)
        acc = _mul(acc, h / 6.0, acc)
        return OK, _add(x, acc, out)
    return rk4_step


#: the ``stages`` of the Python step: every vector a new array
PYTHON_STAGES = (None,) * RK4_STAGES


@njit(cache=True)
def stages_of(buf):
    """The ``stages`` of an RK4 step of a state (6,) as views of ``buf`` (6 * ``RK4_STAGES``,)."""
    s = buf.reshape(RK4_STAGES, 6)
    return (s[RK4_K1], s[RK4_K2], s[RK4_K3], s[RK4_K4], s[RK4_X2], s[RK4_X3], s[RK4_X4], s[RK4_ACC], s[RK4_TMP])


#: one RK4 step of the task-space dynamics, ``ctx = (arm, bodies, bits, tau, q, ws)``
rk4_task_step = njit(cache=True, error_model="numpy")(make_rk4_step(task_rhs_row))


@njit(cache=True, error_model="numpy")
def rk4_task(arm, bodies, bits, tau, h, xs):
    """RK4 of the task-space dynamics with constant torques ``tau`` (3,).

    ``xs`` (n + 1, 6) holds the initial state in row 0; rows 1..n receive the states after each
    step of ``h``.  Returns :data:`OK` or the refusal code of the step refused (its index ``k``;
    row ``k + 1`` then holds the stage state that was refused).
    """
    ctx = (arm, bodies, bits, tau, np.empty(3), new_workspace())
    stages = stages_of(np.empty(6 * RK4_STAGES))
    for k in range(xs.shape[0] - 1):
        st, _ = rk4_task_step(ctx, 0.0, xs[k], h, xs[k + 1], stages)
        if st != OK:
            return code(st, k)
    return OK
