"""Packaging a table slave into an FMU with pythonfmu (host side; never bundled into an FMU).

``build_fmu(script, dest_dir, project_packages=(solver_dir,), data_files={"maps/m.npz": path})``

1. stages the FMU's ``resources/`` folder: the slave script, the modules of ``fmu_src`` and of the
   project packages that the slave imports (:func:`bundled_files`: every import statement of the
   script and, transitively, of the package modules it reaches, also those inside functions; for
   ``fmu_src`` that is its runtime, ``table_slave`` and what it imports), the data files under
   the names given, and ``requirements.txt``: the third-party packages that code imports (but
   pythonfmu, which pythonfmu's builder bundles), with the version ranges of the project's
   dependencies (:func:`declared_requirements`; checked by the
   slave's first statement on the host that runs it, :mod:`fmu_src.requirements`);
2. imports the slave class in isolation and checks it: class name == module name == modelIdentifier
   (pythonfmu FMUs of one process share ``sys.modules``, so a module name may exist only once and must
   not shadow anything importable), it is the class the C wrapper will pick (deepest ``Fmi2Slave``
   subclass of the module), an instance has no attribute outside its table/``STATE``/``CONSTANT``,
   and its FMU state pickles;
3. runs ``pythonfmu.FmuBuilder.build_FMU``;
4. post-processes the archive: cross-checks pythonfmu's ModelVariables against the table, then
   replaces ``modelDescription.xml`` by one generated from the table
   (:mod:`cosim.fmus.model_description`; a GUID derived from the content), makes the Linux binary the
   loader that starts Python in hosts without it (:mod:`cosim.fmus.native`) and rewrites the zip
   deterministically (sorted entries, fixed timestamps and permissions);
5. validates the result (:func:`cosim.fmus.checks.validate`) and raises :class:`BuildError` on any
   problem.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.machinery
import importlib.util
import inspect
import os
import re
import shutil
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Callable, Mapping, Sequence

from fmu_src import requirements
from .checks import validate
from .imports import bundled_files, run_time_modules, third_party_modules
from .native import loader_entries
from .model_description import UNIT_DEFINITIONS, ModelDescriptionError, cross_check, model_description_xml
from fmu_src.table_slave import TableSlave

from .sources import SLAVE_DIR

__all__ = ["BuildError", "build_fmu", "bundled_files", "third_party_modules", "run_time_modules", "declared_requirements",
           "project_dependencies"]

_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
_PROJECT = "rrr-dk"
_GUID_NAMESPACE = uuid.UUID("6f1c54d2-5b8e-4d67-9a4c-0d1f3e2a7b90")


class BuildError(RuntimeError):
    """The slave or its FMU breaks a rule; the message says which."""


def _normalized(dist: str) -> str:
    return re.sub(r"[-_.]+", "-", dist).lower()


def project_dependencies() -> dict[str, requirements.Requirement]:
    """The project's runtime dependencies: ``{normalized distribution name: Requirement}``.

    Read from ``pyproject.toml`` next to the package (a source tree), else from the installed
    project's metadata; dependencies with an environment marker or an extra are left out.
    """
    import importlib.metadata
    import tomllib

    pyproject = SLAVE_DIR.parent / "pyproject.toml"
    specs = None
    if pyproject.is_file():
        project = tomllib.loads(pyproject.read_text()).get("project", {})
        if project.get("name") == _PROJECT:
            specs = list(project.get("dependencies", []))
    if specs is None:
        specs = [s for s in (importlib.metadata.requires(_PROJECT) or []) if ";" not in s]
    reqs = requirements.parse_requirements("\n".join(s.split(";")[0] for s in specs))
    return {_normalized(r.dist): r for r in reqs}


@functools.lru_cache(maxsize=1)
def _providers() -> Mapping[str, list[str]]:
    """``importlib.metadata.packages_distributions()``, read once per process (a few hundred ms: every
    installed distribution's file list)."""
    import importlib.metadata

    return importlib.metadata.packages_distributions()


def declared_requirements(modules: Mapping[str, list[str]]) -> list[requirements.Requirement]:
    """The requirement of each third-party module (``{module: importing files}``, see
    :func:`third_party_modules`): the project dependency that provides it, with its version range.

    Raises :class:`BuildError` for a module no project dependency provides (declare it in
    ``pyproject.toml``: the FMU's host must be told to install it).
    """
    deps = project_dependencies()
    providers = _providers()
    out, unknown = [], []
    for module, files in modules.items():
        dists = [_normalized(d) for d in providers.get(module, [module])]
        found = next((deps[d] for d in dists if d in deps), None)
        if found is None:
            unknown.append(f"{module} (imported by {', '.join(files)})")
        else:
            out.append(requirements.Requirement(found.dist, found.specifiers, module))
    if unknown:
        raise BuildError(f"the FMU's code imports {'; '.join(unknown)}, which no dependency of the project "
                         f"provides: add it to [project] dependencies in pyproject.toml")
    return out


def build_fmu(script: str | os.PathLike, dest_dir: str | os.PathLike = ".", *,
              project_packages: Sequence[str | os.PathLike] = (),
              data_files: Mapping[str, str | os.PathLike] | None = None,
              documentation_dir: str | os.PathLike | None = None,
              can_serialize_state: bool = True,
              check: bool = True,
              kernels: Callable[[Path], Mapping[str, bytes]] | None = None) -> Path:
    """Build ``<dest_dir>/<ModelName>.fmu`` from a :class:`TableSlave` script.

    ``project_packages``: package directories (e.g. ``solver``) whose modules the slave imports are
    copied to ``resources/<name>/`` (:func:`bundled_files`; ``fmu_src``'s runtime always is).
    ``data_files``: ``{path relative to resources: source file}``; at run time the slave finds
    them under ``Path(self.resources) / key``.
    ``can_serialize_state``: sets canSerializeFMUstate (states are pickles, so they serialize).
    ``check``: validate the result and raise :class:`BuildError` on any problem.
    ``kernels``: given the built FMU, the entries to add to it (its compiled kernels,
    :func:`cosim.fmus.kernels.warm_up`); the FMU is then written again with them.
    Same inputs (and the same kernel cache) give a byte-identical FMU.
    """
    from pythonfmu import FmuBuilder

    script = Path(script).resolve()
    if script.suffix != ".py" or not script.is_file():
        raise BuildError(f"{script}: not a Python script")
    module = script.stem
    if not module.isidentifier() or not module.isascii():
        raise BuildError(f"{module!r}: the module name is also the modelIdentifier and must be a C identifier")
    _check_module_name_is_free(module, script)
    dest_dir = Path(dest_dir)
    dest_dir.mkdir(parents=True, exist_ok=True)

    with tempfile.TemporaryDirectory(prefix="fmu_build_") as tmp:
        staging = Path(tmp) / "resources"
        staging.mkdir()
        shutil.copyfile(script, staging / script.name)
        _stage_packages(staging, script, module, project_packages)
        _stage_data_files(staging, data_files or {})
        with _isolated_module(module):
            cls = _load_slave_class(staging / script.name, module)
            if check:
                _check_instance(cls, staging)
            entries = sorted(p for p in staging.iterdir() if p.name != script.name)
            raw = FmuBuilder.build_FMU(staging / script.name, dest=Path(tmp) / "raw",
                                       project_files=entries, documentation_folder=documentation_dir,
                                       canGetAndSetFMUstate=True, canSerializeFMUstate=can_serialize_state)
        final = dest_dir / f"{module}.fmu"
        _postprocess(Path(raw), final, cls, can_serialize_state)
        if kernels is not None:
            _postprocess(Path(raw), final, cls, can_serialize_state, extra=kernels(final))
    if check:
        problems = validate(final)
        if problems:
            raise BuildError(f"{final} is not valid:\n- " + "\n- ".join(problems))
    return final


def _stage_packages(staging: Path, script: Path, module: str, project_packages) -> None:
    """Copy what the slave imports of the project packages (and of :mod:`fmu_src`) to ``staging``, and
    write the requirements file of the third-party packages it needs from its host."""
    packages = {SLAVE_DIR.name: SLAVE_DIR}
    for pkg in project_packages:
        pkg = Path(pkg).resolve()
        if not pkg.is_dir():
            raise BuildError(f"project package {pkg} is not a directory")
        if pkg.name in packages:
            raise BuildError(f"two resources entries named {pkg.name!r}")
        packages[pkg.name] = pkg
    bundled = bundled_files(script, packages)
    for rel, src in bundled.items():
        (staging / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, staging / rel)
    # pythonfmu's builder bundles the pythonfmu package itself into resources/: not a requirement
    needs = declared_requirements(third_party_modules([script, *bundled.values()], {*packages, "pythonfmu"}))
    (staging / requirements.FILE).write_text(requirements.format_requirements(module, needs))


def _stage_data_files(staging: Path, data_files: Mapping[str, str | os.PathLike]) -> None:
    """Copy ``{relative path: source file}`` under ``staging``; names must be relative, forward-slashed
    and new."""
    for rel, src in sorted(data_files.items()):
        rel_path = Path(rel)
        if rel_path.is_absolute() or ".." in rel_path.parts or "\\" in rel:
            raise BuildError(f"data file name {rel!r} must be a relative path with forward slashes")
        target = staging / rel_path
        if target.exists():
            raise BuildError(f"data file {rel!r} collides with another resources entry")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, target)


