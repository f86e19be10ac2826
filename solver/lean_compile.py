"""Compile a kernel once: the machine code of a kernel compiled for a caller is made in its callers only.

numba compiles every ``@njit`` function it meets as a whole program of its own: it links the
callees' LLVM modules into the function's module, optimises that module at ``-O3``, emits its
machine code and, for a cached kernel, writes it to disk, even when the function is compiled only
because a caller calls it.  The caller then links the same callees again, optimises and emits them
again, and so does the caller's caller.  A kernel ``d`` levels down is optimised and emitted ``d``
times; the certified step is about eight levels deep, so most of a first compile was LLVM redoing
its own work.

:func:`install` changes that for the project's kernels (:mod:`solver._kernels` and
:mod:`dynamics._kernels`) when numba compiles one *for a caller* (another compile is under way): the
kernel's own module is optimised per function as before and linked into the caller, but it is not
optimised as a whole, not turned into machine code of its own and not written to numba's disk cache
(an entry already on disk, from an earlier Python call, is still loaded).  The outermost kernel (the
kernel Python called, or the FMU's C entry point) optimises and emits the whole linked program once,
as before, and is cached as before.  The callees then reach their callers optimised per function
only, so LLVM may inline differently; without fast-math its passes keep IEEE semantics, and the
results are the same bit for bit (tests/test_lean_compile.py; the FMU tests compare FMUs built this
way with trackers compiled before it).

Constants: numba types a call with constant arguments with their literal types (``Literal[int](0)``,
``Literal[bool](True)``) and compiles the callee once per distinct constant (six times one kernel of
the tube chain).  A project kernel compiled for a caller is compiled once for the plain types instead
(the caller's call converts its constants); one whose compile needs a constant (a numba error without
it: ``numba.literally``, a literal-only overload) gets the literal compile as before, and so does a
kernel that calls itself (numba matches a recursive call by its literal types).  The same arithmetic
either way, so the same results.

Left to numba's own compile: a library that calls through numba's table of recursive references
(only a library with machine code fills it), lifted loops and object-mode blocks, C callbacks, and
numba's own overloads (``np.dot``, string formatting).  Not handled, since no kernel does it: a kernel
compiled for a caller that needs its numba environment at run time (``print`` of an array,
object-mode blocks inside it) would find none in the process that compiled it.

Measured on the C entry point of the DK FMU (fresh process, empty cache, one core): 162 s to compile
(114 s of it in LLVM) with numba's own compile; 107-115 s with the ``cache=False`` kernels compiled
for their callers only (55 s of it in 244 whole-program finalisations, 47 s of them for cached kernels
the entry point calls); 69.5 s with every project kernel so (105 whole finalisations, 8.8 s, 7.0 s of
them the entry point's own; 68-76 s in five runs); 64.2 s with constants' plain types (133 compiles
fewer); the tracker's step the same (29.2 and 29.7 us in one run).

Safety: such a kernel has no machine code of its own, so numba's table of Python-callable overloads
never lists it.  Python calling it (a test, a user) compiles it whole on that call, as numba would
have (and writes a cached kernel to disk then), and the Python call runs that.  Not covered, since
nothing in the project does it: code that takes such an overload's entry point itself
(``dispatcher.overloads[sig].entry_point``, ``get_overload``) would call address 0, and so would a
Python call of it made from inside a compile (a typing hook).  The fallback is off
with ``RRR_DK_LEAN_COMPILE=0``, and off by itself with a numba whose internals differ from the ones
this patches (then every compile is numba's own: slower, never wrong).
"""
from __future__ import annotations

import os
import threading

__all__ = ["install", "installed", "linked_only", "ENV"]

#: The environment variable that turns the lean compile off (``0``).
ENV = "RRR_DK_LEAN_COMPILE"
#: The packages whose kernels are compiled for their callers only when a caller's compile needs them.
KERNEL_PACKAGES = ("solver._kernels", "dynamics._kernels")
_MARK = "_rrr_dk_lean_compile"
_LINKED_ONLY = "_rrr_dk_linked_only"          # set on a library compiled for its callers only
_state = threading.local()                    # .stack: one flag per compile under way (True: for a caller only)


