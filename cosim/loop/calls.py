"""The master's hot FMI calls: the FMU's C functions as fmpy loaded them, without fmpy's Python layer.

``FMU2Slave.fmi2GetReal(c, vr, n, value)`` is fmpy's ``_call``: a method call, a dict look-up, the ctypes
call (which converts and type-checks each argument), the call logger's check, and the status check that
raises :class:`fmpy.fmi1.FMICallException` above ``fmi2Warning``. A closed loop makes 9 to 11 such calls
a step. Measured on the plant FMU's ``fmi2GetReal`` of its outputs (medians of 5 x 100,000 calls, in one
process with the closed loop's FMUs): fmpy's method 0.9-1.5 us, fmpy's ctypes function 0.6-0.8 us, the
same C function through a ctypes prototype whose arguments are bound once as plain addresses
0.39-0.40 us, and through a cffi function pointer with the same bound addresses 0.27 us (cffi converts
the arguments in C; ctypes makes a Python object of each). On a ``fmi2DoStep`` with its three numbers,
the controller's: 2.73 us by the ctypes prototype, 2.40 us by cffi. The closed loop's step (11 calls):
33.5 -> 30.6 us.

:func:`hot_call` binds the leading arguments of one FMI function once (the instance, value-reference
and value arrays by address) and returns ``call(*rest) -> status``, a cffi function pointer to the
function fmpy loaded (:func:`c_declaration` writes its C type from fmpy's ctypes prototype); :func:`check`
is fmpy's status check, raising the same exception.  The arrays bound must outlive the call (the call
keeps them).  With an FMI call logger (``fmiCallLogger``) set, :func:`hot_call` binds fmpy's method
instead, so every call is still logged and checked.
"""
from __future__ import annotations

import ctypes
import functools

import cffi

#: fmpy raises above this status (fmi2Warning): fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending.
WORST_ACCEPTED = 1

__all__ = ["FMI_NAME", "ORDERS", "WORST_ACCEPTED", "c_declaration", "check", "hot_call", "step_sequence"]

_FFI = cffi.FFI()

#: One step's FMI calls in each master's order (:meth:`ClosedLoop.step_function`): (instance, what),
#: what "set" (its connected inputs), "step" (fmi2DoStep from t over h) or "get" (its Real outputs).
_ALL_STEP = (("dk", "step"), ("controller", "step"), ("plant", "step"), ("dk", "get"), ("controller", "get"),
             ("plant", "get"))
ORDERS = {
    "gauss-seidel": (("dk", "set"), ("dk", "step"), ("dk", "get"), ("controller", "set"), ("controller", "step"),
                     ("controller", "get"), ("plant", "set"), ("plant", "step"), ("plant", "get")),
    "jacobi": (("dk", "set"), ("controller", "set"), ("plant", "set")) + _ALL_STEP,
    "omsimulator": (("dk", "set"), ("dk", "get"), ("controller", "set"), ("controller", "get"), ("plant", "set"))
    + _ALL_STEP,
}
FMI_NAME = {"set": "fmi2SetReal", "step": "fmi2DoStep", "get": "fmi2GetReal"}


def hot_call(fmu, name: str, *fixed):
    """``call(*rest) -> status``: the FMI function ``name`` (e.g. ``"fmi2GetReal"``) of fmpy's slave
    ``fmu``, its leading arguments ``fixed`` bound once.

    Parameters
    ----------
    fmu : fmpy.fmi2.FMU2Slave
        An instantiated slave.
    name : str
        An FMI function fmpy loaded for it.
    *fixed
        Its first arguments: the instance (an address, int; None: NULL) and ctypes arrays (passed by
        address; kept alive by the call) or numbers.

    Returns
    -------
    callable
        ``call(*rest)``: the C function with ``fixed`` then ``rest``; its FMI status (int), unchecked
        (:func:`check`).  ``rest`` are numbers: when a pointer is left for the call, or a type is not
        one of :data:`_C_TYPES`, ``call`` is fmpy's ctypes function with ``fixed`` bound.  With an FMI
        call logger set: fmpy's method (logs, checks, raises).
    """
    functions = getattr(fmu, "_functions", None)
    if getattr(fmu, "fmiCallLogger", None) is not None or not isinstance(functions, dict) or name not in functions:
        return functools.partial(getattr(fmu, name), *fixed)
    raw = functions[name]
    decl = c_declaration(raw)
    if decl is None or any(_is_pointer(t) for t in raw.argtypes[len(fixed):]):
        # not a plain C call as fmpy declared it, or a pointer left for the call (cffi takes only its own
        # pointers there, ctypes also arrays and None): fmpy's ctypes function
        return functools.partial(raw, *fixed)
    call = _FFI.cast(decl, ctypes.cast(raw, ctypes.c_void_p).value)
    bound = []
    for arg, t in zip(fixed, raw.argtypes):
        if isinstance(arg, ctypes.Array):
            bound.append(_FFI.cast("void *", ctypes.addressof(arg)))
        elif _is_pointer(t):
            bound.append(_FFI.NULL if arg is None else _FFI.cast("void *", arg))
        else:
            bound.append(arg)
    out = functools.partial(call, *bound)
    out.keep = (fixed, raw)                     # the arrays bound by address, and the library's function
    return out


