"""Re-acquisition by the eliminant: the DK's one-variable equation over a joint box, in intervals.

The real DK solutions of joints ``q`` have ``phi`` a real root of the eliminant

    f(phi; q) = |n|^2 + 2 delta (n . u_0) + delta^2 k_0

(:func:`.direct_kinematics.elim`: for a given ``phi`` the differences of the loop equations are
linear in ``P``, solved by Cramer as ``P = n / delta``, and the first equation times ``delta^2`` is
``f``).  A pose box the robot is known to be in (the region) and the reading's joint box
``q +- tol`` give a one-dimensional problem, free of the wrapping that makes a three-dimensional
Krawczyk test fail on a long, curved needle (next to a fold ``|S|`` reaches hundreds and the
needle turns by tenths of a radian inside the joint box).

The test covers the region's phi range by intervals, and for each evaluates ``f`` and
``df/dphi`` over the interval times the joint box in interval arithmetic (outward pads as
:mod:`.krawczyk`).  An interval where ``f`` cannot vanish holds no solution for any joint vector
of the box; a run of intervals where ``df/dphi`` keeps one sign holds, for each joint vector, at
most one root, and exactly one when ``f`` has opposite signs at the run's two ends for every joint
vector.  Intervals where neither holds are halved.  When exactly one run holds a root, and the
solution to re-acquire has its phi there, every pose of the region (in any posture) reaching the
joint box is that solution's: its phi in the run, its ``P = n / delta`` in the interval enclosure
over the run (``delta`` kept away from 0), which gives the pose bound.  With the robot's posture
known, a run whose box holds no pose reaching the joint box in that posture is ruled out too
(another assembly mode in another posture), and the range may be a whole turn.  For the robot as built
each ``l2_i^2`` is an interval (its slack, :func:`.kinematics.leg_slack`): every claim holds for each
geometry within it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .clock import expired
from .exclusion import posture_misses
from .kinematics import leg_slack
from .krawczyk import PAD, TWO_PI

#: The first cut of the region's phi range (rad), the narrowest interval halving may reach, and the
#: most interval evaluations one test may spend.
PHI_STEP = 0.01
PHI_MIN = 1e-7
MAX_EVALS = 6000
#: Intervals (of the run that holds the root) kept for the pose enclosure.
MAX_RUN = 512


#: An affine form over the noise symbols e_0 (phi's interval), e_1..e_3 (the joints) and e_4..e_6 (the legs'
#: slacks of the robot as built), all |e_j| <= 1: its centre (index 0), the coefficient of e_j (index 1 + j)
#: and a remainder (index A_R); a quantity is two of them, its value and its d/dphi.
N_SYM = 7
A_C, A_R, A_SIZE = 0, 1 + N_SYM, 2 + N_SYM
Q_SIZE = 2 * A_SIZE
#: The first slack symbol: leg i's slack is e_(SLACK_SYM + i).
SLACK_SYM = 4


@njit(cache=False)
def _dev(x, o):
    """sum |coefficients| of the affine form at ``x[o:]``."""
    t = 0.0
    for j in range(1, A_R):
        t += abs(x[o + j])
    return t


@njit(cache=False)
def _mag(x, o):
    """|centre| + sum |coefficients| of the affine form at ``x[o:]``."""
    return abs(x[o]) + _dev(x, o)


@njit(cache=False)
def _aff_add(x, xo, y, yo, sy, z, zo):
    """z = x + sy y (affine forms at offsets; ``sy`` +1 or -1), the rounding in the remainder."""
    for j in range(A_R):
        z[zo + j] = x[xo + j] + sy * y[yo + j]
    z[zo + A_R] = (x[xo + A_R] + y[yo + A_R]) * (1.0 + PAD) + PAD * (_mag(x, xo) + _mag(y, yo))


@njit(cache=False)
def _aff_mul(x, xo, y, yo, z, zo):
    """z = x y: centre and linear terms exact to rounding, the products of deviations in the remainder."""
    xc, yc = x[xo], y[yo]
    dx = _dev(x, xo) + x[xo + A_R]
    dy = _dev(y, yo) + y[yo + A_R]
    z[zo] = xc * yc
    for j in range(1, A_R):
        z[zo + j] = xc * y[yo + j] + yc * x[xo + j]
    z[zo + A_R] = (abs(xc) * y[yo + A_R] + abs(yc) * x[xo + A_R] + dx * dy) * (1.0 + PAD) + \
        PAD * (_mag(x, xo) * _mag(y, yo) + abs(xc * yc) + 1e-300)


@njit(cache=False)
def q_add(x, y, sy=1.0):
    """x + sy y for quantities (value and d/dphi, :data:`Q_SIZE` floats each)."""
    z = np.empty(Q_SIZE)
    _aff_add(x, 0, y, 0, sy, z, 0)
    _aff_add(x, A_SIZE, y, A_SIZE, sy, z, A_SIZE)
    return z


@njit(cache=False)
def q_mul(x, y):
    """x y with its d/dphi, ``x' y + x y'``."""
    z = np.empty(Q_SIZE)
    t = np.empty(A_SIZE)
    _aff_mul(x, 0, y, 0, z, 0)
    _aff_mul(x, A_SIZE, y, 0, z, A_SIZE)
    _aff_mul(x, 0, y, A_SIZE, t, 0)
    _aff_add(z, A_SIZE, t, 0, 1.0, z, A_SIZE)
    return z


@njit(cache=False)
def q_scale(k, x):
    """k x for a number ``k``."""
    z = np.empty(Q_SIZE)
    for o in (0, A_SIZE):
        for j in range(A_R):
            z[o + j] = k * x[o + j]
        z[o + A_R] = abs(k) * x[o + A_R] * (1.0 + PAD) + PAD * abs(k) * _mag(x, o)
    return z


@njit(cache=False)
def q_const(v, j, a, r):
    """The quantity ``v + a e_j`` (remainder ``r``; ``j`` 1..3 a joint's symbol, SLACK_SYM.. a leg's slack)
    or the number ``v`` (``j = 0``, ``a = 0``), neither depending on phi (its d/dphi is zero)."""
    z = np.zeros(Q_SIZE)
    z[0] = v
    z[1 + j] += a
    z[A_R] = r + PAD * (abs(v) + abs(a))
    return z


@njit(cache=False)
def q_range(x, o):
    """(lo, hi) of the affine form at ``x[o:]``."""
    w = _dev(x, o) + x[o + A_R]
    w += PAD * _mag(x, o)
    return x[o] - w, x[o] + w


@njit(cache=True)
def eliminant(pm, h, D0, D1, b, l2sq, out):
    """Enclosures over ``phi = pm +- h`` and the elbows ``D0``, ``D1`` (3, Q_SIZE each: the elbows' x and y
    as quantities of the joints, :func:`joint_box_elbows`) of the eliminant ``f``, its derivative
    ``df/dphi``, ``delta``, ``nx`` and ``ny`` (lo, hi each) into ``out`` (10,)."""
    cm, sm = math.cos(pm), math.sin(pm)
    rem = 0.5 * h * h + PAD
    c = np.zeros(Q_SIZE)                          # cos phi and its d/dphi = -sin phi
    s = np.zeros(Q_SIZE)                          # sin phi and its d/dphi = cos phi
    c[0], c[1], c[A_R] = cm, -sm * h, rem
    s[0], s[1], s[A_R] = sm, cm * h, rem
    c[A_SIZE], c[A_SIZE + 1], c[A_SIZE + A_R] = -sm, -cm * h, rem
    s[A_SIZE], s[A_SIZE + 1], s[A_SIZE + A_R] = cm, -sm * h, rem
    u0x = q_add(q_add(q_scale(b[0, 0], c), q_scale(b[0, 1], s), -1.0), D0[0], -1.0)
    u0y = q_add(q_add(q_scale(b[0, 0], s), q_scale(b[0, 1], c)), D1[0], -1.0)
    # the robot as built: leg i closes at l2_i^2 + sigma_i e_(SLACK_SYM + i) (its slack, its own symbol)
    k0 = q_add(q_add(q_mul(u0x, u0x), q_mul(u0y, u0y)), q_const(l2sq[0], SLACK_SYM, leg_slack(l2sq, 0), 0.0), -1.0)
    rx = np.empty((2, Q_SIZE))
    ry = np.empty((2, Q_SIZE))
    hh = np.empty((2, Q_SIZE))
    for j in range(2):                            # r_j = u_j - u_0 straight from the geometry, h_j = -(k_j - k_0) / 2
        bx, by = b[j + 1, 0] - b[0, 0], b[j + 1, 1] - b[0, 1]
        rx[j] = q_add(q_add(q_scale(bx, c), q_scale(by, s), -1.0), q_add(D0[j + 1], D0[0], -1.0), -1.0)
        ry[j] = q_add(q_add(q_scale(bx, s), q_scale(by, c)), q_add(D1[j + 1], D1[0], -1.0), -1.0)
        # k_j - k_0 = (r_j + 2 u_0) . r_j - (l2_j^2 - l2_0^2)
        sx = q_add(rx[j], q_scale(2.0, u0x))
        sy = q_add(ry[j], q_scale(2.0, u0y))
        sl = q_const(l2sq[j + 1] - l2sq[0], SLACK_SYM + j + 1, leg_slack(l2sq, j + 1), 0.0)
        sl[1 + SLACK_SYM] = -leg_slack(l2sq, 0)
        sl[A_R] += PAD * leg_slack(l2sq, 0)
        dk = q_add(q_add(q_mul(sx, rx[j]), q_mul(sy, ry[j])), sl, -1.0)
        hh[j] = q_scale(-0.5, dk)
    delta = q_add(q_mul(rx[0], ry[1]), q_mul(ry[0], rx[1]), -1.0)
    nx = q_add(q_mul(hh[0], ry[1]), q_mul(hh[1], ry[0]), -1.0)
    ny = q_add(q_mul(rx[0], hh[1]), q_mul(rx[1], hh[0]), -1.0)
    g = q_add(q_mul(nx, u0x), q_mul(ny, u0y))
    f = q_add(q_add(q_mul(nx, nx), q_mul(ny, ny)), q_add(q_scale(2.0, q_mul(delta, g)), q_mul(q_mul(delta, delta), k0)))
    out[0], out[1] = q_range(f, 0)
    out[2], out[3] = q_range(f, A_SIZE)
    out[4], out[5] = q_range(delta, 0)
    out[6], out[7] = q_range(nx, 0)
    out[8], out[9] = q_range(ny, 0)


@njit(cache=True)
def joint_box_elbows(qc, tol, M, l1, D0, D1):
    """The elbows' x and y over the joints ``qc +- tol`` (3, 3,, rad) as quantities of the joint noise
    symbols (rows of ``D0``, ``D1``, (3, Q_SIZE) each): ``M + l1 (cos q, sin q)``, the second-order
    Taylor remainder ``l1 tol^2 / 2``."""
    for i in range(3):
        cq, sq = math.cos(qc[i]), math.sin(qc[i])
        r0 = 0.5 * l1[i] * tol[i] * tol[i] + PAD * (abs(M[i, 0]) + l1[i])     # Taylor, and the rounding of M +
        r1 = 0.5 * l1[i] * tol[i] * tol[i] + PAD * (abs(M[i, 1]) + l1[i])     # l1 cos q where it cancels
        D0[i] = q_const(M[i, 0] + l1[i] * cq, 1 + i, -l1[i] * sq * tol[i], r0)
        D1[i] = q_const(M[i, 1] + l1[i] * sq, 1 + i, l1[i] * cq * tol[i], r1)


@njit(cache=True)
def eliminant_certificate(phi_c, qc, tol, plo, phi, M, l1, l2sq, b, bound_box, deadline=0.0, posture_bits=-1):
    """Whether, for every joint vector of ``qc +- tol`` (3,, rad), at most one DK solution has its phi
    in [plo, phi] (rad, less than a turn), in the run of intervals holding ``phi_c`` (the module
    docstring): a robot known to be in that phi range, at joints in the box, is at that solution.
    With a posture (``posture_bits`` >= 0: the robot is known to be in posture ``posture_bits + 1``),
    another run that may hold a root is ruled out when no pose of its box reaches the joint box in
    that posture (:func:`.exclusion.posture_misses`), and the range may be a whole turn.
    On success the box (x lo, x hi, y lo, y hi, phi lo, phi hi) holding those solutions goes into
    ``bound_box`` (6,).  False also for a prismatic leg (the 3-RPR), on a cut the ``deadline`` made,
    or when :data:`MAX_EVALS` evaluations did not decide."""
    for i in range(3):
        if l2sq[i] < 0.0:
            return False
    if not (phi - plo < (TWO_PI + 1e-9 if posture_bits >= 0 else TWO_PI - 1e-9)) or not plo < phi:
        return False
    if phi_c == phi_c:
        while phi_c < plo:
            phi_c += TWO_PI
        while phi_c > phi:
            phi_c -= TWO_PI
        if phi_c < plo:
            return False
    D0, D1 = np.empty((3, Q_SIZE)), np.empty((3, Q_SIZE))
    joint_box_elbows(qc, tol, M, l1, D0, D1)
    ev, other = np.empty(10), np.empty(6)
    eps = max(tol[0], max(tol[1], tol[2]))
    n0 = max(1, int(math.ceil((phi - plo) / PHI_STEP)))
    stack = np.empty((64 + n0, 2))                # intervals still to look at, the leftmost on top
    top = 0
    for j in range(n0 - 1, -1, -1):
        stack[top, 0] = plo + (phi - plo) * j / n0
        stack[top, 1] = plo + (phi - plo) * (j + 1) / n0 if j + 1 < n0 else phi
        top += 1
    run = np.empty((MAX_RUN, 2))                  # the intervals of the current run
    n_run = 0
    cur_sign, cur_on, found = 0.0, False, False
    evals = 0
    lo, hi, free, sign = 0.0, 0.0, True, 0.0
    while True:
        done = top == 0
        if not done:
            top -= 1
            lo, hi = stack[top, 0], stack[top, 1]
            evals += 1
            if evals > MAX_EVALS or (evals % 16 == 0 and expired(deadline)):
                return False
            eliminant(0.5 * (lo + hi), 0.5 * (hi - lo), D0, D1, b, l2sq, ev)
            free = ev[0] > 0.0 or ev[1] < 0.0           # f cannot vanish here
            sign = 1.0 if ev[2] > 0.0 else (-1.0 if ev[3] < 0.0 else 0.0)
            if not free and sign == 0.0:
                if hi - lo <= PHI_MIN or top + 2 > stack.shape[0]:
                    return False
                mid = 0.5 * (lo + hi)
                stack[top, 0], stack[top, 1] = mid, hi
                stack[top + 1, 0], stack[top + 1, 1] = lo, mid
                top += 2
                continue
        if cur_on and (done or free or sign != cur_sign):      # the run ends
            r_lo, r_hi = run[0, 0], run[n_run - 1, 1]
            mine = r_lo <= phi_c <= r_hi if phi_c == phi_c else False
            if mine or (end_signs(r_lo, r_hi, D0, D1, b, l2sq, ev) != 1 and not (
                    posture_bits >= 0 and run_box(run, n_run, D0, D1, b, l2sq, ev, other, deadline)
                    and posture_misses(other, qc, eps, posture_bits, M, l1, l2sq, b))):
                # the run of the solution (or, with phi_c NaN, the one run that may hold a root in the
                # posture): at most one root per joint vector
                if found or not (mine or phi_c != phi_c):
                    return False                       # another run may hold a root
                if not run_box(run, n_run, D0, D1, b, l2sq, ev, bound_box, deadline):
                    return False
                found = True
            cur_on, n_run = False, 0
            if expired(deadline):                      # a run's enclosure is not free: the budget first
                return False
        if done:
            break
        if free:
            continue
        if not cur_on:
            cur_on, cur_sign = True, sign
        if n_run >= MAX_RUN:
            return False
        run[n_run, 0], run[n_run, 1] = lo, hi
        n_run += 1
    return found


@njit(cache=False)
def end_signs(lo, hi, D0, D1, b, l2sq, ev):
    """The signs of ``f`` at ``lo`` and at ``hi`` over the joint box: -1 opposite, 1 the same, 0
    when ``f`` may vanish at either end."""
    eliminant(lo, 0.0, D0, D1, b, l2sq, ev)
    a = 1.0 if ev[0] > 0.0 else (-1.0 if ev[1] < 0.0 else 0.0)
    eliminant(hi, 0.0, D0, D1, b, l2sq, ev)
    z = 1.0 if ev[0] > 0.0 else (-1.0 if ev[1] < 0.0 else 0.0)
    if a == 0.0 or z == 0.0:
        return 0
    return -1 if a != z else 1


#: Interval evaluations one pose enclosure may spend cutting its run's intervals where ``f`` cannot vanish.
REFINE_EVALS = 192


@njit(cache=True)
def run_box(run, n, D0, D1, b, l2sq, ev, box, deadline=0.0):
    """The pose box (6,) over the run's intervals ``run[:n]``: each interval is halved where that lets a half
    drop (``f`` cannot vanish on it: no root there), within :data:`REFINE_EVALS` evaluations, the narrowest
    a hundredth of the interval; ``P = n / delta`` is enclosed over the pieces left (False when ``delta``
    may vanish on one), phi is their span (False when no piece is left: the run holds no root).  False too
    when the ``deadline`` (:mod:`.clock`) passes first: the box is then unknown."""
    box[0], box[1], box[2], box[3] = np.inf, -np.inf, np.inf, -np.inf
    box[4], box[5] = np.inf, -np.inf
    stack = np.empty((64, 2))
    budget = REFINE_EVALS
    for j in range(n):
        top = 1
        stack[0, 0], stack[0, 1] = run[j, 0], run[j, 1]
        least = 0.01 * (run[j, 1] - run[j, 0])
        while top > 0:
            top -= 1
            lo, hi = stack[top, 0], stack[top, 1]
            eliminant(0.5 * (lo + hi), 0.5 * (hi - lo), D0, D1, b, l2sq, ev)
            budget -= 1
            if budget % 16 == 0 and expired(deadline):
                return False
            if ev[0] > 0.0 or ev[1] < 0.0:
                continue                               # f cannot vanish here: no root, no pose
            if budget > 2 and hi - lo > least and top + 2 <= stack.shape[0]:
                mid = 0.5 * (lo + hi)
                stack[top, 0], stack[top, 1] = mid, hi
                stack[top + 1, 0], stack[top + 1, 1] = lo, mid
                top += 2
                continue
            dlo, dhi = ev[4], ev[5]
            if not (dlo > 0.0 or dhi < 0.0):
                return False
            for a in range(2):
                nlo, nhi = ev[6 + 2 * a], ev[7 + 2 * a]
                p1, p2, p3, p4 = nlo / dlo, nlo / dhi, nhi / dlo, nhi / dhi
                plo = min(min(p1, p2), min(p3, p4))
                phi_ = max(max(p1, p2), max(p3, p4))
                pad = PAD * max(abs(plo), abs(phi_))
                box[2 * a] = min(box[2 * a], plo - pad)
                box[2 * a + 1] = max(box[2 * a + 1], phi_ + pad)
            box[4], box[5] = min(box[4], lo), max(box[5], hi)
    return box[4] <= box[5]
