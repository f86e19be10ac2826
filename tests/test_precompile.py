"""solver.precompile: the kernels a tracker's Python side calls, compiled without a map, are the ones a tracker
on a real map (as the DK FMU uses it) calls: after compile_tracker, that tracker compiles nothing new."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from solver import Manipulator, cached_map
from solver.precompile import TOY_SHAPE, toy_map

ROOT = Path(__file__).resolve().parents[1]

#: a fresh process (nothing compiled or loaded yet): compile_tracker, then a tracker on the paper's map as the
#: DK FMU drives it; prints the (kernel, signature) pairs the second part added
_CHILD = r"""
import importlib, json, pkgutil
import numpy as np
from numba.core.dispatcher import Dispatcher
import solver._kernels
from solver import Manipulator, Tracker, cached_map, dk_all, ik, jacobians
from solver.manipulator import HOME_POSE
from solver.precompile import compile_tracker

def compiled():
    seen = set()
    for info in pkgutil.iter_modules(solver._kernels.__path__):
        module = importlib.import_module("solver._kernels." + info.name)
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher) and value.__module__ == module.__name__:
                seen.update((module.__name__ + "." + name, str(sig)) for sig in value.overloads)
    return seen

model = Manipulator.paper()
mt = cached_map(model, 1, progress=False)
compile_tracker()
before = compiled()
X0 = np.array(HOME_POSE) + np.array([0.01, -0.02, 0.1])
q0 = ik(model, X0, posture=1)
dk_all(model, q0, rule=mt.rule)                         # what the DK FMU's initial outputs call
jacobians(model, X0, q0)
mt.near_labels(X0, None, mt.default_weights)
tracker = Tracker(model, mt)
tracker.reset(X0, q0)
for k in range(1, 12):
    tracker.step(ik(model, X0 + np.array([2e-4 * k, 1e-4 * k, 1e-3 * k]), posture=1), 1e-3)
snap = tracker.snapshot()
tracker.step(ik(model, X0, posture=1), 1e-3)
tracker.restore(snap)
print(json.dumps({"before": sorted(n for n, _ in before), "added": sorted(map(list, compiled() - before))}))
"""


def test_the_toy_map_has_a_real_maps_types():
    model = Manipulator.paper()
    toy, real = toy_map(model), cached_map(model, 1)
    assert toy.labels.shape == TOY_SHAPE and toy.labels.dtype == real.labels.dtype
    assert toy.labels.flags.writeable == real.labels.flags.writeable
    assert toy.rule == real.rule and toy.periodic == real.periodic
    np.testing.assert_array_equal(toy.bounds, real.bounds)


def test_a_tracker_on_a_real_map_compiles_nothing_compile_tracker_did_not():
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "solver._kernels.start.certify_start" in out["before"]       # the start's proof was compiled
    assert "solver._kernels.stepper.copy_state" in out["before"]        # and the flat state's copies
    assert out["added"] == []
