"""The Python packages an FMU's bundled code needs from the environment that runs it, and the check
that the environment has them (part of the FMU runtime: standard library only).

A pythonfmu FMU runs its slave in the host's Python interpreter (fmpy, libcosimpy and ecospy load
it in their own process; a C host starts one from its libpython).  The FMU bundles the project's
own modules (``fmu_src``'s runtime, ``solver``, ``dynamics``), not the third-party packages they
import (numpy, numba, scipy, python-control).  The build writes those, with the
version ranges of the project's ``pyproject.toml``, to ``resources/requirements.txt``
(:func:`format_requirements`; :func:`cosim.fmus.packaging.build_fmu` finds them by reading every
import statement of the bundled code), so that ``pythonfmu deploy -f <Model>.fmu`` or
``python -m pip install -r requirements.txt`` installs them.  pythonfmu is not among them: its
builder bundles the package into every FMU.

:func:`require` is the first statement of every slave script::

    from fmu_src.requirements import require
    require(__file__)

It reads the ``requirements.txt`` next to the script (none in the source tree: nothing to check)
and, if a package is missing or outside its version range, logs one message naming each missing
module and the command that installs them (Python logger ``fmu_src.<Model>``, level ERROR: on
stderr when the host has not configured logging) and raises :class:`MissingRequirements` (a
``ModuleNotFoundError``).  Instantiation then fails: pythonfmu 0.7's C wrapper turns any exception
of the slave module or constructor into a NULL ``fmi2Instantiate`` and logs it, with the
exception's text, as fmi2Fatal, and only to a host that instantiated with ``loggingOn`` (fmpy's
``simulate_fmu`` does not by default, hence the message on stderr).  fmi2Instantiate returns no
status, so fmi2Error is not possible there.  A check that passed is not repeated in the process.
"""
from __future__ import annotations

import logging
import os
import re
import sys
from pathlib import Path
from typing import NamedTuple

__all__ = ["FILE", "Requirement", "MissingRequirements", "format_requirements", "parse_requirements",
           "problems", "interpreter", "install_command", "message", "require", "instantiated"]

#: The file in the FMU's ``resources/`` folder (the name ``pythonfmu deploy`` looks for).
FILE = "requirements.txt"
_IMPORT_NOTE = re.compile(r"#\s*import\s+([A-Za-z_][A-Za-z0-9_]*)")
_SPEC = re.compile(r"\s*(~=|==|!=|<=|>=|<|>)\s*([0-9][0-9A-Za-z.*+!-]*)\s*")
_CHECKED: set[str] = set()                 # requirements texts this process satisfied
_MODELS: set[str] = set()                  # FMUs whose slave module this process ran (from resources/)


class Requirement(NamedTuple):
    """One line of ``requirements.txt``: distribution, specifiers ``((op, version), ...)``, module."""

    dist: str
    specifiers: tuple[tuple[str, str], ...]
    module: str

    @property
    def spec(self) -> str:
        """The requirement as pip writes it, e.g. ``numpy>=1.26``."""
        return self.dist + ",".join(op + v for op, v in self.specifiers)


class MissingRequirements(ModuleNotFoundError):
    """The Python environment lacks packages the FMU imports; ``missing``: the problems, one each."""

    def __init__(self, text: str, name: str | None, missing: list[str]):
        super().__init__(text, name=name)
        self.missing = missing


def format_requirements(model: str, requirements: list[Requirement]) -> str:
    """The text of ``resources/requirements.txt`` (pip's format; the module as a comment)."""
    head = (f"# Python packages that the code bundled in {model}.fmu imports (written by the build).\n"
            "# Install them into the Python environment of the host that runs the FMU:\n"
            f"#   pythonfmu deploy -f {model}.fmu\n"
            "#   or: python -m pip install -r requirements.txt\n")
    return head + "".join(f"{r.spec}  # import {r.module}\n" for r in sorted(requirements))


def parse_requirements(text: str) -> list[Requirement]:
    """The requirements of a ``requirements.txt`` written by :func:`format_requirements`.

    Raises ``ValueError`` naming the line that is not ``name[specifiers]  [# import module]``.
    """
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        body, _, comment = line.partition("#")
        body = body.strip()
        if not body:
            continue
        m = re.match(r"([A-Za-z0-9][A-Za-z0-9._-]*)(.*)$", body)
        specs = []
        for part in m.group(2).split(",") if m is not None and m.group(2).strip() else []:
            s = _SPEC.fullmatch(part)
            if s is None:
                m = None
                break
            specs.append((s.group(1), s.group(2)))
        if m is None:
            raise ValueError(f"{FILE} line {n}: {line.strip()!r}: expected name>=version[,<version]")
        note = _IMPORT_NOTE.search("#" + comment) if comment else None
        module = note.group(1) if note else m.group(1).replace("-", "_").lower()
        out.append(Requirement(m.group(1), tuple(specs), module))
    return out


def _release(version: str) -> tuple[int, ...]:
    """The release numbers of a version (``1.26.4`` -> (1, 26, 4); pre/post/dev/local parts ignored)."""
    version = version.split("!")[-1].split("+")[0]
    parts = []
    for piece in version.split("."):
        digits = re.match(r"\d+", piece)
        if digits is None:
            break
        parts.append(int(digits.group()))
        if digits.end() != len(piece):
            break
    return tuple(parts)


