"""A C entry point called from Python through one numba dispatch instead of ctypes.

The tracker's step is a numba ``cfunc`` (:func:`.c_entry.entry`): a C function of signature
``int64 f(void *table, int64 cmd, double t, double h)``.  Calling it through ``CFunc.ctypes`` costs
about 0.55 us a call on the machine of ``bench/bench_step.py``: ctypes converts the four arguments
through their ``argtypes``, releases the GIL and takes it back.  :func:`call_entry` is a tiny compiled
function that takes the function's address as its first argument and calls it: one numba dispatch of
five scalars, about 0.25 us with the GIL released around the call as ctypes does (``nogil``: 45 ns of
it), so trackers in several threads still step in parallel.

The address is an argument, not a constant baked into the machine code, so :func:`call_entry` is
cached on disk like any kernel (an address differs from process to process).  It has one signature,
:data:`SIGNATURE` (other argument types are a typing error, not a new compile at call time), which
:meth:`solver.Tracker._entry` compiles or loads when it loads the entry point: a DK FMU's slave does
that when it connects its fast lane, in the build's warm-up too, so the FMU ships it with its other
kernels and its Python path (the steps the fast lane hands back) never compiles it on a host's thread.
"""
from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.core.errors import TypingError
from numba.extending import intrinsic

__all__ = ["call_entry", "SIGNATURE"]

#: The one signature of :func:`call_entry`: (function address, table address, command, t, h).
SIGNATURE = types.int64(types.int64, types.int64, types.int64, types.float64, types.float64)


@intrinsic
def _call_address(typingctx, fn, table, cmd, t, h):
    """Call the C function at address ``fn`` (int64) as ``int64 f(void *, int64, double, double)``."""
    sig = SIGNATURE
    if (fn, table, cmd, t, h) != tuple(sig.args):
        raise TypingError(f"call_entry: expected (int64, int64, int64, float64, float64), got {(fn, table, cmd, t, h)}")

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        fnty = ir.FunctionType(i64, [ir.IntType(8).as_pointer(), i64, f64, f64])
        target = builder.inttoptr(args[0], fnty.as_pointer())
        table_ptr = builder.inttoptr(args[1], ir.IntType(8).as_pointer())
        return builder.call(target, [table_ptr, args[2], args[3], args[4]])

    return sig, codegen


@njit(cache=True, nogil=True)
def call_entry(fn, table, cmd, t, h):
    """``f(table, cmd, t, h)`` of the C entry point ``f`` at address ``fn``.

    Parameters
    ----------
    fn : int
        Address of a C function ``int64 f(void *table, int64 cmd, double t, double h)``
        (``entry().address``): it must stay loaded while it is called.
    table : int
        Address of the entry point's table (:func:`.c_entry.make_table`, ``table.ctypes.data``).
    cmd : int
        Command code (:data:`.c_entry.CMD_ADVANCE`, ...).
    t, h : float
        The command's two doubles.

    Returns
    -------
    int
        What ``f`` returns.

    Notes
    -----
    The GIL is released during the call: ``f`` must not touch Python objects (a numba ``cfunc``
    in nopython mode does not).
    """
    return _call_address(fn, table, cmd, t, h)
