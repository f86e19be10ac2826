"""Re-acquiring the branch with measured joints: a global proof that one posture-P solution exists.

With exact joints the tracker regains certainty by eliminating candidates along the joint
path (:mod:`.certify`).  With measured joints that history proves nothing once a sample
may lie past a fold the robot did not cross, so the tracker regains certainty from the
present sample alone: for every joint vector ``q`` in the box ``Q = q_meas +- eps``,

1. a Krawczyk box ``B`` about the chosen solution holds exactly one solution of
   ``F(., q) = 0`` (:func:`.certify.prove_part`), and
2. every pose of the tool space whose inverse kinematics *in the tracker's posture* lands in
   ``Q`` lies inside ``B`` (:func:`posture_preimage_in`): a branch and bound over the tool
   space that drops pose boxes whose interval inverse kinematics misses ``Q`` (or whose legs
   cannot reach) and pose boxes inside ``B``.

The robot is in the tracker's posture and its true joints are in ``Q``, so its pose is the
one solution in ``B``, and the chosen solution of the measured joints is on its branch.
Interval ends are padded by :data:`.certify.PAD` as in :mod:`.certify`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .certify import TINY, elbow_bits, prove_part, same_pose
from .clock import expired
from .kinematics import geometry, leg_offset, leg_slack
from .krawczyk import PAD, TWO_PI, W_SIZE, _smul, icos, isin, krawczyk
from .scratch import floats, scratch2
from .tube import (TUBE_K, TUBE_Q, TUBE_R, TUBE_S, TUBE_SIZE, TUBE_T, TUBE_V, TUBE_W, TUBE_X, set_spread, slab_test,
                   tube_test)
from .tube_chain import cover_box, needle_frame, slab_cover

#: Smallest half-width (m, m, rad) of a hull the exclusion works with: the branch and bound cannot
#: separate poses from a box far smaller than the region's own scale.
HULL_MIN = 1e-6
#: The box about a needle the exclusion tries, in times its hull: the widest first.
HULL_FACTORS = (3.0, 1.5)


@njit(cache=True)
def _sq(lo, hi):
    """An enclosure of x^2 over [lo, hi]."""
    if lo >= 0.0:
        return lo * lo, hi * hi
    if hi <= 0.0:
        return hi * hi, lo * lo
    return 0.0, max(lo * lo, hi * hi)


@njit(cache=True)
def leg_misses(box, i, sign, qlo_t, qhi_t, M, l1, l2sq, b):
    """True when no pose of ``box`` (x lo/hi, y lo/hi, phi lo/hi) reaches joint ``q_i`` in
    [qlo_t, qhi_t] (mod 2 pi) with elbow sign ``sign`` (+1 or -1), or leg ``i`` cannot reach it."""
    clo, chi = icos(box[4], box[5])
    slo, shi = isin(box[4], box[5])
    a1lo, a1hi = _smul(b[i, 0], clo, chi)
    a2lo, a2hi = _smul(-b[i, 1], slo, shi)
    dxlo, dxhi = box[0] + a1lo + a2lo - M[i, 0] - PAD, box[1] + a1hi + a2hi - M[i, 0] + PAD
    a1lo, a1hi = _smul(b[i, 0], slo, shi)
    a2lo, a2hi = _smul(b[i, 1], clo, chi)
    dylo, dyhi = box[2] + a1lo + a2lo - M[i, 1] - PAD, box[3] + a1hi + a2hi - M[i, 1] + PAD
    if l2sq[i] < 0.0:                                   # a prismatic leg: its length is |A_i - M_i|
        x2lo, x2hi = _sq(dxlo, dxhi)
        y2lo, y2hi = _sq(dylo, dyhi)
        return math.sqrt(x2hi + y2hi) + PAD < qlo_t or math.sqrt(x2lo + y2lo) - PAD > qhi_t
    if dxlo <= 0.0 <= dxhi and dylo <= 0.0 <= dyhi:
        return False                                    # the motor may be inside: no bound on the angle
    # the angle of M_i -> A_i: extreme at the corners of a box that does not hold the origin
    tc = math.atan2(0.5 * (dylo + dyhi), 0.5 * (dxlo + dxhi))
    tlo, thi = np.inf, -np.inf
    for cx in (dxlo, dxhi):
        for cy in (dylo, dyhi):
            d = math.atan2(cy, cx) - tc
            d -= TWO_PI * math.floor((d + math.pi) / TWO_PI)
            tlo, thi = min(tlo, tc + d), max(thi, tc + d)
    tlo, thi = tlo - PAD, thi + PAD
    x2lo, x2hi = _sq(dxlo, dxhi)
    y2lo, y2hi = _sq(dylo, dyhi)
    rlo, rhi = math.sqrt(x2lo + y2lo), math.sqrt(x2hi + y2hi)
    if rlo < 1e-9:
        return False
    # cos alpha = (c0 + rho^2) / (2 l1 rho), c0 = l1^2 - l2^2 (the robot as built: l2^2 within sigma):
    # largest at an end of [rlo, rhi], smallest at an end or at rho^2 = c0 (its minimum when c0 > 0)
    slack = leg_slack(l2sq, i)
    c0lo, c0hi = l1[i] * l1[i] - l2sq[i] - slack, l1[i] * l1[i] - l2sq[i] + slack
    k2 = 2.0 * l1[i]
    flo = min((c0lo + rlo * rlo) / (k2 * rlo), (c0lo + rhi * rhi) / (k2 * rhi))
    fhi = max((c0hi + rlo * rlo) / (k2 * rlo), (c0hi + rhi * rhi) / (k2 * rhi))
    if c0lo > 0.0:
        rs = math.sqrt(c0lo)
        if rlo < rs < rhi:
            flo = min(flo, rs / l1[i])
    flo, fhi = flo - 1e-12, fhi + 1e-12
    if flo > 1.0 or fhi < -1.0:
        return True                                     # the leg cannot reach any pose of the box
    alo, ahi = math.acos(min(1.0, fhi)) - PAD, math.acos(max(-1.0, flo)) + PAD
    if sign > 0.0:
        qlo, qhi = tlo - ahi, thi - alo
    else:
        qlo, qhi = tlo + alo, thi + ahi
    e = leg_offset(l2sq, i)
    if e > 0.0:
        # the robot as built is in the posture, the model at its pose and joints may not be: the elbow's
        # sign is that of the crank's cross product with A_i - M_i, which the geometry moves by at most e:
        # the model's signed elbow angle lies within delta = asin(e / rho) beyond [0, pi]
        delta = math.asin(min(1.0, e / rlo)) + PAD if e < rlo else math.pi
        if alo < delta:
            if sign > 0.0:
                qhi = max(qhi, thi + delta)
            else:
                qlo = min(qlo, tlo - delta)
        if ahi > math.pi - delta:
            if sign > 0.0:
                qlo = min(qlo, tlo - math.pi - delta)
            else:
                qhi = max(qhi, thi + math.pi + delta)
    n_lo = math.ceil((qlo_t - qhi) / TWO_PI)
    n_hi = math.floor((qhi_t - qlo) / TWO_PI)
    return n_lo > n_hi


@njit(cache=True)
def _inside(box, c, rho):
    """The pose box lies inside the box ``c +- rho`` (phi compared modulo 2 pi)."""
    if not (box[0] >= c[0] - rho[0] and box[1] <= c[0] + rho[0] and box[2] >= c[1] - rho[1]
            and box[3] <= c[1] + rho[1]):
        return False
    for n in (-1.0, 0.0, 1.0):
        if box[4] + n * TWO_PI >= c[2] - rho[2] and box[5] + n * TWO_PI <= c[2] + rho[2]:
            return True
    return False


@njit(cache=True)
def in_region(X, region):
    """The pose ``X`` (3,) lies in the region (x, y, phi lo/hi; phi compared modulo 2 pi)."""
    if not (region[0] <= X[0] <= region[1] and region[2] <= X[1] <= region[3]):
        return False
    for n in (-1.0, 0.0, 1.0):
        if region[4] <= X[2] + n * TWO_PI <= region[5]:
            return True
    return False


@njit(cache=False)
def posture_misses(box, q, eps, posture_bits, M, l1, l2sq, b):
    """No pose of ``box`` (6,) reaches ``q +- eps`` (3,) in posture ``posture_bits + 1``: some leg misses."""
    for i in range(3):
        sign = 1.0 - 2.0 * ((posture_bits >> i) & 1)
        if leg_misses(box, i, sign, q[i] - eps, q[i] + eps, M, l1, l2sq, b):
            return True
    return False


@njit(cache=False)
def bisect(stack, top, box, k):
    """Push the two halves of ``box`` (6,) split across coordinate pair ``k`` (0, 2, 4) onto ``stack``
    above ``top``; returns the new top."""
    mid = 0.5 * (box[k] + box[k + 1])
    stack[top, :] = box
    stack[top, k + 1] = mid
    stack[top + 1, :] = box
    stack[top + 1, k] = mid
    return top + 2


@njit(cache=True)
def posture_preimage_in(c, rho, q, eps, posture_bits, root, M, l1, l2sq, b, max_boxes, deadline=0.0):
    """Every pose in the region ``root`` with inverse kinematics (posture ``posture_bits + 1``)
    in ``q +- eps`` lies in the box ``c +- rho``.

    ``root`` (6,): x lo/hi, y lo/hi, phi lo/hi of a region that holds the robot.  A branch and
    bound of at most ``max_boxes`` pose boxes, until the ``deadline`` (:mod:`.clock`).  Returns the
    number of boxes examined when proved (> 0), minus it when not (a box that can neither be
    dropped nor split further, or out of boxes or time).
    """
    if expired(deadline):
        return -1
    stack = np.empty((PREIMAGE_STACK, 6))
    stack[0, :] = root
    prog = floats(2)
    prog[0], prog[1] = 1.0, 0.0
    r = preimage_on(c, rho, q, eps, posture_bits, M, l1, l2sq, b, max_boxes, deadline, stack, prog)
    return int(prog[1]) if r > 0 else -max(int(prog[1]), 1)


#: The depth of :func:`preimage_on`'s stack of pose boxes.
PREIMAGE_STACK = 64


@njit(cache=True)
def preimage_on(c, rho, q, eps, posture_bits, M, l1, l2sq, b, max_boxes, deadline, stack, prog):
    """The branch and bound of :func:`posture_preimage_in`, resumable: the boxes still to examine are
    ``stack[:prog[0]]`` (PREIMAGE_STACK, 6), ``prog[1]`` counts those examined so far (both read and
    rewritten).  Examines at least one box, then goes on until the ``deadline``.  Returns 1 when
    proved, -1 when not (a box that can neither be dropped nor split further, or ``max_boxes``
    examined), 0 when the deadline passed first (the stack and ``prog`` hold where it stands)."""
    top, seen = int(prog[0]), int(prog[1])
    scale_phi = 0.0
    for i in range(3):
        scale_phi = max(scale_phi, math.hypot(b[i, 0], b[i, 1]))
    first = True
    box = floats(6)
    while top > 0:
        if not first and expired(deadline):
            prog[0], prog[1] = top, seen
            return 0
        first = False
        top -= 1
        box[:] = stack[top]
        seen += 1
        if seen > max_boxes:
            prog[0], prog[1] = 0.0, seen
            return -1
        if _inside(box, c, rho):
            continue
        if posture_misses(box, q, eps, posture_bits, M, l1, l2sq, b):
            continue
        wx, wy, wp = box[1] - box[0], box[3] - box[2], (box[5] - box[4]) * scale_phi
        if max(wx, max(wy, wp)) < 1e-7 or top + 2 > PREIMAGE_STACK:
            prog[0], prog[1] = 0.0, seen
            return -1
        k = 0 if wx >= wy and wx >= wp else (2 if wy >= wp else 4)
        top = bisect(stack, top, box, k)
    prog[0], prog[1] = 0.0, seen
    return 1


@njit(cache=True)
def reacquire(X, q, eps, posture_bits, region, max_boxes, model_pack, box, deadline=0.0):
    """The proof of the module docstring for the solution ``X`` (3,) of the measured joints ``q`` (3,).

    ``region`` (6,): a pose box known to hold the robot (x, y, phi lo/hi); ``box`` (6,)
    receives the Krawczyk box's centre and half-widths (it holds the robot's pose).  True when
    ``X`` is in the posture and in the region, a Krawczyk box about it holds one solution
    for every joint vector in ``q +- eps`` (:func:`reacquire_box`), and no other pose of the region
    in the posture reaches them.
    """
    if not reacquire_box(X, q, eps, posture_bits, region, model_pack, box):
        return False
    M, l1, l2sq, b = geometry(model_pack)
    return posture_preimage_in(box[:3].copy(), box[3:].copy(), q, eps, posture_bits, region, M, l1, l2sq, b,
                               max_boxes, deadline) > 0


@njit(cache=True)
def reacquire_box(X, q, eps, posture_bits, region, model_pack, box):
    """Step 1 of :func:`reacquire`: ``X`` (3,) is in the posture and in the ``region`` (6,), and a
    Krawczyk box about it, written to ``box`` (6,: centre, half-widths), holds one solution for
    every joint vector in ``q +- eps``.  (``X`` outside the region would make step 2 true of a
    region that no pose reaching ``q +- eps`` is in: joints off by more than ``eps``.)"""
    M, l1, l2sq, b = geometry(model_pack)
    if elbow_bits(X, q, M, l1, b) != posture_bits or not in_region(X, region):
        return False
    w = floats(W_SIZE)
    xc, rho, none, e, tiny = floats(3), floats(3), floats(3), floats(3), floats(3)
    none[:] = 0.0
    e[:] = eps
    tiny[:] = TINY
    no_points = scratch2(1, 3, np.float64)
    if prove_part(q, e, no_points, no_points, 0, X, M, l1, b, l2sq, w, xc, rho) != 1:
        return False
    if not same_pose(xc, X) or not krawczyk(xc, tiny, q, none, none, 0.0, 0.0, none, M, l1, b, l2sq, w):
        return False
    box[:3], box[3:] = xc, rho
    return True


#: The covers :func:`tube_exclusion` tries, by attempt: one tube, slabs across the needle (3, then 8:
#: :func:`.tube_chain.slab_cover`), then 2**3 and 3**3 axis-aligned parts.
EXCLUSION_COVERS = (1, -3, -8, 2, 3)


@njit(cache=True)
def exclusion_cover(out, point, qc, t, attempt, M, l1, l2sq, b, deadline=0.0):
    """Cover ``attempt`` (1-based, :data:`EXCLUSION_COVERS`) of the joint box ``qc +- t`` (3,) into
    ``out`` (n, TUBE_SIZE) from the point tube ``point``; returns its number of tubes, or -1."""
    kind = EXCLUSION_COVERS[attempt - 1]
    if kind > 0:
        return cover_box(out, 0, point, qc, t, kind, M, l1, l2sq, b, deadline)
    if cover_box(out, 0, point, qc, t, 1, M, l1, l2sq, b, deadline) == 1 or not out[0, TUBE_S] == out[0, TUBE_S]:
        return -1                                       # one tube held it (attempt 1's) or no S to cut across
    V = scratch2(3, 3, np.float64)
    needle_frame(out[0, TUBE_S:TUBE_S + 9].reshape((3, 3)).copy(), V)
    return slab_cover(out, 0, point, qc, t, -kind, V, M, l1, l2sq, b, deadline)


@njit(cache=True)
def tube_exclusion(Xc, qc, tol, posture_lo, posture_hi, region, max_boxes, attempt, M, l1, l2sq, b, out,
                   deadline=0.0):
    """The robot's pose is the solution of a cover of the joint box ``qc +- tol`` (rad) by tubes about
    the DK solution ``Xc`` (3,) (cover ``attempt``: :func:`exclusion_cover`), written to ``out[:n]``
    (n, TUBE_SIZE): a proof from this joint box alone and a region (6,) known to hold the robot,
    for the robot in a posture of ``posture_lo..posture_hi - 1`` (posture bits).

    The tubes agree where their joint sets meet (:mod:`.handoff`), and for each (1) a fat tube,
    wide enough to hold a box about its needle's hull, holds one solution per joint vector of its
    joint set (:func:`.tube.slab_test`), and (2) every pose of the region in those postures
    reaching its joint box lies in that box (:func:`posture_preimage_in`; both in
    :func:`hull_excludes`).  The robot, at joints in some part, is then in that box, where the only
    solution is the part's tube's.  Returns n when proved, else 0 (also when the ``deadline`` passed).
    """
    point = floats(TUBE_SIZE)
    zero = floats(3)
    zero[:] = 0.0
    if not tube_test(Xc, qc, zero, zero, M, l1, l2sq, b, point):
        return 0
    t = floats(3)
    t[:] = tol
    n = exclusion_cover(out, point, qc, t, attempt, M, l1, l2sq, b, deadline)
    if n <= 0:
        return 0
    for k in range(n):
        if not hull_excludes(out[k], posture_lo, posture_hi, region, max_boxes, M, l1, l2sq, b, deadline):
            return 0
    return n


@njit(cache=True)
def hull_excludes(sub, posture_lo, posture_hi, region, max_boxes, M, l1, l2sq, b, deadline=0.0):
    """Steps (2) and (3) of :func:`tube_exclusion` for the tube ``sub`` (its joint set: a box or a slab):
    a box about its centre, :data:`HULL_FACTORS` times the needle's hull, holds one solution per
    joint vector of that set (a fat tube: :func:`fat_hull`), and every pose of the region in the
    postures reaching the set's joint box lies in it.  (A box far wider than the needle lets the
    branch and bound drop the poses about the needle quickly; the fat tube's test decides how wide
    it may be.)"""
    hull = floats(3)
    xc, q, t = sub[TUBE_X:TUBE_X + 3].copy(), sub[TUBE_Q:TUBE_Q + 3].copy(), sub[TUBE_T:TUBE_T + 3]
    for factor in HULL_FACTORS:
        if not fat_hull(sub, factor, M, l1, l2sq, b, hull):
            continue
        for p in range(posture_lo, posture_hi):
            if posture_preimage_in(xc, hull, q, max(t[0], max(t[1], t[2])), p, region, M, l1, l2sq, b,
                                   max_boxes, deadline) <= 0:
                return False
        return True
    return False


@njit(cache=True)
def fat_hull(sub, factor, M, l1, l2sq, b, hull):
    """The box about the tube ``sub``'s centre pose, ``factor`` times its needle's hull (half-widths into
    ``hull`` (3,): m, m, rad), holds one solution per joint vector of the tube's joint set, and the
    tube's solutions lie inside it: True when a fat tube (:func:`.tube.slab_test`) proves both."""
    fat = floats(TUBE_SIZE)
    rho = floats(3)
    xc, q = sub[TUBE_X:TUBE_X + 3].copy(), sub[TUBE_Q:TUBE_Q + 3].copy()
    V = sub[TUBE_V:TUBE_V + 9].reshape((3, 3)).copy()
    tw, t = sub[TUBE_W:TUBE_W + 3].copy(), sub[TUBE_T:TUBE_T + 3].copy()
    for r in range(3):
        s = set_spread(sub, r)
        hull[r] = factor * max((s + sub[TUBE_K + r]) * (1.0 + 1e-9), HULL_MIN)
        rho[r] = (hull[r] + s) * (1.0 + 1e-4) + 1e-12
    if not slab_test(xc, q, V, tw, t, rho, M, l1, l2sq, b, fat):
        return False
    for r in range(3):                   # the box xc +- hull inside the fat tube at every q: its own centre, S
        reach = abs(xc[r] - fat[TUBE_X + r]) + hull[r] + set_spread(fat, r)
        if not reach * (1.0 + 1e-9) + 1e-15 < fat[TUBE_R + r]:
            return False
    return True
