"""What a tracker step costs beside its compiled math: ``step``, the compiled kernel, and ``track``.

    python bench/bench_step.py [--n 1000] [--repeats 5]

On the paper circle (``--n`` points, posture 1, exact joints) it times, interleaved in one run:

* ``kernel``: the compiled step alone, as the compiled stream loop of ``track`` times it (the CPU's
  cycle counter around each step inside compiled code: no Python, no call overhead);
* ``call``: the step's compiled call from Python alone (the joints in, one call of the entry point that
  steps and advances the flat state), without the argument checks and the ``StepInfo``;
* ``step``: ``Tracker.step(q)`` from Python (argument checks, one compiled call that packs the flat
  state, steps and advances it in place, the ``StepInfo``);
* ``step (objects)``: the same step with the state as a ``TrackerState`` object packed and rebuilt in
  Python at every step (the reference path, used while the stuck-joint detector or the encoder-grid
  watch is on; every step before this change);
* ``track``: ``track(q_stream, X0)`` over the stream, less the ``reset`` it makes (the honest start,
  timed inside it), per step.

for the tracker (default mode) and for ``NewtonTracker`` (Newton from the previous pose).  It prints
medians (us) and the ratios the compiled-step issue sets targets for: ``step / kernel`` (tracker at most
1.3, Newton at most 3) and ``track / sum of kernels`` (at most 1.05: each pass's ``track`` over the sum
of that pass's kernels, the median of the passes).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from report import publish, table, target    # bench/ is on sys.path when a script there runs
from solver import Manipulator, Tracker, cached_map, circle_path, ik
from solver.baselines import NewtonTracker


def _time_each(call, q, *args) -> list:
    """Seconds of ``call(q[k], *args)`` for k = 1.. (the rows made before: the clock times the call only)."""
    out, clock = [], time.perf_counter
    for qk in list(q[1:]):
        t0 = clock()
        call(qk, *args)
        out.append(clock() - t0)
    return out


def _time_steps(tr, X, q, objects: bool) -> list:
    tr._objects = objects
    tr.reset(X[0], q[0])
    out = _time_each(tr.step, q)
    tr._objects = False
    return out


def _time_calls(tr, X, q) -> list:
    """The step's compiled call from Python alone (the joints in, one call of the entry point that steps
    and advances the flat state), without the argument checks and the ``StepInfo``: what ``step`` costs
    beyond it is the Python a step returns its answer through."""
    tr.reset(X[0], q[0])
    out = _time_each(tr._advance, q, float("nan"), 0.0, tr._flat_state())
    tr.flat_advanced()                                   # the flat state moved on outside step
    return out


def _time_track(tr, X, q) -> tuple:
    """(seconds of track less its reset, per step; the compiled loop's own step times).  The reset that
    ``track`` makes is timed inside it (the instance's ``reset`` wrapped for the call): a reset timed
    apart, before it, takes longer or shorter (the tracker's honest start is a proof, about 0.5 ms)."""
    spent = []
    reset = tr.reset

    def timed_reset(*args, **kwargs):
        t0 = time.perf_counter()
        out = reset(*args, **kwargs)
        spent.append(time.perf_counter() - t0)
        return out

    tr.reset = timed_reset
    try:
        t0 = time.perf_counter()
        res = tr.track(q, X[0])
        t_track = time.perf_counter() - t0 - sum(spent)
    finally:
        del tr.reset                                     # the class's method again
    return t_track / (len(q) - 1), res.seconds[1:]


def measure(n: int = 1000, repeats: int = 5) -> dict:
    """Median microseconds per step of every (method, what) on the paper circle of ``n`` points."""
    model = Manipulator.paper()
    X = circle_path(n)
    q = ik(model, X, 1)
    trackers = {"tracker": Tracker(model, cached_map(model, 1), start_tolerance=(1e-9, 1e-9, 1e-9)),
                "newton": NewtonTracker(model)}
    samples = {(name, what): [] for name in trackers
               for what in ("kernel", "call", "step", "step (objects)", "track", "track ratio")}
    for _ in range(repeats):
        for name, tr in trackers.items():                  # interleaved: the same conditions for all
            samples[name, "step"] += _time_steps(tr, X, q, False)
            samples[name, "call"] += _time_calls(tr, X, q)
            samples[name, "step (objects)"] += _time_steps(tr, X, q, True)
            per_step, kernel = _time_track(tr, X, q)
            samples[name, "track"].append(per_step)
            samples[name, "kernel"] += list(kernel)
            # track against the sum of its own kernels, pass by pass (the machine's speed drifts
            # between passes: a median of track times over a mean of all kernels would mix them)
            samples[name, "track ratio"].append(per_step / float(np.mean(kernel)))
    med = {key: 1e6 * float(np.median(v)) for key, v in samples.items()}
    for name in trackers:
        med[name, "track ratio"] = float(np.median(samples[name, "track ratio"]))
    return med


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="points of the paper circle (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=5, help="passes over the circle (default %(default)s)")
    args = ap.parse_args(argv)
    measure(50, 1)                                         # compiled and warm before the timing
    med = measure(args.n, args.repeats)
    rows, ratios = [], {}
    for name in ("tracker", "newton"):
        k, c, s, o, t = (med[name, w] for w in ("kernel", "call", "step", "step (objects)", "track"))
        ratios[name] = (s / k, med[name, "track ratio"])
        rows.append((name, f"{k:.2f}", f"{c:.2f}", f"{s:.2f}", f"{o:.2f}", f"{t:.2f}", f"{s / k:.2f}x", f"{o / k:.2f}x",
                     f"{ratios[name][1]:.3f}x"))
    body = table(["method", "kernel (us)", "call (us)", "step (us)", "step, objects (us)", "track, per step (us)",
                  "step / kernel", "objects / kernel", "track / kernels' sum"], rows)
    print(f"paper circle, {args.n} points, exact joints, {args.repeats} passes; medians")
    print(body)
    note = (f"The paper circle, {args.n} points, exact joints, {args.repeats} passes, interleaved.  *kernel*: "
            "the compiled step alone, timed by the CPU's cycle counter inside the compiled loop of `track`; "
            "*call*: the step's compiled call from Python alone (the joints in, one call of the entry point "
            "that steps and advances the flat state; no argument checks, no `StepInfo`); "
            "*step*: `step(q)` from Python (one compiled call that packs the flat state, steps and advances "
            "it in place); *objects*: the reference path that packs and rebuilds a `TrackerState` in Python "
            "at every step (every step before the compiled stepper; now only with the stuck-joint detector "
            "or the encoder-grid watch on); *track*: `track` over the stream less its `reset` (timed inside "
            "it), per step; *track / kernels' sum*: each pass's `track` time over the sum of that pass's "
            "kernels, median of the passes.")
    publish("step", body, note=note, command=" ".join(["python bench/bench_step.py", *(argv or sys.argv[1:])]),
            headline=[("tracker step from Python / its compiled kernel, default mode", f"{ratios['tracker'][0]:.2f}x",
                       target("<= 1.3x", ratios["tracker"][0] <= 1.3)),
                      ("Newton step from Python / its compiled kernel", f"{ratios['newton'][0]:.2f}x",
                       target("<= 3x", ratios["newton"][0] <= 3.0)),
                      ("`track` over a stream / its kernels' sum: tracker, Newton",
                       f"{ratios['tracker'][1]:.3f}x, {ratios['newton'][1]:.3f}x",
                       target("<= 1.05x", max(ratios["tracker"][1], ratios["newton"][1]) <= 1.05))])


if __name__ == "__main__":
    main()
