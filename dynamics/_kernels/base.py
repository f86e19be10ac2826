"""Compiled building blocks shared by the kernels: angle wrap, finiteness, refusal codes, 3x3
linear systems by Gaussian elimination, and the work arrays of one configuration."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .layout import (OK, STATUS_SPAN, WS_AUG, WS_BETA, WS_FORCES, WS_JQ, WS_JX, WS_LEG, WS_M, WS_MX, WS_SIZE,
                     WS_U, WS_V, WS_V3, WS_VJ)

TWO_PI = 2.0 * math.pi


# ----------------------------------------------------------------------------- helpers
@njit(cache=True, error_model="numpy")
def wrap_angle(a):
    """``pi - mod(pi - a, 2 pi)``: angle in (-pi, pi] (numpy's mod, the sign of the divisor)."""
    return math.pi - (math.pi - a) % TWO_PI


@njit(cache=True, error_model="numpy")
def finite(v):
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@njit(cache=True)
def code(status, index):
    """The refusal code of ``status`` at ``index`` (``OK`` stays 0)."""
    return status if status == OK else status + STATUS_SPAN * index


@njit(cache=True, error_model="numpy")
def gauss(aug, m):
    """Solve in place the 3x3 system of ``aug`` (3, 3 + m) for its ``m`` right-hand columns.

    Gaussian elimination with partial pivoting (the largest pivot of the column, as LAPACK's
    getrf); the solution overwrites the right-hand columns.  False if a pivot is exactly zero.
    """
    nc = 3 + m
    for c in range(3):
        p = c
        big = abs(aug[c, c])
        for r in range(c + 1, 3):
            if abs(aug[r, c]) > big:
                big, p = abs(aug[r, c]), r
        if big == 0.0:
            return False
        if p != c:
            for j in range(c, nc):
                aug[c, j], aug[p, j] = aug[p, j], aug[c, j]
        for r in range(c + 1, 3):
            f = aug[r, c] / aug[c, c]
            for j in range(c + 1, nc):
                aug[r, j] -= f * aug[c, j]
    for j in range(3, nc):
        for r in range(2, -1, -1):
            s = aug[r, j]
            for k in range(r + 1, 3):
                s -= aug[r, k] * aug[k, j]
            aug[r, j] = s / aug[r, r]
    return True


@njit(cache=True, error_model="numpy")
def solve(A, transpose, b, x, aug):
    """``x = A^{-1} b`` (or ``A^{-T} b``) for a 3x3 ``A``; False if singular."""
    for r in range(3):
        for c in range(3):
            aug[r, c] = A[c, r] if transpose else A[r, c]
        aug[r, 3] = b[r]
    if not gauss(aug, 1):
        return False
    for r in range(3):
        x[r] = aug[r, 3]
    return True


@njit(cache=True, error_model="numpy")
def inverse(A, Ainv, aug):
    """``Ainv = A^{-1}`` for a 3x3 ``A``; False if singular."""
    for r in range(3):
        for c in range(3):
            aug[r, c] = A[r, c]
            aug[r, 3 + c] = 1.0 if r == c else 0.0
    if not gauss(aug, 3):
        return False
    for r in range(3):
        for c in range(3):
            Ainv[r, c] = aug[r, 3 + c]
    return True


@njit(cache=True, inline="always")
def workspace(buf):
    """The work arrays of one configuration as views of ``buf`` (``WS_SIZE``,): leg table (9, 3),
    J_q, J_x, V (21, 3), beta (21,), M_X, M, forces (6, 3), V J_x (21, 3), elimination scratch
    (3, 6) and two 3-vectors."""
    return (buf[WS_LEG:WS_JQ].reshape(9, 3), buf[WS_JQ:WS_JX].reshape(3, 3), buf[WS_JX:WS_V].reshape(3, 3),
            buf[WS_V:WS_BETA].reshape(21, 3), buf[WS_BETA:WS_MX], buf[WS_MX:WS_M].reshape(3, 3),
            buf[WS_M:WS_FORCES].reshape(3, 3), buf[WS_FORCES:WS_VJ].reshape(6, 3), buf[WS_VJ:WS_AUG].reshape(21, 3),
            buf[WS_AUG:WS_U].reshape(3, 6), buf[WS_U:WS_V3], buf[WS_V3:WS_SIZE])


@njit(cache=True)
def new_workspace():
    """:func:`workspace` of a new buffer."""
    return workspace(np.empty(WS_SIZE))