def installed() -> bool:
    """Whether this process compiles the project's kernels for their callers only (see the module doc)."""
    try:
        from numba.core import codegen
    except ImportError:
        return False
    return getattr(codegen.CPUCodeLibrary.finalize, _MARK, False)


def linked_only(dispatcher, signature) -> bool:
    """Whether ``dispatcher``'s overload of ``signature`` (a tuple of numba types) was compiled for its
    callers only (no machine code of its own; a Python call compiles it whole first)."""
    cres = dispatcher.overloads.get(tuple(signature))
    return cres is not None and getattr(cres.library, _LINKED_ONLY, False)


def _stack() -> list:
    stack = getattr(_state, "stack", None)
    if stack is None:
        stack = _state.stack = []
    return stack


def _recursive(library) -> bool:
    """Whether ``library`` calls through numba's table of unresolved (recursive) references, which only
    a library with machine code of its own fills: then it is finalized whole."""
    return any(gv.name.startswith(".numba.unresolved$") for gv in library._final_module.global_variables)


def _project_kernel(dispatcher) -> bool:
    """A kernel of :data:`KERNEL_PACKAGES`."""
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module.startswith(KERNEL_PACKAGES)


def _plain(sig):
    """``sig`` (argument types, as a caller's typing asks for them) with every literal type made plain
    (``Literal[int](0)`` -> ``int64``), or None when it has none (or names a return type)."""
    from numba.core import sigutils, types
    args, ret = sigutils.normalize_signature(sig)
    plain = tuple(types.unliteral(a) for a in args)
    return plain if ret is None and plain != tuple(args) else None


class _LoadOnly:
    """A kernel's disk cache while the kernel is compiled for a caller: an entry on disk (a whole compile of
    an earlier Python call) is loaded as before; a linked-only overload is not written (it has no machine
    code, and writing one would emit it)."""

    __slots__ = ("_cache",)

    def __init__(self, cache):
        self._cache = cache

    def save_overload(self, sig, cres):
        if not getattr(cres.library, _LINKED_ONLY, False):
            self._cache.save_overload(sig, cres)

    def __getattr__(self, name):
        if name == "_cache":                  # not set (a copy): no endless lookup
            raise AttributeError(name)
        return getattr(self._cache, name)


def _patchable(codegen, cpu, dispatcher, ccallback, caching) -> bool:
    """Whether numba has the internals this module patches (checked by name; a numba that lacks one
    keeps its own compile)."""
    needs = [(codegen.CPUCodeLibrary, ("finalize", "_get_module_for_linking", "_finalize_dynamic_globals",
                                       "_raise_if_finalized", "_ensure_finalized")),
             (codegen, ("require_global_compiler_lock",)), (cpu.CPUContext, ("get_executable",)),
             (dispatcher.Dispatcher, ("compile", "add_overload", "is_compiling")), (dispatcher, ("LiftedCode",)),
             (ccallback.CFunc, ("compile",)),
             (caching, ("NullCache",))]
    return all(hasattr(owner, name) for owner, names in needs for name in names)


