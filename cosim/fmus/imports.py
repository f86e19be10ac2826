"""What an FMU's code imports: the project modules to bundle and the third-party packages to list.

Read from the import statements of the sources (:mod:`ast`), also those inside functions: a build
follows the slave script's imports through the project packages (:func:`bundled_files`) and names
the packages outside them that the code imports or loads at run time (:func:`third_party_modules`).

A source file is parsed once per process and content (:func:`_statements`): the builds of one
process (``build_fmu.py``'s three FMUs, a test suite's dozens) read the same ``solver`` and
``fmu_src`` modules, and each build reads each file twice (its imports, then whether it loads BLAS).
"""
from __future__ import annotations

import ast
import sys
from functools import lru_cache
from pathlib import Path
from typing import Mapping

__all__ = ["bundled_files", "third_party_modules", "run_time_modules"]

#: numpy functions whose compiled (numba) form calls BLAS or LAPACK, which numba takes from scipy
#: (``scipy.linalg.cython_blas``/``cython_lapack``) when the code runs, not when it is imported
_BLAS_CALLS = frozenset({"dot", "vdot", "inner", "matmul", "linalg"})


@lru_cache(maxsize=4096)
def _statements(filename: str, text: str) -> tuple[tuple, bool]:
    """The import statements of the source ``text`` (``(level, module, names)``: ``level`` None for a
    plain ``import``), and whether its code uses the matrix product ``@`` or a numpy BLAS/LAPACK function;
    memoized on the text itself, so an edited file is parsed again."""
    tree = ast.parse(text, filename=filename)
    imports = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imports.append((None, None, tuple(alias.name for alias in node.names)))
        elif isinstance(node, ast.ImportFrom):
            imports.append((node.level, node.module, tuple(alias.name for alias in node.names)))
    blas = any((isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult))
               or (isinstance(node, ast.Attribute) and node.attr in _BLAS_CALLS) for node in ast.walk(tree))
    return tuple(imports), blas


def _parsed(path: Path) -> tuple[tuple, bool]:
    return _statements(str(path), Path(path).read_text())


def _module_file(name: str, packages: Mapping[str, Path]) -> Path | None:
    """The source file of module ``name`` (``pkg.sub.mod``) if it belongs to one of ``packages``."""
    top, *rest = name.split(".")
    if top not in packages:
        return None
    base = packages[top].joinpath(*rest)
    for path in (base / "__init__.py", base.with_suffix(".py")):
        if path.is_file():
            return path
    return None


def _imported_names(path: Path, module: str | None, is_package: bool) -> set[str]:
    """Absolute names of every module an ``import`` statement of ``path`` may load (also in functions)."""
    names = set()
    for level, source, aliases in _parsed(path)[0]:
        if level is None:
            names.update(aliases)
            continue
        if level:
            if module is None:
                continue                              # a relative import in a script: not ours to follow
            parts = module.split(".") if is_package else module.split(".")[:-1]
            parts = parts[:len(parts) - level + 1]
            base = ".".join(parts + ([source] if source else []))
        else:
            base = source
        names.add(base)
        names.update(f"{base}.{alias}" for alias in aliases)      # ``from pkg import submodule``
    return names


def bundled_files(script: Path, packages: Mapping[str, Path]) -> dict[str, Path]:
    """The modules of ``packages`` ({name: folder}) that ``script`` imports, directly or through them:
    ``{path relative to resources: source file}``, every enclosing ``__init__.py`` included."""
    out: dict[str, Path] = {}
    todo = [(Path(script), None, False)]
    while todo:
        path, module, is_package = todo.pop()
        for name in sorted(_imported_names(path, module, is_package)):
            parts = name.split(".")
            for n in range(1, len(parts) + 1):               # the package, its subpackages, the module
                prefix = ".".join(parts[:n])
                found = _module_file(prefix, packages)
                if found is None:
                    break
                rel = found.relative_to(packages[parts[0]].parent).as_posix()
                if rel not in out:
                    out[rel] = found
                    todo.append((found, prefix, found.name == "__init__.py"))
    return dict(sorted(out.items()))


def run_time_modules(path: Path) -> set[str]:
    """The modules ``path`` needs at run time without importing them: scipy for a module that imports
    numba and uses ``@``, ``np.dot`` or ``np.linalg`` (numba compiles them into calls of scipy's BLAS
    and LAPACK: without scipy the first such call aborts the process with "Specified LAPACK function
    could not be found")."""
    return _run_time(Path(path), _imported_names(Path(path), None, False))


def _run_time(path: Path, names: set[str]) -> set[str]:
    """:func:`run_time_modules` of ``path``, whose imported ``names`` the caller has."""
    if not any(n == "numba" or n.startswith("numba.") for n in names):
        return set()
    return {"scipy"} if _parsed(path)[1] else set()


def third_party_modules(files, local) -> dict[str, list[str]]:
    """The top-level modules that ``files`` import, or load at run time (:func:`run_time_modules`), and
    that are neither the standard library nor ``local`` (the bundled packages):
    ``{module: [importing file names]}``."""
    out: dict[str, set[str]] = {}
    skip = set(sys.stdlib_module_names) | set(local) | {"__future__"}
    for path in map(Path, files):
        names = _imported_names(path, None, False)
        for name in (*names, *_run_time(path, names)):
            top = name.split(".")[0] if name else ""
            if top and top not in skip:
                out.setdefault(top, set()).add(path.name)
    return {k: sorted(v) for k, v in sorted(out.items())}
