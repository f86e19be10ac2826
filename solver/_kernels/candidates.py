"""The tracker's candidate set after a step, compiled: the DK solutions the true branch can be.

:func:`certify` narrows the candidates with chains of Krawczyk boxes (:mod:`.certify`).
One candidate: a forward chain from it names its continuation (with measured joints,
first along the tube: the proof that keeps the chain of certificates intact;
:func:`continue_single`).  Otherwise each real solution of the new joints is followed
backwards; one that provably comes from a non-candidate is dropped (:func:`eliminate`).
Finally, if several remain and the tracker knows its posture, those of another posture
are dropped (:func:`keep_posture`).  The answer is vouched for when one candidate remains.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .certify import (CERT_CONTINUATION, CERT_ELIMINATION, CERT_NONE, CERT_POSTURE, elbow_bits, follow_back,
                      follow_branch, same_pose)
from .kinematics import geometry
from .scratch import floats, scratch


@njit(cache=True)
def certify(cands, n_cand, verified, intact, qp, dq, d2_par, have_par, eps, poses, real, posture_bits, max_tests,
            model_pack, new_cands, keep, deadline=0.0):
    """The candidate set after one step (see the module docstring).

    cands (6, 3): the candidates at ``qp`` (``n_cand`` of them; ``verified``: the
    single one is the end of a chain).  dq (3,): the wrapped joint step;
    d2_par (3,): the parabola's quadratic term (used when ``have_par``).
    poses (6, 3) complex / real (6,): the DK solutions at ``qp + dq``.
    posture_bits: the tracker's posture - 1, or -1 for no posture certificate.
    Writes the new candidates to ``new_cands`` (6, 3) (verified chain ends when
    one remains by continuation) and, in ``keep`` (6,), which solutions they are.
    Returns (number of candidates, certificate code, chain intact, linked): ``linked``
    when the one candidate left is joined to a previous candidate by a chain of boxes
    along the measured joints (forwards, or backwards in elimination), so that the
    segment between the samples crossed no fold on its way.
    """
    M, l1, l2sq, b = geometry(model_pack)
    d1_par = floats(3)
    qu = floats(3)
    for i in range(3):
        d1_par[i] = dq[i] - d2_par[i]
        qu[i] = qp[i] + dq[i]
    n_paths = 2 if have_par else 1
    for k in range(6):
        keep[k] = False
    if n_cand == 1:
        p = continue_single(cands[0], verified, eps > 0.0 and intact, qp, dq, d1_par, d2_par, n_paths, eps, poses,
                            real, max_tests, M, l1, b, l2sq, new_cands, keep, deadline)
        if p >= 0:
            return 1, CERT_CONTINUATION, eps == 0.0 or p == 0, True
    linked = scratch(6, np.bool_)               # followed back to a candidate
    linked[:] = False
    n_new = eliminate(cands, n_cand, qu, dq, d1_par, d2_par, n_paths, poses, real, max_tests, M, l1, b, l2sq,
                      new_cands, keep, linked, deadline)
    code = CERT_ELIMINATION
    if n_new > 1 and posture_bits >= 0:
        n_post = keep_posture(poses, qu, posture_bits, M, l1, b, new_cands, keep)
        if n_post >= 1:
            n_new, code = n_post, CERT_POSTURE
    if n_new == 0:                                  # nothing consistent (cannot happen in exact arithmetic)
        for k in range(6):
            if real[k]:
                keep[k] = True
                for i in range(3):
                    new_cands[n_new, i] = poses[k, i].real
                n_new += 1
    sole_linked = False
    if n_new == 1:
        for k in range(6):
            sole_linked = sole_linked or (keep[k] and linked[k])
    return n_new, code if n_new == 1 else CERT_NONE, eps == 0.0, sole_linked


@njit(cache=False)
def continue_single(X0, verified, tube_first, qp, dq, d1_par, d2_par, n_paths, eps, poses, real, max_tests,
                    M, l1, b, l2sq, new_cands, keep, deadline):
    """Continuation: a forward chain from the one candidate ``X0`` (3,) names its continuation.

    Paths tried in turn: with ``tube_first`` (measured joints, chain intact) the tube of
    joint paths within ``eps`` of the segment (path 0, the proof that keeps the chain
    intact), then the segment itself (path 1) and, with ``n_paths = 2``, the parabola
    ``qp + s d1_par + s^2 d2_par`` (path 2).  The first chain that ends on exactly one real
    solution of ``poses`` (6, 3) complex / ``real`` (6,) marks it in ``keep`` (6,) and puts the
    chain's end in ``new_cands[0]``.  Returns that path's index, or -1 when none does.
    """
    zero = floats(3)
    zero[:] = 0.0
    end = floats(3)
    Xr = floats(3)
    for p in range(0 if tube_first else 1, n_paths + 1):
        d1 = dq if p <= 1 else d1_par
        d2 = zero if p <= 1 else d2_par
        if follow_branch(X0, verified, qp, d1, d2, eps if p == 0 else 0.0, M, l1, b, l2sq, max_tests, end,
                         deadline) > 0:
            hit = -1
            for k in range(6):
                if real[k]:
                    for i in range(3):
                        Xr[i] = poses[k, i].real
                    if same_pose(Xr, end):
                        hit = k if hit < 0 else 6          # 6: two solutions match (cannot tell)
            if 0 <= hit < 6:
                keep[hit] = True
                new_cands[0, :] = end
                return p
    return -1


@njit(cache=False)
def eliminate(cands, n_cand, qu, dq, d1_par, d2_par, n_paths, poses, real, max_tests, M, l1, b, l2sq, new_cands,
              keep, linked, deadline):
    """Elimination: every real solution at ``qu`` followed back along the segment (then, when its
    chain does not close, the parabola); one whose chain provably ends at a non-candidate of
    ``cands[:n_cand]`` is dropped.  The others are marked in ``keep`` (6,) and listed in
    ``new_cands`` (6, 3); ``linked`` (6,) marks those whose chain ended on a candidate.
    Returns how many are kept."""
    zero = floats(3)
    zero[:] = 0.0
    Xr = floats(3)
    n_new = 0
    for k in range(6):
        if not real[k]:
            continue
        for i in range(3):
            Xr[i] = poses[k, i].real
        kept = True
        followed = False
        for p in range(n_paths):
            # the same path backwards (the segment, then the parabola)
            came = follow_back(Xr, qu, dq if p == 0 else d1_par, zero if p == 0 else d2_par, cands, n_cand,
                               max_tests, M, l1, b, l2sq, deadline)
            if came >= 0:
                kept = followed = came == 1
                break
        if kept:
            linked[k] = followed
            keep[k] = True
            new_cands[n_new, :] = Xr
            n_new += 1
    return n_new


@njit(cache=False)
def keep_posture(poses, qu, posture_bits, M, l1, b, new_cands, keep):
    """Posture: of the solutions marked in ``keep`` (6,), those whose elbows are in the posture
    ``posture_bits`` + 1 at the joints ``qu``.  When at least one is, ``keep`` and ``new_cands``
    (6, 3) are narrowed to them; returns how many are (0: nothing changed)."""
    Xr = floats(3)
    in_posture = scratch(6, np.bool_)           # kept candidates in the tracker's posture
    in_posture[:] = False
    n_post = 0
    for k in range(6):
        if keep[k]:
            for i in range(3):
                Xr[i] = poses[k, i].real
            in_posture[k] = elbow_bits(Xr, qu, M, l1, b) == posture_bits
            n_post += in_posture[k]
    if n_post >= 1:
        n_new = 0
        for k in range(6):
            keep[k] = in_posture[k]
            if keep[k]:
                for i in range(3):
                    new_cands[n_new, i] = poses[k, i].real
                n_new += 1
    return n_post