def _satisfies(version: str, op: str, wanted: str) -> bool:
    if op in ("==", "!=") and wanted.endswith(".*"):
        prefix = _release(wanted[:-2])
        equal = _release(version)[:len(prefix)] == prefix
        return equal if op == "==" else not equal
    have, want = _release(version), _release(wanted)
    width = max(len(have), len(want))
    have, want = have + (0,) * (width - len(have)), want + (0,) * (width - len(want))
    if op == "~=":
        return have >= want and have[:len(_release(wanted)) - 1] == want[:len(_release(wanted)) - 1]
    return {"==": have == want, "!=": have != want, "<=": have <= want, ">=": have >= want,
            "<": have < want, ">": have > want}[op]


def problems(requirements: list[Requirement]) -> list[tuple[Requirement, str]]:
    """The requirements this interpreter does not meet, each with the reason
    (``No module named 'numba'``, or ``numpy 1.24.0 is installed``)."""
    import importlib.metadata
    import importlib.util

    out = []
    for req in requirements:
        present = req.module in sys.modules
        if not present:
            try:
                present = importlib.util.find_spec(req.module) is not None
            except (ImportError, ValueError):
                present = False
        try:
            version = importlib.metadata.version(req.dist)
        except importlib.metadata.PackageNotFoundError:
            version = None
        if not present:
            out.append((req, f"No module named {req.module!r}"))
        elif version is not None and not all(_satisfies(version, op, v) for op, v in req.specifiers):
            out.append((req, f"{req.dist} {version} is installed"))
    return out


def _runs(path: str) -> bool:
    return bool(path) and os.path.isfile(path) and os.access(path, os.X_OK)


def interpreter() -> str:
    """The Python executable of this interpreter's environment, as a path that exists ("" if none).

    ``sys.executable`` when it is a python file that runs: a Python host, or a C host whose loader
    started the interpreter under its own name (a host binary that embedded Python is not one).  A host that embedded Python without naming it (pythonfmu's
    wrappers alone set a program name like ``<cwd>/PythonFMU``, which does not exist) gets the
    ``bin/python3.X`` of the environment the interpreter actually runs (``sys.prefix``, then
    ``sys.base_prefix``), the one whose ``pip`` installs what this process imports.
    """
    if _runs(sys.executable) and os.path.basename(sys.executable).lower().startswith("python"):
        return sys.executable
    version = "%d.%d" % sys.version_info[:2]
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix, sys.exec_prefix)):
        for name in (f"python{version}", "python3", "python"):
            candidate = os.path.join(prefix, "bin", name)
            if _runs(candidate):
                return candidate
    return ""


def install_command(requirements: list[Requirement]) -> str:
    """The pip command that installs ``requirements`` into this interpreter's environment."""
    exe = interpreter()
    python = (f'"{exe}"' if " " in exe else exe) or "python3"
    return f"{python} -m pip install " + " ".join(f'"{r.spec}"' for r in requirements)


def message(model: str, found: list[tuple[Requirement, str]], path: str | Path | None = None) -> str:
    """The text of :class:`MissingRequirements` for the FMU ``model`` (one problem a line, then the fix);
    ``path``: its ``requirements.txt`` (named in the second fix, absolute)."""
    where = interpreter() or f"the host's embedded interpreter, prefix {sys.prefix}"
    reasons = "".join(f"\n  {why} (the FMU needs {req.spec})" for req, why in found)
    listed = Path(path).resolve() if path else Path("resources") / FILE
    pip = install_command([]).rstrip()
    return (f"{model}.fmu cannot run in this Python environment ({where}, Python "
            f"{sys.version.split()[0]}):{reasons}\nInstall what it needs into that environment:\n  "
            f"{install_command([req for req, _ in found])}\nor everything the FMU lists:\n  "
            f"{pip} -r \"{listed}\"")


def require(script: str) -> None:
    """The guard at the top of a slave script: check the ``requirements.txt`` next to ``script``.

    Does nothing when there is no such file (the source tree) or when this process already met
    the same requirements.  Otherwise logs and raises :class:`MissingRequirements`.
    """
    path = Path(script).with_name(FILE)
    try:
        text = path.read_text()
    except OSError:
        return
    if path.with_name("slavemodule.txt").is_file():       # an FMU's resources/, not a build's staging
        _MODELS.add(Path(script).stem)
    if text in _CHECKED:
        return
    found = problems(parse_requirements(text))
    if not found:
        _CHECKED.add(text)
        return
    model = Path(script).stem
    msg = message(model, found, path)
    try:
        logging.getLogger(f"fmu_src.{model}").error("%s", msg)
    except Exception:  # noqa: BLE001 - a broken logging setup must not hide the reason below
        pass
    missing = [why for _, why in found]
    first = next((req.module for req, why in found if why.startswith("No module")), None)
    raise MissingRequirements(msg, first, missing)


def instantiated() -> tuple[str, ...]:
    """The FMUs whose slave module ran in this process from an FMU's ``resources/`` (sorted names):
    each instantiation of one of the project's FMUs passes :func:`require` first, successful or not."""
    return tuple(sorted(_MODELS))