#: C types of the ctypes types fmpy declares FMI functions with (fmi2Status, fmi2Real, size_t, fmi2Boolean,
#: fmi1Boolean...).  ctypes.c_size_t is an alias (c_ulong on 64-bit Linux and macOS, c_ulonglong on
#: Windows): an argument of that type is written "size_t", which has its size; a c_char takes one byte.
_C_TYPES = {ctypes.c_int: "int", ctypes.c_uint: "unsigned int", ctypes.c_double: "double",
            ctypes.c_size_t: "size_t", ctypes.c_char: "char"}


def c_declaration(function) -> str | None:
    """The cffi type of the ctypes function ``function`` (as fmpy loaded it), pointers as ``void *``: for
    ``fmi2GetReal``, ``"int (*)(void *, void *, size_t, void *)"``.  None when it is not a plain C call
    of types :data:`_C_TYPES` and pointers (then :func:`hot_call` binds the ctypes function itself)."""
    if function.argtypes is None or getattr(function, "_flags_", 0) != ctypes.CFUNCTYPE(None)._flags_:
        return None
    args = ["void *" if _is_pointer(t) else _C_TYPES.get(t) for t in function.argtypes]
    result = _C_TYPES.get(function.restype)
    if result is None or None in args:
        return None
    return f"{result} (*)({', '.join(args)})"


def _is_pointer(t) -> bool:
    """Whether the ctypes type ``t`` is passed as an address (a pointer, or ``c_void_p``)."""
    return t is ctypes.c_void_p or t is ctypes.c_char_p or (isinstance(t, type) and issubclass(t, ctypes._Pointer))


def check(status: int, instance: str, function: str) -> None:
    """fmpy's status check of one call's ``status``: raise :class:`fmpy.fmi1.FMICallException` (naming
    ``instance`` and ``function``) when it is worse than fmi2Warning."""
    if status > WORST_ACCEPTED:
        from fmpy.fmi1 import FMICallException
        raise FMICallException(function=f"{instance}: {function}", status=status)


def step_sequence(calls: dict, order: str):
    """``advance(t, h)``: one step's FMI calls in the master's ``order`` (:data:`ORDERS`), each status checked.

    ``calls``: {(instance, what): call} for every instance and what of :data:`ORDERS`, each returning
    its FMI status: "set" and "get" take no argument, "step" takes ``(t, h, noSetFMUStatePriorToCurrentPoint)``.
    A status worse than fmi2Warning raises (:func:`check`) before the next call is made.  Each order is
    written out call by call (a loop over :data:`ORDERS`' entries costs 1.5 us more a step, measured).

    Raises
    ------
    ValueError
        ``order`` is not one of :data:`ORDERS`.
    """
    if order not in ORDERS:
        raise ValueError(f"order: expected one of {tuple(ORDERS)}, got {order!r}")
    W, SET, STEP, GET = WORST_ACCEPTED, FMI_NAME["set"], FMI_NAME["step"], FMI_NAME["get"]
    dk_set, dk_step, dk_get = calls["dk", "set"], calls["dk", "step"], calls["dk", "get"]
    ct_set, ct_step, ct_get = calls["controller", "set"], calls["controller", "step"], calls["controller", "get"]
    pl_set, pl_step, pl_get = calls["plant", "set"], calls["plant", "step"], calls["plant", "get"]

    def gauss_seidel(t, h):
        if (s := dk_set()) > W: check(s, "dk", SET)                          # noqa: E701
        if (s := dk_step(t, h, 1)) > W: check(s, "dk", STEP)                 # noqa: E701
        if (s := dk_get()) > W: check(s, "dk", GET)                          # noqa: E701
        if (s := ct_set()) > W: check(s, "controller", SET)                  # noqa: E701
        if (s := ct_step(t, h, 1)) > W: check(s, "controller", STEP)         # noqa: E701
        if (s := ct_get()) > W: check(s, "controller", GET)                  # noqa: E701
        if (s := pl_set()) > W: check(s, "plant", SET)                       # noqa: E701
        if (s := pl_step(t, h, 1)) > W: check(s, "plant", STEP)              # noqa: E701
        if (s := pl_get()) > W: check(s, "plant", GET)                       # noqa: E701

    def step_all(t, h):                         # every FMU steps from t, then every output is read
        if (s := dk_step(t, h, 1)) > W: check(s, "dk", STEP)                 # noqa: E701
        if (s := ct_step(t, h, 1)) > W: check(s, "controller", STEP)         # noqa: E701
        if (s := pl_step(t, h, 1)) > W: check(s, "plant", STEP)              # noqa: E701
        if (s := dk_get()) > W: check(s, "dk", GET)                          # noqa: E701
        if (s := ct_get()) > W: check(s, "controller", GET)                  # noqa: E701
        if (s := pl_get()) > W: check(s, "plant", GET)                       # noqa: E701

    def jacobi(t, h):
        if (s := dk_set()) > W: check(s, "dk", SET)                          # noqa: E701
        if (s := ct_set()) > W: check(s, "controller", SET)                  # noqa: E701
        if (s := pl_set()) > W: check(s, "plant", SET)                       # noqa: E701
        step_all(t, h)

    def omsimulator(t, h):
        if (s := dk_set()) > W: check(s, "dk", SET)                          # noqa: E701
        if (s := dk_get()) > W: check(s, "dk", GET)                          # noqa: E701
        if (s := ct_set()) > W: check(s, "controller", SET)                  # noqa: E701
        if (s := ct_get()) > W: check(s, "controller", GET)                  # noqa: E701
        if (s := pl_set()) > W: check(s, "plant", SET)                       # noqa: E701
        step_all(t, h)

    return {"gauss-seidel": gauss_seidel, "jacobi": jacobi, "omsimulator": omsimulator}[order]