def _check_module_name_is_free(module: str, script: Path) -> None:
    if module in sys.builtin_module_names or module in sys.stdlib_module_names:
        raise BuildError(f"module name {module!r} shadows a standard-library module")
    spec = importlib.machinery.PathFinder.find_spec(module, [p or os.getcwd() for p in sys.path])
    if spec is None or spec.origin is None:
        return
    origin = Path(spec.origin).resolve()
    if origin == script or (origin.parent / "slavemodule.txt").is_file():
        return  # the script itself, or the resources folder of an FMU of this model loaded earlier
    raise BuildError(f"module name {module!r} is already importable from {origin}; pythonfmu FMUs share "
                     "sys.modules with the host process, so the slave module needs a unique name")


@contextlib.contextmanager
def _isolated_module(module: str):
    """Import the slave from the staging folder without leaving traces in sys.path/sys.modules.

    A leftover ``sys.modules[module]`` would make later FMU instances of this process run the build
    copy instead of the FMU's own resources (the C wrapper imports the module by name).
    """
    saved_path = list(sys.path)
    saved_module = sys.modules.pop(module, None)
    try:
        yield
    finally:
        sys.path[:] = saved_path
        sys.modules.pop(module, None)
        if saved_module is not None:
            sys.modules[module] = saved_module


