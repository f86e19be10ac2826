"""A kernel compiled for a caller (solver.lean_compile): no machine code and no disk cache entry of its own,
the caller's results bit for bit numba's own, and a Python call of it still runs (compiled whole then,
and a cached kernel written to disk then)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: a fresh process, empty numba cache: ``leg_batch`` (cached) calls ``leg_row`` (callee-only) calls
#: ``loop_row``; then Python calls ``leg_row`` itself
_CHILD = r"""
import json
import numpy as np
from solver import lean_compile
from solver._kernels import kinematics as k

rng = np.random.default_rng(7)
X = rng.uniform(-0.3, 0.3, (40, 3)); q = rng.uniform(-3.0, 3.0, (40, 3))
M = rng.uniform(-1.0, 1.0, (3, 2)); l1 = rng.uniform(0.2, 0.8, 3); b = rng.uniform(-0.3, 0.3, (3, 2))
out = np.empty((40, k.LEG_ROWS, 3))
k.leg_batch(X, q, M, l1, b, out)
sig = next(iter(k.leg_row.overloads))
linked = lean_compile.linked_only(k.leg_row, sig)
c, s = np.cos(X[5, 2]), np.sin(X[5, 2])
row = k.leg_row(X[5, 0], X[5, 1], c, s, q[5, 1], M[1, 0], M[1, 1], l1[1], b[1, 0], b[1, 1])
again = k.leg_row(X[6, 0], X[6, 1], c, s, q[6, 1], M[1, 0], M[1, 1], l1[1], b[1, 0], b[1, 1])
print(json.dumps({"installed": lean_compile.installed(), "linked_only": linked,
                  "linked_only_after_python_call": lean_compile.linked_only(k.leg_row, sig),
                  "out": [v.hex() for v in out.ravel()],
                  "python_row": [float(v).hex() for v in row], "batch_row": [v.hex() for v in out[5, :, 1]],
                  "again_finite": bool(np.all(np.isfinite(again)))}))
"""


#: a fresh process, empty numba cache: ``ik_batch`` (cached) calls ``ik_pose`` (cached too); then Python
#: calls ``ik_pose`` itself; the cache entries of ``ik_pose`` on disk before and after that call
_CACHED_CHILD = r"""
import glob, json, os
import numpy as np
from solver import lean_compile
from solver._kernels import kinematics as k

def entries():
    return len(glob.glob(os.path.join(os.environ["NUMBA_CACHE_DIR"], "**", "*ik_pose*.nbi"), recursive=True))

rng = np.random.default_rng(3)
X = np.column_stack([rng.uniform(-0.05, 0.05, 30), rng.uniform(-0.05, 0.05, 30), rng.uniform(-0.5, 0.5, 30)])
M = np.array([[0.0, 0.0], [0.5, 0.0], [0.25, 0.43]]); l1 = np.full(3, 0.3); l2 = np.full(3, 0.3)
b = np.array([[0.1, -0.05], [-0.1, -0.05], [0.0, 0.1]])
bits = np.full(30, 5, dtype=np.int64)
out = np.empty((30, 3))
k.ik_batch(X, bits, M, l1, l2, b, out)
sig = next(iter(k.ik_pose.overloads))
before = entries()
linked = lean_compile.linked_only(k.ik_pose, sig)
q = np.empty(3)
n = int(np.flatnonzero(np.isfinite(out[:, 0]))[0]) if np.isfinite(out[:, 0]).any() else 0
ok = k.ik_pose(X[n, 0], X[n, 1], X[n, 2], bits[n], M, l1, l2, b, q)
print(json.dumps({"linked_only": linked, "entries_before": before, "entries_after": entries(),
                  "out": [v.hex() for v in out.ravel()], "python_q": [v.hex() for v in q] if ok else None,
                  "batch_q": [v.hex() for v in out[n]], "reachable": int(np.isfinite(out[:, 0]).sum())}))
