"""The kernels' scratch arrays on the stack (:mod:`solver._kernels.scratch`): what they are, that a step
no longer allocates on the heap, and that a step still runs on the smallest thread stack Python makes."""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from host_support import run_python
from solver._kernels.scratch import MAX_BYTES, floats, scratch, scratch2, scratch3

SIX = 6


@njit(cache=False)
def _fill_and_sum():
    a = scratch3(3, 2, 3, np.float64)
    for i in range(3):
        for j in range(2):
            for k in range(3):
                a[i, j, k] = 100 * i + 10 * j + k
    flags = scratch(SIX, np.bool_)              # a module constant is a constant size
    flags[:] = False
    flags[3] = True
    z = scratch2(2, 3, np.complex128)
    for i in range(2):
        for j in range(3):
            z[i, j] = complex(i, j)
    v = floats(4)
    for i in range(4):
        v[i] = 0.5 * i
    return a.sum(), a[2, 1, 2], a[1].sum(), flags.sum(), np.argmax(flags), z.sum(), v.sum(), a.strides, z.strides


def test_scratch_arrays_are_c_arrays_of_their_shape_and_dtype():
    ref = np.empty((3, 2, 3))
    for i in range(3):
        for j in range(2):
            for k in range(3):
                ref[i, j, k] = 100 * i + 10 * j + k
    total, corner, middle, n_true, where, zsum, vsum, strides, zstrides = _fill_and_sum()
    assert (total, corner, middle) == (ref.sum(), ref[2, 1, 2], ref[1].sum())
    assert (n_true, where) == (1, 3)                     # a bool is a byte, as in a numpy array
    assert zsum == complex(3, 6)
    assert vsum == 3.0
    assert strides == ref.strides and zstrides == np.empty((2, 3), np.complex128).strides


def test_a_size_that_is_not_a_constant_is_refused_at_compile_time():
    @njit(cache=False)
    def runtime_size(n):
        return scratch(n, np.float64).shape[0]

    with pytest.raises(TypingError, match="compile-time constant"):
        runtime_size(3)


def test_an_empty_or_a_large_stack_array_is_refused_at_compile_time():
    @njit(cache=False)
    def empty():
        return scratch(0, np.float64).shape[0]

    @njit(cache=False)
    def large():                                # 4104 bytes: over MAX_BYTES (4096)
        return scratch2(27, 19, np.float64).shape[0]

    @njit(cache=False)
    def largest():                              # 4096 bytes of bools: the most allowed
        return scratch(MAX_BYTES, np.bool_).shape[0]

    with pytest.raises(TypingError, match="positive size"):
        empty()
    with pytest.raises(TypingError, match="at most 4096 bytes"):
        large()
    assert largest() == MAX_BYTES


_ALLOCATIONS = """
import sys
import numpy as np
from numba.core.runtime import rtsys
from solver import Manipulator, Tracker, cached_map, circle_path, ik
from solver.baselines import NewtonTracker
m = Manipulator.paper()
X = circle_path(300)
q = ik(m, X, 1)
qn = q + np.random.default_rng(0).uniform(-1e-4, 1e-4, q.shape)
trackers = {
    "newton": (NewtonTracker(m), q),
    "tracker": (Tracker(m, cached_map(m, 1), start_tolerance=(1e-9,) * 3), q),
    "measured": (Tracker(m, cached_map(m, 1), start_tolerance=(1e-3,) * 3, joint_tolerance=1e-4,
                         speed_bound=(0.5, 2.0)), qn),
}
for name, (tr, qs) in trackers.items():
    tr.track(qs[:20], X[0])
    before = rtsys.get_allocation_stats().alloc
    tr.track(qs, X[0])
    print(name, (rtsys.get_allocation_stats().alloc - before) / len(qs))
"""


def test_a_step_allocates_next_to_nothing_on_the_heap():
    """numba's runtime counts its heap allocations (NUMBA_NRT_STATS): a Newton step makes none, a certified
    step at most one (the tube chain's table of pieces, 58 kB: too large for a host thread's stack); there
    were 15 and 189 before the kernels' small arrays moved to the stack."""
    proc = run_python(_ALLOCATIONS, env={"NUMBA_NRT_STATS": "1"})
    assert proc.returncode == 0, proc.stderr
    per_step = {line.split()[0]: float(line.split()[1]) for line in proc.stdout.splitlines()}
    assert per_step["newton"] == 0.0
    assert per_step["tracker"] <= 1.05          # (the track call's own blocks and table are allocated in Python)
    assert per_step["measured"] <= 1.05


_SMALL_STACK = """
import threading
import numpy as np
from solver import Manipulator, Tracker, cached_map, circle_path, ik
m = Manipulator.paper()
X = circle_path(200)
q = ik(m, X, 1)
qn = q + np.random.default_rng(0).uniform(-1e-4, 1e-4, q.shape)
runs = [(dict(), q), (dict(joint_tolerance=1e-4, speed_bound=(0.5, 2.0), start_tolerance=(1e-3,) * 3), qn),
        (dict(joint_tolerance=1e-4, step_budget=1e-4, start_tolerance=(1e-3,) * 3), qn)]
def make(kw):
    kw = {"start_tolerance": (1e-9,) * 3, **kw}
    return Tracker(m, cached_map(m, 1), **kw)
main = [make(kw).track(qs, X[0]).X for kw, qs in runs]
threading.stack_size(32 * 1024)                 # the smallest Python makes
got = []
t = threading.Thread(target=lambda: got.extend(make(kw).track(qs, X[0]).X for kw, qs in runs))
t.start()
t.join()
assert len(got) == 3
for a, b, (kw, _) in zip(main, got, runs):
    if "step_budget" not in kw:                 # (a budget's steps depend on the clock)
        assert np.array_equal(a, b)
print("ok")
"""


def test_a_step_runs_on_a_32_kib_thread_stack():
    """A host calls the FMU's step on its own threads, whose stacks may be small: the kernels' stack arrays
    (at most about 2.3 kB a kernel, the tube test's) leave a whole stream, exact or measured, within the smallest thread
    stack Python makes; the poses are the main thread's.  (Run in a child: an overflow is a crash.)"""
    proc = run_python(_SMALL_STACK)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-2000:]