def _load_slave_class(path: Path, module: str) -> type[TableSlave]:
    from pythonfmu import Fmi2Slave

    spec = importlib.util.spec_from_file_location(module, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[module] = mod  # pickling of the state needs the module by name; removed afterwards
    sys.path.insert(0, str(path.parent))
    spec.loader.exec_module(mod)
    # The C wrapper of pythonfmu 0.7 picks, among all classes of the module namespace, the one with
    # Fmi2Slave deepest in its MRO (first one on ties).  Mirror that and insist on a unique answer.
    depth = {obj: inspect.getmro(obj).index(Fmi2Slave) for obj in vars(mod).values()
             if inspect.isclass(obj) and issubclass(obj, Fmi2Slave)}
    if not depth:
        raise BuildError(f"{path.name}: no Fmi2Slave subclass")
    deepest = max(depth.values())
    chosen = [c for c, d in depth.items() if d == deepest]
    if len(chosen) != 1:
        raise BuildError(f"{path.name}: the C wrapper could pick any of {[c.__name__ for c in chosen]}")
    cls = chosen[0]
    if cls.__name__ != module:
        raise BuildError(f"{path.name}: the slave class is {cls.__name__!r}; name it {module!r} (class name == "
                         "module name == modelIdentifier keeps FMUs of one process apart)")
    if cls.__module__ != module:
        raise BuildError(f"{path.name}: class {cls.__name__} must be defined in the script, not imported")
    if not issubclass(cls, TableSlave) or not cls._table:
        raise BuildError(f"{cls.__name__} must subclass fmu_src.table_slave.TableSlave and define VARIABLES")
    if cls.step is TableSlave.step:
        raise BuildError(f"{cls.__name__} defines no step(t, dt)")
    units = {**UNIT_DEFINITIONS, **cls.UNITS}
    unknown = sorted({v.unit for v in cls._table if v.unit is not None} - set(units))
    if unknown:
        raise BuildError(f"{cls.__name__}: units {unknown} are not defined; add them to the class attribute "
                         "UNITS as {name: {kg/m/s/A/K/mol/cd/rad: exponent, factor, offset}}")
    return cls


def _check_instance(cls: type[TableSlave], resources: Path) -> None:
    inst = cls(instance_name="fmu_src-build-check", resources=str(resources))
    extra = inst.undeclared_attributes()
    if extra:
        raise BuildError(f"{cls.__name__}: setup() created attributes {sorted(extra)} that are neither table "
                         "variables nor listed in STATE (rolled back with the FMU state) or CONSTANT")
    try:
        blob = inst._get_fmu_state()
        inst._set_fmu_state(cls._fmu_state_from_bytes(cls._fmu_state_to_bytes(blob)))
    except Exception as exc:
        raise BuildError(f"{cls.__name__}: the FMU state does not round-trip through pickle: "
                         f"{type(exc).__name__}: {exc}") from exc


def _postprocess(raw: Path, final: Path, cls: type[TableSlave], can_serialize_state: bool,
                 extra: Mapping[str, bytes] | None = None) -> None:
    with zipfile.ZipFile(raw) as z:
        entries = {i.filename: z.read(i) for i in z.infolist() if not i.is_dir()}
    if set(entries) & set(extra or {}):
        raise BuildError(f"added entries collide with the FMU's: {sorted(set(entries) & set(extra))[:5]}")
    entries.update(extra or {})
    try:
        cross_check(ET.fromstring(entries["modelDescription.xml"]), cls)
    except ModelDescriptionError as exc:
        raise BuildError(str(exc)) from None
    if entries.get("resources/slavemodule.txt", b"").decode().strip() != cls.__name__:
        raise BuildError("resources/slavemodule.txt does not name the slave module")
    del entries["modelDescription.xml"]
    entries = loader_entries(entries, cls.__name__)         # hosts without Python (cosim.fmus.native)
    digest = hashlib.sha256()
    digest.update(model_description_xml(cls, guid="", can_serialize_state=can_serialize_state))
    for name in sorted(entries):
        digest.update(name.encode() + b"\0" + hashlib.sha256(entries[name]).digest())
    guid = str(uuid.uuid5(_GUID_NAMESPACE, digest.hexdigest()))
    entries["modelDescription.xml"] = model_description_xml(cls, guid=guid,
                                                            can_serialize_state=can_serialize_state)
    write_zip(final, entries)


def write_zip(final: Path, entries: dict) -> None:
    """Write ``entries`` ({name: bytes}) as the zip ``final``, byte for byte the same for the same entries
    (sorted names, one date, fixed modes: executables under ``binaries/``); written beside and moved
    into place, so a reader never sees half a file."""
    tmp = final.with_name(final.name + ".part")
    with zipfile.ZipFile(tmp, "w") as z:
        for name in sorted(entries):
            info = zipfile.ZipInfo(name, date_time=_ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3
            mode = 0o755 if name.startswith("binaries/") else 0o644
            info.external_attr = (0o100000 | mode) << 16
            z.writestr(info, entries[name], compresslevel=9)
    os.replace(tmp, final)
