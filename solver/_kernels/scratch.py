"""Scratch arrays in the calling kernel's stack frame: ``np.empty`` without the heap.

A kernel's small working arrays (a 3x3 system, the six roots, a candidate mask) cost a heap
allocation and a free each through numba's runtime, about 25 ns a pair: 189 a certified step and 15 a
Newton step before this module (numba's ``NUMBA_NRT_STATS`` counts, ``tests/test_scratch.py``), a
third of the one's kernel time and a third of the other's (docs/benchmarks.md, section step).
:func:`scratch` gives the same arrays in the stack frame of the function that calls it: one
``alloca`` in that function's entry block, taken once per call of it however often a loop in it
asks, given back when it returns.

Rules, as for any stack memory:

- the array must not outlive the call of the function that made it: never return it (or a view of
  it), never store it where a caller keeps it.  Views of it passed *down* to callees are fine;
- its content is undefined, as ``np.empty``'s: write before reading (fill it where ``np.zeros`` or
  ``np.full`` stood);
- its shape is made of compile-time constants (literals or module constants), so a frame's size is
  known, and one array is at most :data:`MAX_BYTES` (refused at compile time above).  The largest
  kernel frame is the tube test's (:func:`.tube.slab_test`, about 2.3 kB of arrays); with the callees
  LLVM inlines, a whole step runs on a 32 KiB thread stack (``tests/test_scratch.py``), the smallest
  Python makes.  Larger work arrays (the tube chain's 58 kB table of pieces) stay on the heap.

(numba's ``cgutils.alloca_once`` zeroes the first element where it allocates; the rest is undefined.)
"""
from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array
from numba.np.numpy_support import as_dtype

__all__ = ["floats", "scratch", "scratch2", "scratch3", "MAX_BYTES"]

#: The largest stack array (bytes): larger ones belong on the heap (a host thread's stack may be small).
MAX_BYTES = 4096


def _constant(name, value) -> int:
    if not isinstance(value, types.IntegerLiteral):
        raise TypingError(f"{name}: expected a compile-time constant integer (a literal or a module constant), "
                          f"got {value}")
    if value.literal_value < 1:
        raise TypingError(f"{name}: expected a positive size, got {value.literal_value}")
    return value.literal_value


def _dtype(dtype):
    if isinstance(dtype, (types.NumberClass, types.DType)):
        return dtype.dtype
    raise TypingError(f"dtype: expected a numpy scalar type such as np.float64, got {dtype}")


def _stack_array(context, builder, arrty, shape):
    """An array of type ``arrty`` and ``shape`` (python ints) on the stack, C order, no meminfo (no free)."""
    item = context.get_data_type(arrty.dtype)     # (a bool is a byte in an array)
    size = 1
    for s in shape:
        size *= s
    itemsize = context.get_abi_sizeof(item)
    data = cgutils.alloca_once(builder, item, size=context.get_constant(types.intp, size))
    strides, stride = [], itemsize
    for s in reversed(shape):
        strides.insert(0, stride)
        stride *= s
    ary = make_array(arrty)(context, builder)
    populate_array(ary, data=data, shape=[context.get_constant(types.intp, s) for s in shape],
                   strides=[context.get_constant(types.intp, s) for s in strides],
                   itemsize=context.get_constant(types.intp, itemsize), meminfo=None)
    return ary._getvalue()


def _typed(sizes, dtype, args):
    """The signature (an array of ``dtype`` and the constant ``sizes``' shape, of the intrinsic's ``args``)
    and the codegen of a stack array."""
    shape = tuple(_constant(name, value) for name, value in sizes)
    size = as_dtype(dtype).itemsize
    for s in shape:
        size *= s
    if size > MAX_BYTES:
        raise TypingError(f"scratch: expected at most {MAX_BYTES} bytes on the stack, got {shape} of {dtype} "
                          f"({size} bytes): allocate it on the heap (np.empty)")
    arrty = types.Array(dtype, len(shape), "C")

    def codegen(context, builder, signature, args):
        return _stack_array(context, builder, arrty, shape)

    return arrty(*args), codegen


@intrinsic
def floats(typingctx, n):
    """A float64 array ``(n,)`` in the caller's stack frame (``n`` a constant): :func:`scratch`'s common case."""
    return _typed((("n", n),), types.float64, (n,))


@intrinsic
def scratch(typingctx, n, dtype):
    """A C-contiguous array ``(n,)`` of ``dtype`` in the caller's stack frame (``n`` a constant)."""
    return _typed((("n", n),), _dtype(dtype), (n, dtype))


@intrinsic
def scratch2(typingctx, n, m, dtype):
    """A C-contiguous array ``(n, m)`` of ``dtype`` in the caller's stack frame (constants)."""
    return _typed((("n", n), ("m", m)), _dtype(dtype), (n, m, dtype))


@intrinsic
def scratch3(typingctx, n, m, k, dtype):
    """A C-contiguous array ``(n, m, k)`` of ``dtype`` in the caller's stack frame (constants)."""
    return _typed((("n", n), ("m", m), ("k", k)), _dtype(dtype), (n, m, k, dtype))
