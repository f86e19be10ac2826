"""A clock the kernels can read: the CPU's cycle counter, for the step budget's deadline.

numba's compiled code cannot call Python's clocks.  :func:`cycles` reads the processor's cycle
counter (LLVM's ``readcyclecounter``: ``rdtsc`` on x86-64, about 10 ns a read, compiled and
cached like any kernel); :func:`cycles_per_second` calibrates it once per process against
:func:`time.perf_counter` (about 20 ms).  Modern x86-64 CPUs keep this counter at a constant
rate whatever the core's clock (an invariant TSC), which is what a deadline needs.

A *deadline* is a cycle count as a float (0.0: none); :func:`expired` says whether it has passed.
"""
from __future__ import annotations

import platform
import time

from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

#: Seconds the calibration of :func:`cycles_per_second` lasts.
CALIBRATION = 0.02
_RATE: list[float] = []


@intrinsic
def _read_cycle_counter(typingctx):
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.readcyclecounter", fnty=ir.FunctionType(ir.IntType(64), []))
        return builder.call(fn, [])

    return sig, codegen


@njit(cache=True)
def cycles():
    """The CPU's cycle counter now (an integer count; only differences mean something)."""
    return _read_cycle_counter()


@njit(cache=True)
def expired(deadline):
    """Whether the deadline ``deadline`` (a cycle count as float; 0.0 or less: none) has passed."""
    return deadline > 0.0 and float(cycles()) > deadline


def cycles_per_second() -> float:
    """The cycle counter's rate (counts per second), measured once per process."""
    if not _RATE:
        if platform.machine().lower() not in ("x86_64", "amd64", "i386", "i686"):
            raise RuntimeError(f"a step budget reads the x86-64 cycle counter; this CPU is {platform.machine()!r} "
                               "(use step_budget=None here)")
        cycles()                                      # compiled or loaded before the measurement
        t0, c0 = time.perf_counter(), cycles()
        time.sleep(CALIBRATION)
        t1, c1 = time.perf_counter(), cycles()
        rate = (c1 - c0) / (t1 - t0)
        if not rate > 0.0:
            raise RuntimeError(f"the CPU's cycle counter does not advance ({c0} then {c1}): no step budget here")
        _RATE.append(rate)
    return _RATE[0]


def deadline_after(seconds: float | None) -> float:
    """The deadline ``seconds`` from now (a cycle count as float); 0.0 (none) for None."""
    if seconds is None:
        return 0.0
    rate = cycles_per_second()                        # calibrated first (once)
    return float(cycles()) + seconds * rate