"""


def _child(numba_cache: Path, code: str = _CHILD, **env_extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "RRR_DK_LEAN_COMPILE")}
    env.update(NUMBA_CACHE_DIR=str(numba_cache), PYTHONPATH=str(ROOT), RRR_DK_SHARED_KERNELS="0", **env_extra)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_a_callee_compiled_for_its_caller_has_no_code_of_its_own_and_changes_no_bit(tmp_path):
    lean = _child(tmp_path / "lean")
    whole = _child(tmp_path / "whole", RRR_DK_LEAN_COMPILE="0")
    assert lean["installed"] and not whole["installed"]
    # the callee was compiled for leg_batch only: no machine code of its own
    assert lean["linked_only"] and not whole["linked_only"]
    # leg_batch's results are numba's own compile's, bit for bit
    assert lean["out"] == whole["out"]
    # Python calls the callee: it is compiled whole on that call and gives the caller's values
    assert not lean["linked_only_after_python_call"]
    assert lean["python_row"] == lean["batch_row"] == whole["python_row"]
    assert lean["again_finite"]


def test_a_cached_kernel_compiled_for_its_caller_is_written_to_disk_only_when_python_calls_it(tmp_path):
    lean = _child(tmp_path / "lean", _CACHED_CHILD)
    whole = _child(tmp_path / "whole", _CACHED_CHILD, RRR_DK_LEAN_COMPILE="0")
    assert lean["reachable"] > 0                                  # the poses exercise the kernel
    # compiled for ik_batch only: no machine code and no disk entry of its own (numba's compile writes one)
    assert lean["linked_only"] and lean["entries_before"] == 0
    assert not whole["linked_only"] and whole["entries_before"] > 0
    # the caller's results are numba's own compile's, bit for bit
    assert lean["out"] == whole["out"]
    # Python calls it: compiled whole, written to disk then, and equal to the caller's row
    assert lean["entries_after"] > 0
    assert lean["python_q"] == lean["batch_q"] == whole["python_q"]


#: a fresh process: a project kernel (its module named as one) called with three constants, and one whose
#: typing needs its constant (a heterogeneous tuple's index); prints their overloads and the caller's values
_CONSTANTS_CHILD = r"""
import json
import numpy as np
from numba import njit
import solver                                        # installs the lean compile (unless turned off)

def _scaled(a, k):
    return a[k] * 2.0

def _picked(k):
    t = (1.5, 7)
    return t[k]

for f in (_scaled, _picked):
    f.__module__ = "solver._kernels.probe"           # the rule is by module
scaled, picked = njit(cache=False)(_scaled), njit(cache=False)(_picked)

@njit(cache=False)
def caller(a):
    return scaled(a, 0) + scaled(a, 1) + scaled(a, 2) + picked(0) + picked(1)

a = np.array([0.1, 0.2, 0.3])
print(json.dumps({"value": float(caller(a)).hex(), "scaled": sorted(str(s) for s in scaled.overloads),
                  "picked": sorted(str(s) for s in picked.overloads)}))
"""


def test_a_kernel_a_caller_calls_with_constants_is_compiled_once_for_their_plain_types(tmp_path):
    lean = _child(tmp_path / "lean", _CONSTANTS_CHILD)
    whole = _child(tmp_path / "whole", _CONSTANTS_CHILD, RRR_DK_LEAN_COMPILE="0")
    # numba's own compile: one overload per constant; the lean one: the plain type, once
    assert len(whole["scaled"]) == 3 and all("Literal[int]" in s for s in whole["scaled"])
    assert len(lean["scaled"]) == 1 and "Literal" not in lean["scaled"][0] and "int64" in lean["scaled"][0]
    # a kernel whose typing needs the constant keeps numba's literal compile
    assert len(lean["picked"]) == 2 and all("Literal[int]" in s for s in lean["picked"])
    assert lean["value"] == whole["value"]
