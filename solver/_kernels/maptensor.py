"""Procedure 2 (eq. 18-19) on a map tensor, compiled: the labels of the nodes near one pose,
and the label of the node nearest to it.

Shared by :meth:`solver.MapTensor.near_labels` / :meth:`~solver.MapTensor.label_at`
(batched) and the tracker's step, so there is one implementation of the procedure.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .linalg import wrap
from .scratch import floats, scratch

#: A stencil spanning fewer node offsets than this along every axis keeps its per-axis distances on the
#: stack (:mod:`.scratch`); a wider one (a map far finer than its procedure-2 radius) on the heap.
STENCIL_SPAN = 32


@njit(cache=True)
def near_mask_one(labels, origin, step, periodic, X, r2, w, stencil, out):
    """Set ``out[l]`` (7,) true for every label l of a node within weighted distance^2 ``r2`` of X.

    ``stencil`` (S, 3) int: the node offsets tried from the cell of ``X``.  Each axis's weighted
    squared distance (and the phi index, wrapped on a periodic map) is computed once per offset
    value, not once per node (the stencil is a cube: 6 values an axis for 216 nodes); a node off
    the grid gets NaN there, which no sum passes.  The same sums, in the same order, as node by node.
    """
    for l in range(7):
        out[l] = False
    nx, ny, nphi = labels.shape
    n = stencil.shape[0]
    if n == 0:
        return
    b0 = math.floor((X[0] - origin[0]) / step[0])
    b1 = math.floor((X[1] - origin[1]) / step[1])
    b2 = math.floor((X[2] - origin[2]) / step[2])
    lo0, lo1, lo2 = stencil[0, 0], stencil[0, 1], stencil[0, 2]
    hi0, hi1, hi2 = lo0, lo1, lo2
    for s in range(1, n):
        lo0, hi0 = min(lo0, stencil[s, 0]), max(hi0, stencil[s, 0])
        lo1, hi1 = min(lo1, stencil[s, 1]), max(hi1, stencil[s, 1])
        lo2, hi2 = min(lo2, stencil[s, 2]), max(hi2, stencil[s, 2])
    if max(hi0 - lo0, max(hi1 - lo1, hi2 - lo2)) < STENCIL_SPAN:     # (every map's so far: 6 an axis)
        e0, e1, e2 = floats(STENCIL_SPAN), floats(STENCIL_SPAN), \
            floats(STENCIL_SPAN)
        kk = scratch(STENCIL_SPAN, np.int64)
    else:
        e0, e1, e2 = np.empty(hi0 - lo0 + 1), np.empty(hi1 - lo1 + 1), np.empty(hi2 - lo2 + 1)
        kk = np.empty(hi2 - lo2 + 1, dtype=np.int64)
    for o in range(lo0, hi0 + 1):
        i = b0 + o
        dx = origin[0] + i * step[0] - X[0]
        e0[o - lo0] = w[0] * dx * dx if 0 <= i < nx else np.nan
    for o in range(lo1, hi1 + 1):
        j = b1 + o
        dy = origin[1] + j * step[1] - X[1]
        e1[o - lo1] = w[1] * dy * dy if 0 <= j < ny else np.nan
    for o in range(lo2, hi2 + 1):
        k = b2 + o
        dp = origin[2] + k * step[2] - X[2]
        if periodic:
            dp = wrap(dp)
            k = k % nphi
        elif k < 0 or k >= nphi:
            dp = np.nan
            k = 0
        e2[o - lo2] = w[2] * dp * dp
        kk[o - lo2] = k
    for s in range(n):
        a, c, d = stencil[s, 0] - lo0, stencil[s, 1] - lo1, stencil[s, 2] - lo2
        if e0[a] + e1[c] + e2[d] <= r2:
            out[labels[b0 + stencil[s, 0], b1 + stencil[s, 1], kk[d]]] = True


@njit(cache=True)
def label_at_one(labels, origin, step, periodic, X):
    """Label of the node nearest to X (0 outside the grid)."""
    nx, ny, nphi = labels.shape
    i = int(round((X[0] - origin[0]) / step[0]))
    j = int(round((X[1] - origin[1]) / step[1]))
    k = int(round((X[2] - origin[2]) / step[2]))
    if periodic:
        k = k % nphi
    if i < 0 or i >= nx or j < 0 or j >= ny or k < 0 or k >= nphi:
        return 0
    return labels[i, j, k]


@njit(cache=True)
def near_mask_batch(labels, origin, step, periodic, X, r2, w, stencil, out):
    """:func:`near_mask_one` of poses ``X`` (N, 3) into ``out`` (N, 7)."""
    for n in range(X.shape[0]):
        near_mask_one(labels, origin, step, periodic, X[n], r2, w, stencil, out[n])


@njit(cache=True)
def label_at_batch(labels, origin, step, periodic, X, out):
    """:func:`label_at_one` of poses ``X`` (N, 3) into ``out`` (N,)."""
    for n in range(X.shape[0]):
        out[n] = label_at_one(labels, origin, step, periodic, X[n])
