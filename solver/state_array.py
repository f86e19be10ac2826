"""The serialised form of a :class:`solver.tracker_state.TrackerState`: where each field sits in
:meth:`TrackerState.as_array` (:data:`STATE_FLOATS` floats), and the checks a saved array's parts
pass before they reach the compiled kernels (which do not check their bounds).
"""
from __future__ import annotations

import numpy as np

from ._kernels.anytime import (ANY_C_K, ANY_C_STAGE, ANY_K_KIND, ANY_K_N_PATH, ANY_K_ON, ANY_K_PATH, ANY_LAST, ANY_N,
                               ANY_N_PATH, ANY_PATH, ANY_PIECES, ANY_R_F, ANY_R_K, ANY_R_N, ANY_R_N_PATH, ANY_R_ON,
                               ANY_R_PATH, ANY_R_PROG, ANY_SIZE, MAX_KPATH, MAX_PATH, N_STAGES, walk_floats)
from ._kernels.exclusion import HULL_FACTORS, PREIMAGE_STACK
from ._kernels.layout import PAVE_BOXES
from ._kernels.reacquisition import REACQUIRE_COVERS
from ._kernels.state_layout import (STATE_FLOATS, _AGE, _ANCHOR, _ANCHOR_BOUND, _A_SCALE, _BASE, _CANDS,  # noqa: F401
                                    _CLEAN_LAG, _CLEAN_TIME, _DQ_SCALE, _DT, _FINITE, _INTACT, _N_CAND, _N_PAVE,
                                    _N_TUBES, _PAVE, _Q, _Q2, _READING, _REFUSED, _REPEATS, _SINCE, _SKIPPED,
                                    _SKIPPED_TIME, _STEPS, _TUBE, _VERIFIED, _WALK, _X, _X2)
from ._kernels.tube import TUBE_SIZE
from ._kernels.tube_chain import MAX_COVER, MAX_PIECES


class TrackerError(ValueError):
    """A tracker used wrongly (no state yet, a map of another geometry...)."""


def _saved_cover(a: np.ndarray) -> np.ndarray | None:
    """The cover of tubes of a saved state (:meth:`TrackerState.as_array`), None when it has none."""
    n = int(a[_N_TUBES]) if np.isfinite(a[_N_TUBES]) else 0
    if not 1 <= n <= MAX_COVER:
        return None
    cover = a[_TUBE:_TUBE + n * TUBE_SIZE].reshape(n, TUBE_SIZE).copy()
    if not np.all(np.isfinite(cover)):
        raise TrackerError(f"state: {n} tubes expected, got non-finite values")
    return cover


def _saved_paving(a: np.ndarray) -> np.ndarray | None:
    """The paving of a saved state (:meth:`TrackerState.as_array`), None when it has none."""
    n = a[_N_PAVE]
    if n == 0:
        return None
    paving = a[_PAVE:_PAVE + 6 * int(n)].reshape(-1, 6).copy() if n == int(n) and 1 <= n <= PAVE_BOXES else None
    if paving is None or not np.all(np.isfinite(paving)) or np.any(paving[:, 0::2] > paving[:, 1::2]) \
            or (a[_SINCE] < 0 and a[_N_TUBES] > 0) or np.any(np.isnan(a[_ANCHOR:_ANCHOR + 3])):
        raise TrackerError(f"state: a paving of 1 to {PAVE_BOXES} pose boxes (lo <= hi) with an anchor, of an "
                           f"uncertain state or a certain one without tubes (re-acquired by the eliminant) "
                           f"expected, got {n:g} boxes "
                           f"{np.array2string(a[_PAVE:_PAVE + 12], threshold=12)}... (uncertain_since {a[_SINCE]:g})")
    return paving


def _saved_seconds(a: np.ndarray, i: int, name: str) -> float:
    """A saved span of time (s): >= 0, or NaN (unknown); :class:`TrackerError` otherwise."""
    v = float(a[i])
    if not (np.isnan(v) or (np.isfinite(v) and v >= 0.0)):
        raise TrackerError(f"state: {name} expected seconds >= 0 or NaN (unknown), got {v!r}")
    return v


def _saved_walk(a: np.ndarray, state) -> np.ndarray | None:
    """The walk of a saved state (the floats after its clean state), checked: None when there is none;
    :class:`TrackerError` when it is not one the tracker can have left at ``state.q`` (a corrupt state
    must not reach the kernels, which do not check their bounds)."""
    if np.isnan(a[ANY_N]):
        return None
    head = a[:ANY_PIECES]
    n, k, stage = head[ANY_N], head[ANY_C_K], head[ANY_C_STAGE]
    ok = (np.all(np.isfinite(head)) and n == int(n) and 0 <= n <= MAX_PIECES and k == int(k) and stage == int(stage)
          and 0 <= stage < N_STAGES and 0 <= k and n + k <= MAX_PIECES
          and (n > 0 or head[ANY_K_ON] > 0 or head[ANY_R_ON] > 0))
    if ok and n > 0:
        m = int(head[ANY_N_PATH])
        ok = head[ANY_N_PATH] == m and 2 <= m <= MAX_PATH and 0 <= head[ANY_LAST] < n and \
            _same_angles(head[ANY_PATH + 3 * (m - 1):ANY_PATH + 3 * m], state.q)
    if ok and head[ANY_K_ON] > 0:
        m = int(head[ANY_K_N_PATH])
        ok = head[ANY_K_N_PATH] == m and 1 <= m <= MAX_KPATH and head[ANY_K_KIND] in (1.0, 2.0) and \
            _same_angles(head[ANY_K_PATH + 3 * (m - 1):ANY_K_PATH + 3 * m], state.q)
    if ok and head[ANY_R_ON] > 0:
        ok = _saved_reacquisition(head, state.q)
    walk = a[:walk_floats(head)].copy() if ok else None
    if walk is None or not np.all(np.isfinite(walk)) or state.tube is not None:
        raise TrackerError(f"state: the walk of an unfinished proof expected after the clean state, at the "
                           f"joints {state.q.tolist()} of an uncertain state, got "
                           f"{np.array2string(a[:12], threshold=12)}...")
    return walk


def _saved_reacquisition(head: np.ndarray, q) -> bool:
    """The re-acquisition under way in a saved anytime pack ``head`` is one the tracker can have left at ``q``."""
    def whole(v, lo, hi):
        return v == int(v) and lo <= v <= hi
    m = head[ANY_R_N_PATH]
    return (whole(head[ANY_R_ON], 1, REACQUIRE_COVERS + 1) and whole(head[ANY_R_N], 0, MAX_COVER)
            and whole(head[ANY_R_K], 0, max(head[ANY_R_N] - 1, 0)) and whole(head[ANY_R_F], 0, len(HULL_FACTORS) - 1)
            and whole(head[ANY_R_PROG], 0, PREIMAGE_STACK) and whole(head[ANY_R_PROG + 1], 0, np.inf)
            and whole(m, 1, MAX_PATH) and _same_angles(head[ANY_R_PATH + 3 * (int(m) - 1):ANY_R_PATH + 3 * int(m)], q))


def _same_angles(a, b) -> bool:
    """The joints ``a`` and ``b`` (3,) are the same up to whole turns."""
    d = np.asarray(a) - np.asarray(b)
    return bool(np.all(np.abs(d - 2 * np.pi * np.round(d / (2 * np.pi))) < 1e-9))
