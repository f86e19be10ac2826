"""Digests of every tracker's answers over the suites: has a kernel change changed any bit of a result?

    python bench/track_digests.py --out before.json            # on the old code
    python bench/track_digests.py --compare before.json         # on the new code: exit 1 on any change

For every stream of the default and hard suites (:mod:`experiments.suite`) and every method of
``bench/bench_tracker.py`` (the tracker in default and paper mode, the baselines), and for the
tracker with measured joints (the suite's joints plus a uniform error of 1e-4 rad, joint tolerances
1e-4 and 3e-4 rad), it hashes each field of the :class:`solver.TrackResult` but ``seconds`` (SHA-1 of
the array's bytes).  Two runs agree when the code gives the same bits; ``--compare`` lists the streams
and fields that differ.  (No step budget: a budgeted step depends on the clock.)  About 1.5 minutes.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time

import numpy as np

from bench_tracker import methods              # bench/ is on sys.path when a script there runs
from experiments.suite import default_suite, hard_suite
from solver import Manipulator, Tracker, cached_map

#: The measured-joint runs: the error added to the suite's joints (rad, uniform, seeded) and the tolerances.
NOISE, TOLERANCES = 1e-4, (1e-4, 3e-4)


def digest(result) -> dict:
    """``{field: the first 16 hex digits of the SHA-1 of its bytes}`` of a TrackResult, ``seconds`` left out."""
    return {f: hashlib.sha1(np.ascontiguousarray(getattr(result, f)).tobytes()).hexdigest()[:16]
            for f in result._fields if f != "seconds"}


def digests() -> dict:
    """``{"<path>|<method>": digest}`` of every stream (module docstring)."""
    model = Manipulator.paper()
    maps = {p: cached_map(model, p) for p in range(1, 9)}
    makers = methods(model, maps)
    out = {}
    for suite in (default_suite(model), hard_suite(model)):
        for path in suite:
            for name, make in makers.items():
                out[f"{path.name}|{name}"] = digest(make(path.posture).track(path.q, path.X[0]))
            noisy = path.q + np.random.default_rng(1).uniform(-NOISE, NOISE, path.q.shape)
            for tol in TOLERANCES:
                tracker = Tracker(model, maps[path.posture], joint_tolerance=tol, start_tolerance=(1e-9,) * 3)
                out[f"{path.name}|measured {tol:g}"] = digest(tracker.track(noisy, path.X[0]))
    return out


def differences(old: dict, new: dict) -> list:
    """``(stream, field)`` pairs whose digests differ, or that one side lacks."""
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, {}), new.get(key, {})
        out += [(key, f) for f in sorted(set(a) | set(b)) if a.get(f) != b.get(f)]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", help="write the digests (JSON) here")
    ap.add_argument("--compare", help="digests (JSON) of another run to compare with")
    args = ap.parse_args(argv)
    if not (args.out or args.compare):
        ap.error("give --out FILE, --compare FILE or both")
    t0 = time.perf_counter()
    new = digests()
    print(f"{len(new)} streams digested in {time.perf_counter() - t0:.0f} s")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(new, f, indent=0, sort_keys=True)
    if args.compare:
        with open(args.compare) as f:
            diff = differences(json.load(f), new)
        for key, field in diff[:50]:
            print(f"differs: {key}: {field}")
        print(f"{len(diff)} (stream, field) pairs differ" if diff else "identical: every field of every stream")
        return 1 if diff else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
