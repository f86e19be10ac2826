"""Scalar helpers of every kernel (the solver's and the dynamics'): the one angle wrap and the one
family of 3x3 linear algebra, by cofactors (determinant, Cramer's rule, the adjugate inverse), and
the identity written into a caller's array."""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def wrap(a):
    """An angle wrapped to (-pi, pi] (as :func:`solver.wrap_angle`)."""
    return math.pi - ((math.pi - a) % (2.0 * math.pi)) + 0.0


@njit(cache=False)
def identity3(out):
    """The 3x3 identity into ``out`` (3, 3) (a caller's array, often on its stack: :mod:`.scratch`)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 1.0 if i == j else 0.0


@njit(cache=True)
def turns_to(a, ref):
    """The whole turns (rad, a multiple of 2 pi) that bring the angle ``a`` nearest ``ref``."""
    return 2.0 * math.pi * round((ref - a) / (2.0 * math.pi))


@njit(cache=True)
def det3(A):
    """Determinant of a 3x3 matrix by cofactors of its first row."""
    return (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
            + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))


@njit(cache=True)
def cramer3(A, r, det, out):
    """``out = A^-1 r`` by Cramer's rule with ``det = det3(A)`` (nonzero); False if not finite."""
    out[0] = (r[0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (r[1] * A[2, 2] - A[1, 2] * r[2])
              + A[0, 2] * (r[1] * A[2, 1] - A[1, 1] * r[2])) / det
    out[1] = (A[0, 0] * (r[1] * A[2, 2] - A[1, 2] * r[2]) - r[0] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
              + A[0, 2] * (A[1, 0] * r[2] - r[1] * A[2, 0])) / det
    out[2] = (A[0, 0] * (A[1, 1] * r[2] - r[1] * A[2, 1]) - A[0, 1] * (A[1, 0] * r[2] - r[1] * A[2, 0])
              + r[0] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])) / det
    return math.isfinite(out[0]) and math.isfinite(out[1]) and math.isfinite(out[2])


@njit(cache=True)
def solve3(A, r, out):
    """Solve ``A x = r`` (3x3) into ``out``; False if ``A`` is singular or the solution not finite."""
    det = det3(A)
    if det == 0.0 or not math.isfinite(det):
        return False
    return cramer3(A, r, det, out)


@njit(cache=True)
def row_ratio(A, det):
    """``|det| / prod |rows of A|`` for ``det = det3(A)``: 0 singular, 1 for orthogonal rows."""
    norm = 1.0
    for i in range(3):
        norm *= math.sqrt(A[i, 0] ** 2 + A[i, 1] ** 2 + A[i, 2] ** 2)
    return abs(det) / norm if norm > 0 else 0.0


@njit(cache=True)
def hadamard(A):
    """The Hadamard ratio ``|det A| / prod |rows of A|`` (0 at a singularity, 1 at best)."""
    return row_ratio(A, det3(A))


@njit(cache=True)
def inverse3(A, out):
    """``out = A^-1`` (3, 3) by the adjugate over ``det3(A)``; False if ``A`` is singular or the
    inverse not finite (``out`` then partly written)."""
    det = det3(A)
    if det == 0.0 or not math.isfinite(det):
        return False
    r = 1.0 / det
    out[0, 0] = (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) * r
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * r
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * r
    out[1, 0] = (A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]) * r
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * r
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * r
    out[2, 0] = (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]) * r
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * r
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * r
    for i in range(3):
        for j in range(3):
            if not math.isfinite(out[i, j]):
                return False
    return True


@njit(cache=True)
def inverse3_flat(w, src, dst):
    """``w[dst:dst+9]`` = the inverse of the 3x3 matrix ``w[src:src+9]`` (row-major, in a flat workspace:
    the interval kernels' layout), the same adjugate as :func:`inverse3`; False if singular."""
    a, b_, c = w[src], w[src + 1], w[src + 2]
    d, e, f = w[src + 3], w[src + 4], w[src + 5]
    g, h, k = w[src + 6], w[src + 7], w[src + 8]
    A, B, C = e * k - f * h, f * g - d * k, d * h - e * g
    det = a * A + b_ * B + c * C
    if det == 0.0 or not math.isfinite(det):
        return False
    r = 1.0 / det
    w[dst], w[dst + 1], w[dst + 2] = A * r, (c * h - b_ * k) * r, (b_ * f - c * e) * r
    w[dst + 3], w[dst + 4], w[dst + 5] = B * r, (a * k - c * g) * r, (c * d - a * f) * r
    w[dst + 6], w[dst + 7], w[dst + 8] = C * r, (b_ * g - a * h) * r, (a * e - b_ * d) * r
    return True
