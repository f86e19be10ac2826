"""Addresses as pointers inside compiled code: what a C entry point (a numba ``cfunc``) needs to view
the arrays whose addresses a table holds (:mod:`.c_entry`, :mod:`dynamics._kernels.c_entry`)."""
from __future__ import annotations

from numba import types
from numba.extending import intrinsic

__all__ = ["address_pointer"]


@intrinsic
def address_pointer(typingctx, address):
    """The integer ``address`` (int64) as a void pointer (what ``numba.carray`` views)."""
    sig = types.voidptr(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return sig, codegen
