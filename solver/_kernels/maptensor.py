"""Procedure 2 (eq. 18-19) on a map tensor, compiled: the labels of the nodes near one pose,
and the label of the node nearest to it.

Shared by :meth:`solver.MapTensor.near_labels` / :meth:`~solver.MapTensor.label_at`
(batched) and the tracker's step, so there is one implementation of the procedure.
"""
from __future__ import annotations

import math

from numba import njit

from .linalg import wrap


@njit(cache=True)
def near_mask_one(labels, origin, step, periodic, X, r2, w, stencil, out):
    """Set ``out[l]`` (7,) true for every label l of a node within weighted distance^2 ``r2`` of X."""
    for l in range(7):
        out[l] = False
    nx, ny, nphi = labels.shape
    b0 = math.floor((X[0] - origin[0]) / step[0])
    b1 = math.floor((X[1] - origin[1]) / step[1])
    b2 = math.floor((X[2] - origin[2]) / step[2])
    for s in range(stencil.shape[0]):
        i = b0 + stencil[s, 0]
        j = b1 + stencil[s, 1]
        k = b2 + stencil[s, 2]
        if i < 0 or i >= nx or j < 0 or j >= ny:
            continue
        dx = origin[0] + i * step[0] - X[0]
        dy = origin[1] + j * step[1] - X[1]
        dp = origin[2] + k * step[2] - X[2]
        if periodic:
            dp = wrap(dp)
            k = k % nphi
        elif k < 0 or k >= nphi:
            continue
        if w[0] * dx * dx + w[1] * dy * dy + w[2] * dp * dp <= r2:
            out[labels[i, j, k]] = True


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