def install() -> None:
    """Compile the project's kernels for their callers only when a caller needs them (once per process; not
    with ``RRR_DK_LEAN_COMPILE=0``, nor with a numba whose internals differ)."""
    if os.environ.get(ENV, "1").strip() == "0":
        return
    try:
        from numba import _dynfunc
        from numba.core import caching, ccallback, codegen, cpu, dispatcher
    except ImportError:                       # no numba, no kernels
        return
    if installed() or not _patchable(codegen, cpu, dispatcher, ccallback, caching):
        return
    from numba.core import errors
    from numba.core.compiler_lock import global_compiler_lock

    library_cls, context_cls, dispatcher_cls = codegen.CPUCodeLibrary, cpu.CPUContext, dispatcher.Dispatcher
    lifted_cls = dispatcher.LiftedCode
    finalize, get_executable = library_cls.finalize, context_cls.get_executable
    compile_overload, add_overload, compile_cfunc = dispatcher_cls.compile, dispatcher_cls.add_overload, \
        ccallback.CFunc.compile

    def lean_finalize(self):
        stack = _stack()
        if not (stack and stack[-1]) or _recursive(self):
            return finalize(self)
        # numba's finalize without the whole-module optimisation and the machine code: link the
        # callees (their callers link this module in turn), keep what numba records, and stop
        codegen.require_global_compiler_lock()
        self._raise_if_finalized()
        seen = set()
        for library in self._linking_libraries:
            if library not in seen:
                seen.add(library)
                self._reload_init.update(library._reload_init)
                self._final_module.link_in(library._get_module_for_linking(), preserve=True)
        self._finalize_dynamic_globals()
        setattr(self, _LINKED_ONLY, True)
        self._finalized = True

    def lean_get_executable(self, library, fndesc, env):
        library._ensure_finalized()                            # lean or whole, as the compile under way says
        if not getattr(library, _LINKED_ONLY, False):
            return get_executable(self, library, fndesc, env)
        # no machine code, no address: a function object numba keeps but never lists for Python calls
        return _dynfunc.make_function(fndesc.lookup_module(), fndesc.qualname.split(".")[-1],
                                      f"linked-only overload of {fndesc.qualname!r}", 0, env, (library,))

    def lean_compile(self, sig):
        with global_compiler_lock:                             # re-entrant; numba's compile takes it too
            stack = _stack()
            for_caller = bool(stack)
            if not for_caller:
                from numba.core import sigutils
                args, _ = sigutils.normalize_signature(sig)
                cres = self.overloads.get(tuple(args))
                if cres is not None and getattr(cres.library, _LINKED_ONLY, False):
                    del self.overloads[tuple(args)]          # Python calls it: compile it whole now
            lean = for_caller and _project_kernel(self)
            stack.append(lean)
            cache = self._cache
            if lean and not isinstance(cache, caching.NullCache):
                self._cache = _LoadOnly(cache)
            try:
                # not while this kernel compiles already (a recursive call: numba matches it by the
                # literal types)
                plain = _plain(sig) if lean and not self.is_compiling else None
                if plain is not None:
                    try:                               # the caller converts its constants to the plain types
                        return compile_overload(self, plain)
                    except errors.NumbaError:          # a kernel whose typing or lowering needs the constant
                        pass                           # (numba.literally, a literal-only overload)
                return compile_overload(self, sig)
            finally:
                self._cache = cache
                stack.pop()

    def whole_compile(original):
        """``original`` (a compile of code a lean kernel may hold: a lifted loop, a C callback) compiled whole."""
        def compile_whole(self, *args, **kwargs):
            stack = _stack()
            stack.append(False)
            try:
                return original(self, *args, **kwargs)
            finally:
                stack.pop()
        return compile_whole

    def lean_add_overload(self, cres):
        if not getattr(cres.library, _LINKED_ONLY, False):
            return add_overload(self, cres)
        self.overloads[tuple(cres.signature.args)] = cres     # for callers; not in the table of Python calls

    lean_compile_cfunc = whole_compile(compile_cfunc)          # a C entry point has callers outside numba
    lean_compile_lifted = whole_compile(lifted_cls.compile)     # object mode and lifted loops: Python calls them

    for function in (lean_finalize, lean_get_executable, lean_compile, lean_add_overload, lean_compile_cfunc,
                     lean_compile_lifted):
        setattr(function, _MARK, True)
    library_cls.finalize = lean_finalize
    context_cls.get_executable = lean_get_executable
    dispatcher_cls.compile = lean_compile
    dispatcher_cls.add_overload = lean_add_overload
    ccallback.CFunc.compile = lean_compile_cfunc
    lifted_cls.compile = lean_compile_lifted
