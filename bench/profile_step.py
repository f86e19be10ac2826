"""Where the certified step's time goes: the tracker step's phases timed inside compiled code.

    python bench/profile_step.py [--n 1000] [--repeats 5]

On the paper circle (``--n`` points, posture 1, exact joints, default mode) it runs the tracker's
step as :func:`solver._kernels.tracker.tracker_step` does, phase by phase, with the CPU's cycle counter
read between phases (a copy of that function's sequence compiled here, for the bench only: the
shipped kernel has no timers), on the flat state of :mod:`solver._kernels.stepper`, and prints each
phase's median and mean (us) and its share of the step:

pack (the flat state into the state pack), gate (the step pack and the outlier gate), solve (all DK
solutions and procedure 2 at the previous pose), predict (eq. 22 and the RK4 continuation), choose
(the nearest candidate, the map's label), certify (the certificates: tubes, chains), finish (margins,
speed gate, publish), advance (the next flat state).  The poses are checked equal to ``Tracker.step``'s.
Writes section ``profile`` of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from numba import njit

from report import publish, table            # bench/ is on sys.path when a script there runs
from solver import Manipulator, Tracker, cached_map, circle_path, ik
from solver._kernels.anytime import ANY_CUT, ANY_DEADLINE
from solver._kernels.certified import certify_phase
from solver._kernels.choice import choose_default, linear_prediction, predict
from solver._kernels.clock import cycles, cycles_per_second
from solver._kernels.layout import OUT_X, OUT_X_PRED, STATUS_UNREACHABLE
from solver._kernels.stepper import advance_state, load_walk, pack_state
from solver._kernels.tracker import (gate_phase, hold, margins, publish as publish_phase, solve_phase,
                                     speed_gate_phase, step_pack)
from solver._kernels.scratch import floats, scratch, scratch2
from solver._kernels.tracker_packs import STEP_SIZE, STEP_X_LIN

PHASES = ("pack", "gate", "solve", "predict", "choose", "certify", "finish", "advance")


@njit
def timed_step(mode, rule, q, a, pk, model_pack, sample_to_sextic, labels, map_pack, stencil, params, out_real,
               out_int, anytime, t):
    """One default-mode step from the flat state ``a``, its phases' cycle counts into ``t`` (8,); False when
    the step left the phases this profile follows (a refused or unreachable sample)."""
    c0 = cycles()
    pack_state(a, math.nan, pk)
    load_walk(a, anytime, 0.0)
    c1 = cycles()
    work = floats(STEP_SIZE)                   # (the step's arrays on the stack, as tracker_step's)
    step_pack(q, pk, params, out_real, out_int, work)
    anytime[ANY_CUT] = 0.0
    refused, untrusted = gate_phase(pk, work, params, model_pack, out_real, out_int)
    if refused:
        return False
    c2 = cycles()
    poses = scratch2(6, 3, np.complex128)
    real = scratch(6, np.bool_)
    near_prev = scratch(7, np.bool_)
    near_prev[:] = False
    n_real, n_near, single = solve_phase(q, rule, pk, work, model_pack, sample_to_sextic, labels, map_pack, stencil,
                                         poses, real, near_prev, out_int)
    c3 = cycles()
    cond_prev = linear_prediction(pk, work, model_pack, out_real)
    if n_real == 0:
        out_real[OUT_X_PRED:OUT_X_PRED + 3] = work[STEP_X_LIN:STEP_X_LIN + 3]
        hold(pk, out_real, out_int, STATUS_UNREACHABLE)
        return False
    ok, worst = predict(mode, pk, work, params, model_pack, out_real, cond_prev)
    c4 = cycles()
    chosen, ambiguous = choose_default(poses, real, near_prev, work, pk, params, labels, map_pack, stencil, n_near,
                                       ok, worst, out_real, out_int)
    c5 = cycles()
    chosen, linked = certify_phase(mode, chosen, untrusted, pk, work, poses, real, params, model_pack, map_pack,
                                   out_real, out_int, anytime)
    c6 = cycles()
    if margins(mode, chosen, poses, real, work, params, map_pack, out_real):
        ambiguous = True
    taken = speed_gate_phase(mode, chosen, linked, untrusted, pk, work, poses, real, params, model_pack, out_real,
                             out_int, anytime[ANY_DEADLINE])
    if taken < 0:
        return False
    publish_phase(taken, ambiguous or taken != chosen, poses, work, params, model_pack, out_real, out_int)
    c7 = cycles()
    advance_state(a, q, math.nan, out_real, out_int, anytime, True)
    c8 = cycles()
    t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7] = c1 - c0, c2 - c1, c3 - c2, c4 - c3, c5 - c4, c6 - c5, \
        c7 - c6, c8 - c7
    return True


def profile(n: int = 1000, repeats: int = 5) -> np.ndarray:
    """Phase times (s), shape (steps, 8), over ``repeats`` passes of the paper circle of ``n`` points."""
    model = Manipulator.paper()
    X = circle_path(n)
    q = ik(model, X, 1)
    tr = Tracker(model, cached_map(model, 1), start_tolerance=(1e-9, 1e-9, 1e-9))
    ref = tr.track(q, X[0]).X                               # the poses the shipped step returns
    rows, t = [], np.zeros(8, dtype=np.int64)
    for _ in range(repeats):
        tr.reset(X[0], q[0])
        a = tr._flat_state()
        for k in range(1, n):
            if not timed_step(tr._mode, tr._rule, q[k], a, tr._state_pack, tr._model_pack, tr._sample_to_sextic,
                              tr._labels, tr._map_pack, tr._stencil, tr._params, tr._out_real, tr._out_int,
                              tr._anytime, t):
                raise SystemExit(f"step {k}: left the phases this profile follows")
            if not np.array_equal(tr._out_real[OUT_X:OUT_X + 3], ref[k]):
                raise SystemExit(f"step {k}: the profiled step's pose differs from Tracker.track's")
            rows.append(t.copy())
    return np.array(rows) / cycles_per_second()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="points of the paper circle (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=5, help="passes over the circle (default %(default)s)")
    args = ap.parse_args(argv)
    profile(20, 1)                                          # compiled before the timing
    t = profile(args.n, args.repeats) * 1e6
    total = t.sum(axis=1)
    rows = [(name, f"{np.median(t[:, i]):.2f}", f"{t[:, i].mean():.2f}", f"{100 * t[:, i].sum() / total.sum():.1f} %")
            for i, name in enumerate(PHASES)]
    rows.append(("whole step", f"{np.median(total):.2f}", f"{total.mean():.2f}", "100 %"))
    body = table(["phase", "median (us)", "mean (us)", "share"], rows)
    print(body)
    publish("profile", body, command=" ".join(["python bench/profile_step.py", *(argv or sys.argv[1:])]),
            note=f"The tracker's step (default mode, exact joints) on the paper circle, {args.n} points, "
                 f"{args.repeats} passes, timed phase by phase inside compiled code (a bench-only copy of "
                 "`tracker_step`'s sequence with cycle-counter reads between phases; its poses equal "
                 "`Tracker.track`'s).")


if __name__ == "__main__":
    main()
