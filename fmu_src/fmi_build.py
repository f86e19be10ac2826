"""Build, check and run the project's pythonfmu FMUs (host side; never bundled into an FMU).

Build
-----
``build_fmu(script, dest_dir, project_packages=(solver_dir,), data_files={"maps/m.npz": path})``

1. stages the FMU's ``resources/`` folder: the slave script, the runtime part of ``fmu_src``
   (``__init__.py``, ``table_slave.py``), each project package (without ``__pycache__``, tests,
   numba caches) and the data files under the names given;
2. imports the slave class in isolation and checks it: class name == module name == modelIdentifier
   (pythonfmu FMUs of one process share ``sys.modules``, so a module name may exist only once and must
   not shadow anything importable), it is the class the C wrapper will pick (deepest ``Fmi2Slave``
   subclass of the module), an instance has no attribute outside its table/``STATE``/``CONSTANT``,
   and its FMU state pickles;
3. runs ``pythonfmu.FmuBuilder.build_FMU``;
4. post-processes the archive: cross-checks pythonfmu's ModelVariables against the table, then
   replaces ``modelDescription.xml`` by one generated from the table (units and UnitDefinitions,
   explicit variability/initial, ModelStructure/Outputs with ``dependencies``/``dependenciesKind``,
   InitialUnknowns, FMU-state capability flags, a GUID derived from the content, no timestamp) and
   rewrites the zip deterministically (sorted entries, fixed timestamps and permissions);
5. validates the result (``validate``) and raises :class:`BuildError` on any problem.

What pythonfmu 0.7 emits by itself (and why step 4 exists): Outputs ``<Unknown index=..>`` without
``dependencies`` (i.e. "depends on every input"), no ``InitialUnknowns`` (fmpy: "does not contain
the expected set of variables"), no units, no variability for Integer/Boolean outputs (defaults to
continuous: illegal; FMI Library/libcosim log "Only Real variables can have variability='continuous'"),
a time-based ``uuid1`` GUID and ``generationDateAndTime`` (never the same twice), zip entries with
file mtimes.

Run
---
``simulate`` wraps ``fmpy.simulate_fmu`` and raises :class:`StepRefusedError` when the FMU refused
a step (fmpy itself returns the truncated result without a word).  ``run_libcosim`` runs one FMU in
DNV libcosim through libcosimpy; ``write_osp_system_structure`` + ``run_osp_system`` run a system of
FMUs described by an OspSystemStructure.xml.  pythonfmu FMUs run in-process there: the FMU's binary
does not link libpython, it uses the interpreter of the host process (libcosimpy calls libcosimc
through ctypes.CDLL, which releases the GIL, and pythonfmu takes it with PyGILState_Ensure from
libcosim's worker threads).  So the host interpreter must be able to import what the slave imports
(numpy, scipy, numba... from its own environment; project packages bundled in ``resources/`` come
first on ``sys.path`` unless a module of that name is already imported).  The ``cosim`` command-line
tool (a C++ process without Python) cannot load pythonfmu FMUs: the binary leaves its 45 ``Py*``
symbols undefined (it would need libpython preloaded and PYTHONHOME/PYTHONPATH pointing at this
environment).

Process hygiene
---------------
All pythonfmu FMUs of a process share one interpreter: ``sys.modules`` (the slave module is imported
by name; the first version loaded wins until it is forgotten), ``sys.path`` (every instantiation
prepends its resources folder and never removes it) and the imported packages (a bundled ``solver``
is used only if the host has not imported ``solver`` yet; import it first in a host that runs FMUs
repeatedly, or numba recompiles it for every fresh extraction).  ``simulate``, ``smoke_check``,
``run_libcosim`` and ``run_osp_system`` restore ``sys.path`` and forget the modules imported from the
FMU's temporary folder when they return; a custom FMU2Slave master should do the same.
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib.machinery
import importlib.util
import inspect
import logging
import math
import os
import shutil
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .table_slave import TableSlave, Var

__all__ = [
    "UNIT_DEFINITIONS", "BuildError", "StepRefusedError", "LibcosimError", "build_fmu", "validate",
    "smoke_check",
    "model_description_xml", "value_references", "input_table", "simulate", "run_libcosim",
    "write_osp_system_structure", "run_osp_system", "CosimResult",
]

_log = logging.getLogger(__name__)

# SI base-unit exponents (FMI 2.0 BaseUnit attributes kg, m, s, A, K, mol, cd, rad, factor, offset).
UNIT_DEFINITIONS: dict[str, dict[str, float]] = {
    "1": {},
    "rad": {"rad": 1},
    "deg": {"rad": 1, "factor": math.pi / 180.0},
    "m": {"m": 1},
    "s": {"s": 1},
    "kg": {"kg": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "1/s": {"s": -1},
    "1/s2": {"s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
}
_BASE_UNIT_ORDER = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")

_RUNTIME_FILES = ("__init__.py", "table_slave.py")
_IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo", "*.nbi", "*.nbc", ".pytest_cache",
                                 ".hypothesis", "tests", "*.egg-info", ".DS_Store")
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
_GUID_NAMESPACE = uuid.UUID("6f1c54d2-5b8e-4d67-9a4c-0d1f3e2a7b90")


class BuildError(RuntimeError):
    """The slave or its FMU breaks a rule; the message says which."""


class StepRefusedError(RuntimeError):
    """An FMU refused a step (fmi2Discard) during ``simulate``; ``.messages`` has its log."""

    def __init__(self, message: str, messages: list[str], result: np.ndarray | None):
        super().__init__(message)
        self.messages = messages
        self.result = result


class LibcosimError(RuntimeError):
    """libcosim failed (e.g. a slave refused a step); ``.partial`` holds the samples until then."""

    def __init__(self, message: str, partial: "CosimResult | None" = None):
        super().__init__(message)
        self.partial = partial


# ====================================================================== build
def build_fmu(script: str | os.PathLike, dest_dir: str | os.PathLike = ".", *,
              project_packages: Sequence[str | os.PathLike] = (),
              data_files: Mapping[str, str | os.PathLike] | None = None,
              documentation_dir: str | os.PathLike | None = None,
              can_serialize_state: bool = True,
              check: bool = True) -> Path:
    """Build ``<dest_dir>/<ModelName>.fmu`` from a :class:`TableSlave` script.

    ``project_packages``: package directories copied to ``resources/<name>/`` (e.g. ``solver``).
    ``data_files``: ``{path relative to resources: source file}``; at run time the slave finds
    them under ``Path(self.resources) / key``.
    ``can_serialize_state``: sets canSerializeFMUstate (states are pickles, so they serialize).
    ``check``: validate the result and raise :class:`BuildError` on any problem.
    Same inputs give a byte-identical FMU.
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

    with tempfile.TemporaryDirectory(prefix="fmi_build_") as tmp:
        staging = Path(tmp) / "resources"
        staging.mkdir()
        shutil.copyfile(script, staging / script.name)
        _stage_runtime(staging)
        for pkg in project_packages:
            pkg = Path(pkg).resolve()
            if not pkg.is_dir():
                raise BuildError(f"project package {pkg} is not a directory")
            target = staging / pkg.name
            if target.exists():
                raise BuildError(f"two resources entries named {pkg.name!r}")
            shutil.copytree(pkg, target, ignore=_IGNORE)
        for rel, src in sorted((data_files or {}).items()):
            rel_path = Path(rel)
            if rel_path.is_absolute() or ".." in rel_path.parts or "\\" in rel:
                raise BuildError(f"data file name {rel!r} must be a relative path with forward slashes")
            target = staging / rel_path
            if target.exists():
                raise BuildError(f"data file {rel!r} collides with another resources entry")
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, target)

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
    if check:
        problems = validate(final)
        if problems:
            raise BuildError(f"{final} is not valid:\n- " + "\n- ".join(problems))
    return final


def _stage_runtime(staging: Path) -> None:
    here = Path(__file__).resolve().parent
    target = staging / here.name
    target.mkdir()
    for name in _RUNTIME_FILES:
        shutil.copyfile(here / name, target / name)


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
    inst = cls(instance_name="fmi_build-check", resources=str(resources))
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


# ---------------------------------------------------------------------- post-processing
def _postprocess(raw: Path, final: Path, cls: type[TableSlave], can_serialize_state: bool) -> None:
    with zipfile.ZipFile(raw) as z:
        entries = {i.filename: z.read(i) for i in z.infolist() if not i.is_dir()}
    _cross_check(ET.fromstring(entries["modelDescription.xml"]), cls)
    if entries.get("resources/slavemodule.txt", b"").decode().strip() != cls.__name__:
        raise BuildError("resources/slavemodule.txt does not name the slave module")
    del entries["modelDescription.xml"]
    digest = hashlib.sha256()
    digest.update(model_description_xml(cls, guid="", can_serialize_state=can_serialize_state))
    for name in sorted(entries):
        digest.update(name.encode() + b"\0" + hashlib.sha256(entries[name]).digest())
    guid = str(uuid.uuid5(_GUID_NAMESPACE, digest.hexdigest()))
    entries["modelDescription.xml"] = model_description_xml(cls, guid=guid,
                                                            can_serialize_state=can_serialize_state)
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


def _cross_check(raw_root: ET.Element, cls: type[TableSlave]) -> None:
    """pythonfmu registered exactly the table, in order (value reference = row number)."""
    raw = [(sv.get("name"), int(sv.get("valueReference")), sv.get("causality"))
           for sv in raw_root.find("ModelVariables")]
    mine = [(v.name, i, v.causality) for i, v in enumerate(cls._table)]
    if raw != mine:
        raise BuildError(f"pythonfmu registered {raw}, the table says {mine}")
    cs = raw_root.find("CoSimulation")
    if cs is None or cs.get("modelIdentifier") != cls.__name__:
        raise BuildError("pythonfmu's modelIdentifier differs from the class name")


def _fmt(v: Var, value) -> str:
    if v.type == "Boolean":
        return "true" if value else "false"
    if v.type == "Integer":
        return str(int(value))
    return repr(float(value))


def model_description_xml(cls: type[TableSlave], *, guid: str, can_serialize_state: bool = True) -> bytes:
    """modelDescription.xml of a TableSlave class, generated from its table (deterministic)."""
    from pythonfmu import __version__ as pythonfmu_version

    table = cls._table
    index = {v.name: i + 1 for i, v in enumerate(table)}   # ScalarVariable indices are 1-based
    attrib = {"fmiVersion": "2.0", "modelName": cls.__name__, "guid": guid}
    for key in ("description", "author", "version", "copyright", "license"):
        value = getattr(cls, key, None)
        if isinstance(value, str) and value:
            attrib[key] = value
    attrib.update(generationTool=f"PythonFMU {pythonfmu_version} + fmu_src.fmi_build",
                  variableNamingConvention="structured", numberOfEventIndicators="0")
    root = ET.Element("fmiModelDescription", attrib)
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": cls.__name__,
        "needsExecutionTool": "true",
        "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true" if can_serialize_state else "false",
        "providesDirectionalDerivative": "false",
    })
    units = {**UNIT_DEFINITIONS, **cls.UNITS}
    used = sorted({v.unit for v in table if v.unit is not None})
    if used:
        unit_defs = ET.SubElement(root, "UnitDefinitions")
        for name in used:
            unit = ET.SubElement(unit_defs, "Unit", {"name": name})
            base = units[name]
            ET.SubElement(unit, "BaseUnit", {k: repr(base[k]) if k in ("factor", "offset") else str(int(base[k]))
                                             for k in _BASE_UNIT_ORDER if k in base})
    categories = getattr(cls, "log_categories", {})
    if categories:
        cats = ET.SubElement(root, "LogCategories")
        for name, text in categories.items():
            ET.SubElement(cats, "Category", {"name": name, "description": text})
    experiment = getattr(cls, "default_experiment", None)
    if experiment is not None:
        ex = {}
        for key, attr in (("startTime", "start_time"), ("stopTime", "stop_time"),
                          ("tolerance", "tolerance"), ("stepSize", "step_size")):
            value = getattr(experiment, attr, None)
            if value is not None:
                ex[key] = repr(float(value))
        ET.SubElement(root, "DefaultExperiment", ex)
    variables = ET.SubElement(root, "ModelVariables")
    for i, v in enumerate(table):
        sv = {"name": v.name, "valueReference": str(i)}
        if v.description:
            sv["description"] = v.description
        sv["causality"] = v.causality
        sv["variability"] = v.variability
        if v.initial is not None:
            sv["initial"] = v.initial
        node = ET.SubElement(variables, "ScalarVariable", sv)
        typed = {}
        if v.unit is not None:
            typed["unit"] = v.unit
        if v.min is not None:
            typed["min"] = _fmt(v, v.min)
        if v.max is not None:
            typed["max"] = _fmt(v, v.max)
        if v.start is not None:
            typed["start"] = _fmt(v, v.start)
        ET.SubElement(node, v.type, typed)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [v for v in table if v.is_output]
    if outputs:
        node = ET.SubElement(structure, "Outputs")
        for v in outputs:
            deps = sorted(index[d] for d in v.depends_on)
            ET.SubElement(node, "Unknown", _unknown(index[v.name], deps))
    params = [index[v.name] for v in table if v.causality == "parameter"]
    initial_unknowns = [v for v in table if (v.is_output and v.initial in ("approx", "calculated"))
                        or v.causality == "calculatedParameter"]
    if initial_unknowns:
        node = ET.SubElement(structure, "InitialUnknowns")
        for v in initial_unknowns:
            # in Initialization Mode an output may also depend on every parameter (exact);
            # listing them all is the safe over-approximation (parameters are never in a loop)
            deps = sorted(set(index[d] for d in (v.depends_on or ())) | set(params))
            ET.SubElement(node, "Unknown", _unknown(index[v.name], deps))
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode() + b"\n"


def _unknown(idx: int, deps: list[int]) -> dict[str, str]:
    return {"index": str(idx), "dependencies": " ".join(map(str, deps)),
            "dependenciesKind": " ".join(["dependent"] * len(deps))}


# ====================================================================== process helpers
@contextlib.contextmanager
def _fmu_hygiene():
    """Undo what loading pythonfmu FMUs does to this process once the run is over.

    pythonfmu's C wrapper prepends the FMU's resources folder to ``sys.path`` at every
    instantiation and never removes it, and the modules the slave imports from there (its own
    module, bundled packages such as ``solver`` if the host had not imported them yet) stay in
    ``sys.modules`` although fmpy/libcosim delete the extracted folder afterwards.  Restore
    ``sys.path`` and forget those modules, so that later imports resolve normally.
    """
    saved = list(sys.path)
    before = set(sys.modules)
    try:
        yield
    finally:
        added = [p for p in set(sys.path) - set(saved) if p and os.path.isabs(p)]
        sys.path[:] = saved
        if added:
            # only the modules imported meanwhile can come from the new folders (string prefixes:
            # a pathlib test over every module of the process cost ~20 ms per instantiation)
            prefixes = tuple(os.path.join(os.path.abspath(p), "") for p in added)
            for name in set(sys.modules) - before:
                origin = getattr(sys.modules.get(name), "__file__", None)
                if origin and os.path.abspath(origin).startswith(prefixes):
                    del sys.modules[name]


#: Public name of the context manager, for masters that instantiate FMUs themselves.
import_hygiene = _fmu_hygiene


@contextlib.contextmanager
def captured_slave_log(strip_traceback: bool = False):
    """Collect the warnings and errors TableSlave instances of this process send to Python logging
    (logger ``fmu_src.<Model>``); ``strip_traceback`` keeps only each message's first part."""
    records: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record):
            try:
                msg = record.getMessage()
            except Exception:  # noqa: BLE001 - a malformed record must not break the run
                return
            records.append(msg.split("\nTraceback", 1)[0] if strip_traceback else msg)

    handler = _Collect(level=logging.WARNING)
    target = logging.getLogger("fmu_src")
    target.addHandler(handler)
    try:
        yield records
    finally:
        target.removeHandler(handler)


def _with_slave_log(message: str, records: list[str]) -> str:
    return message + ("\nslave log:\n  " + "\n  ".join(records) if records else "")


# ====================================================================== checks
def validate(fmu_path: str | os.PathLike) -> list[str]:
    """Problems of an FMU (empty list: none): fmpy.validation.validate_fmu plus this project's rules."""
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    fmu_path = str(fmu_path)
    problems = list(validate_fmu(fmu_path))
    if problems:
        return problems
    md = read_model_description(fmu_path, validate=False)
    cs = md.coSimulation
    if cs is None:
        return ["no CoSimulation interface"]
    if not cs.canGetAndSetFMUstate:
        problems.append('canGetAndSetFMUstate must be "true"')
    ident = cs.modelIdentifier
    with zipfile.ZipFile(fmu_path) as z:
        names = set(z.namelist())
        if f"binaries/linux64/{ident}.so" not in names:
            problems.append(f"binaries/linux64/{ident}.so missing")
        module = z.read("resources/slavemodule.txt").decode().strip() if "resources/slavemodule.txt" in names else None
        if module != ident:
            problems.append(f"resources/slavemodule.txt names {module!r}, expected {ident!r}")
        elif f"resources/{module}.py" not in names:
            problems.append(f"resources/{module}.py missing")
        if any("__pycache__" in n or n.endswith(".pyc") for n in names):
            problems.append("compiled Python files in the archive")
    inputs = {v for v in md.modelVariables if v.causality == "input"}
    for unknown in md.outputs:
        if unknown.dependencies is None:
            problems.append(f"output {unknown.variable.name!r} has no dependencies attribute "
                            "(means: depends on all inputs); state them explicitly")
            continue
        bad = [d.name for d in unknown.dependencies if d not in inputs]
        if bad:
            problems.append(f"output {unknown.variable.name!r} depends on non-inputs {bad}")
    for v in md.modelVariables:
        if v.type == "Real" and v.causality in ("input", "output", "parameter") and v.unit is None:
            problems.append(f"Real variable {v.name!r} has no unit (use '1' for dimensionless)")
    return problems


def value_references(fmu_path: str | os.PathLike) -> dict[str, int]:
    """Name -> value reference, read once from the model description (FMPy style)."""
    from fmpy import read_model_description

    return {v.name: v.valueReference for v in read_model_description(str(fmu_path)).modelVariables}


def smoke_check(fmu_path: str | os.PathLike, *, n_steps: int = 20, step_size: float = 1e-3,
                inputs: Mapping[str, Sequence[float] | float] | None = None,
                start_values: Mapping[str, Any] | None = None) -> list[str]:
    """Run an FMU through fmpy's FMU2Slave and list what is wrong (empty list: nothing).

    Checks that ``n_steps`` steps succeed with finite outputs; that getFMUstate/setFMUstate in the
    middle of the run and serialize/deserialize into a second instance reproduce the outputs bit for
    bit (a state not fully covered shows here); that fmi2Reset reproduces the first run; and that
    the FMU logged no warning or error.  ``inputs``: name -> constant or ``n_steps`` values.
    """
    from fmpy import extract, read_model_description

    md = read_model_description(str(fmu_path))
    unzipdir = extract(str(fmu_path))
    problems: list[str] = []
    instances = []
    hygiene = _fmu_hygiene()
    hygiene.__enter__()
    try:
        master = _Master(md, unzipdir, inputs or {}, start_values or {}, n_steps, step_size)
        a = master.instance("smoke-a")
        instances.append(a)
        try:
            first = master.run(a, 0, n_steps)
        except _MasterError as exc:
            return [str(exc)]
        bad = [name for name, value in zip(master.output_names, first[-1] if first else ())
               if isinstance(value, float) and not math.isfinite(value)]
        if bad:
            problems.append(f"non-finite outputs after {n_steps} steps: {bad}")
        b = master.instance("smoke-b")
        instances.append(b)
        half = n_steps // 2
        try:
            master.run(b, 0, half)
            state = b.fmu.getFMUstate()
            blob = b.fmu.serializeFMUstate(state) if md.coSimulation.canSerializeFMUstate else None
            rest = master.run(b, half, n_steps)
            b.fmu.setFMUstate(state)
            b.fmu.freeFMUstate(state)
            if master.run(b, half, n_steps) != rest:
                problems.append("getFMUstate/setFMUstate does not reproduce the outputs: the FMU state "
                                "misses part of the internal state")
            if blob is not None:
                c = master.instance("smoke-c")
                instances.append(c)
                restored = c.fmu.deSerializeFMUstate(blob)
                c.fmu.setFMUstate(restored)
                c.fmu.freeFMUstate(restored)
                if master.run(c, half, n_steps) != rest:
                    problems.append("a deserialized FMU state does not reproduce the outputs in another instance")
            a.fmu.reset()
            master.initialize(a)
            if master.run(a, 0, n_steps) != first:
                problems.append("fmi2Reset does not return to the initial state")
        except _MasterError as exc:
            problems.append(str(exc))
        for inst in instances:
            problems += [f"{inst.name} logged: {m}" for status, m in inst.messages if status >= 1]
        return problems
    finally:
        for inst in instances:
            with contextlib.suppress(Exception):
                inst.fmu.terminate()
            with contextlib.suppress(Exception):
                inst.fmu.freeInstance()
        hygiene.__exit__(None, None, None)
        shutil.rmtree(unzipdir, ignore_errors=True)


class _MasterError(RuntimeError):
    pass


class _Master:
    """The minimal FMU2Slave master of ``smoke_check`` (value references looked up once)."""

    def __init__(self, md, unzipdir, inputs, start_values, n_steps, step_size):
        self.md, self.unzipdir, self.h = md, unzipdir, step_size
        self.variables = {v.name: v for v in md.modelVariables}
        unknown = [n for n in [*inputs, *start_values] if n not in self.variables]
        if unknown:
            raise _MasterError(f"unknown variables {unknown}")
        self.inputs = {n: np.broadcast_to(np.asarray(v), (n_steps,)) for n, v in inputs.items()}
        self.start_values = dict(start_values)
        outputs = [v for v in md.modelVariables if v.causality == "output"]
        self.output_names = [v.name for v in outputs]
        self.outputs = [(v.type, v.valueReference) for v in outputs]

    def instance(self, name):
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        import fmpy
        from ctypes import byref
        from fmpy.logging import addLoggerProxy

        class _Inst:
            pass

        inst = _Inst()
        inst.name, inst.messages = name, []

        def logger(_c, _n, status, _cat, message):
            inst.messages.append((int(status), message.decode("utf-8", "replace") if message else ""))

        inst.callbacks = fmi2CallbackFunctions()
        inst.callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        inst.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        inst.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        addLoggerProxy(byref(inst.callbacks))
        inst.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        inst.fmu.instantiate(callbacks=inst.callbacks, loggingOn=True)
        self.initialize(inst)
        return inst

    def _set(self, inst, name, value):
        v = self.variables[name]
        setter = {"Real": inst.fmu.setReal, "Integer": inst.fmu.setInteger, "Boolean": inst.fmu.setBoolean}[v.type]
        cast = {"Real": float, "Integer": int, "Boolean": bool}[v.type]
        setter([v.valueReference], [cast(value)])

    def initialize(self, inst):
        inst.fmu.setupExperiment(startTime=0.0)
        inst.fmu.enterInitializationMode()
        for name, value in self.start_values.items():
            self._set(inst, name, value)
        for name, values in self.inputs.items():
            self._set(inst, name, values[0])
        inst.fmu.exitInitializationMode()

    def run(self, inst, k0, k1):
        from fmpy.fmi1 import FMICallException

        rows = []
        for k in range(k0, k1):
            for name, values in self.inputs.items():
                self._set(inst, name, values[k])
            try:
                inst.fmu.doStep(k * self.h, self.h)
            except FMICallException as exc:
                log = "; ".join(m for _, m in inst.messages[-3:])
                raise _MasterError(f"{inst.name}: doStep at t={k * self.h!r} returned status {exc.status}: {log}")
            row = []
            for kind, vr in self.outputs:
                getter = {"Real": inst.fmu.getReal, "Integer": inst.fmu.getInteger,
                          "Boolean": inst.fmu.getBoolean, "String": inst.fmu.getString}[kind]
                row.append(getter([vr])[0])
            rows.append(tuple(row))
        return rows


# ====================================================================== fmpy
def input_table(time: Sequence[float], **signals: Sequence[float]) -> np.ndarray:
    """Structured array in fmpy's input format: a 'time' column and one column per input."""
    time = np.asarray(time, dtype=float)
    dtype = [("time", np.float64)]
    columns = [time]
    for name, values in signals.items():
        values = np.asarray(values)
        if values.shape != time.shape:
            raise ValueError(f"input {name!r}: {values.shape} values for {time.shape} times")
        dtype.append((name, np.bool_ if values.dtype == bool else
                      (np.int32 if np.issubdtype(values.dtype, np.integer) else np.float64)))
        columns.append(values)
    table = np.empty(time.shape, dtype=dtype)
    for (name, _), column in zip(dtype, columns):
        table[name] = column
    return table


def simulate(fmu_path: str | os.PathLike, *, stop_time: float, step_size: float, start_time: float = 0.0,
             inputs: np.ndarray | None = None, start_values: Mapping[str, Any] | None = None,
             outputs: Sequence[str] | None = None, raise_on_refusal: bool = True,
             log: list[str] | None = None) -> np.ndarray:
    """Smoke simulation with ``fmpy.simulate_fmu`` (communication step = ``step_size``).

    fmpy.simulate_fmu ends quietly when a step is refused (fmi2Discard + fmi2Terminated) and returns
    the result up to the last good communication point.  Here the FMU log is captured (debug logging
    on) and :class:`StepRefusedError` is raised if any message has status >= fmi2Discard or the
    result stops before ``stop_time``.  ``log`` (optional) receives every FMU log line.
    """
    import fmpy
    from fmpy.fmi2 import fmi2Discard

    captured: list[tuple[int, str]] = []

    def logger(_component, _instance, status, _category, message):
        captured.append((int(status), message.decode("utf-8", "replace") if message else ""))

    with _fmu_hygiene(), captured_slave_log() as records:
        result = fmpy.simulate_fmu(str(fmu_path), start_time=start_time, stop_time=stop_time,
                                   step_size=step_size, output_interval=step_size, input=inputs,
                                   start_values=dict(start_values or {}), output=outputs,
                                   debug_logging=True, logger=logger, fmi_type="CoSimulation")
    if log is not None:
        log.extend(m for _, m in captured)
    refusals = [m for s, m in captured if s >= fmi2Discard] or [m for m in records if "refused" in m]
    end = float(result["time"][-1]) if len(result) else start_time
    truncated = end < stop_time - 1e-9 * max(1.0, abs(stop_time))
    if raise_on_refusal and (refusals or truncated):
        what = "; ".join(refusals) or f"result ends at t={end} < stop_time={stop_time}"
        raise StepRefusedError(f"{Path(fmu_path).name}: simulation stopped at t={end}: {what}",
                               refusals, result)
    return result


# ====================================================================== libcosim
@dataclass
class CosimResult:
    """Samples after each libcosim step: ``time`` (s) and one array per observed variable."""

    time: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.time if name == "time" else self.values[name]


def _cosim_modules():
    from libcosimpy import CosimExecution, CosimLogging, CosimManipulator, CosimObserver, CosimSlave
    from libcosimpy._internal import get_last_error_message

    return CosimExecution, CosimLogging, CosimManipulator, CosimObserver, CosimSlave, get_last_error_message


_COSIM_LOG_LEVELS = ("trace", "debug", "info", "warning", "error", "fatal")


def _set_cosim_log_level(level: str) -> None:
    CosimLogging = _cosim_modules()[1]
    CosimLogging.log_output_level(CosimLogging.CosimLogLevel[level.upper()])


def _variable_index(execution, slave: int) -> dict[str, tuple[int, str, int]]:
    """name -> (value reference, 'Real'|'Integer'|'Boolean'|'String', causality code) from libcosim."""
    from libcosimpy.CosimEnums import CosimVariableType

    names = {CosimVariableType.REAL.value: "Real", CosimVariableType.INTEGER.value: "Integer",
             CosimVariableType.BOOLEAN.value: "Boolean", CosimVariableType.STRING.value: "String"}
    return {v.name.decode(): (v.reference, names[v.type], v.causality) for v in execution.slave_variables(slave)}


def _set_initial(execution, slave: int, index, name: str, value) -> None:
    vr, kind, _ = index[name]
    ok = {"Real": lambda: execution.real_initial_value(slave, vr, float(value)),
          "Integer": lambda: execution.integer_initial_value(slave, vr, int(value)),
          "Boolean": lambda: execution.boolean_initial_value(slave, vr, bool(value)),
          "String": lambda: execution.string_initial_value(slave, vr, str(value))}[kind]()
    if not ok:
        raise LibcosimError(f"could not set the initial value of {name!r}")


def _read(observer, slave: int, index, names: Sequence[str]) -> list:
    out = []
    for name in names:
        vr, kind, _ = index[name]
        getter = {"Real": observer.last_real_values, "Integer": observer.last_integer_values,
                  "Boolean": observer.last_boolean_values}[kind]
        out.append(getter(slave, [vr])[0])
    return out


def run_libcosim(fmu_path: str | os.PathLike, *, step_size: float, n_steps: int,
                 inputs: Mapping[str, Sequence[float] | float] | None = None,
                 start_values: Mapping[str, Any] | None = None,
                 outputs: Sequence[str] | None = None, instance_name: str = "model",
                 log_level: str = "error") -> CosimResult:
    """Run one FMU for ``n_steps`` fixed steps in libcosim (in this process) and sample its outputs.

    ``inputs``: name -> constant or a sequence of ``n_steps`` values; value k is applied (override
    manipulator) before step k, i.e. on [k*h, (k+1)*h].  ``start_values`` are set as initial values
    (parameters, inputs).  Returns the outputs after each step at t = h, 2h, ...  A failed step
    (e.g. a refused one) raises :class:`LibcosimError` with libcosim's message and the partial result.
    """
    _set_cosim_log_level(log_level)
    step_ns = int(round(step_size * 1e9))
    if step_ns <= 0 or abs(step_ns - step_size * 1e9) > 1e-3:
        raise ValueError("step_size must be a positive multiple of 1 ns")
    with _fmu_hygiene(), captured_slave_log() as records:
        return _run_libcosim(fmu_path, step_ns, n_steps, inputs, start_values, outputs, instance_name, records)


def _run_libcosim(fmu_path, step_ns, n_steps, inputs, start_values, outputs, instance_name, records):
    CosimExecution, _, CosimManipulator, CosimObserver, CosimSlave, last_error = _cosim_modules()
    step_size = step_ns * 1e-9
    execution = CosimExecution.CosimExecution.from_step_size(step_ns)
    local = CosimSlave.CosimLocalSlave(fmu_path=str(Path(fmu_path).resolve()), instance_name=instance_name)
    slave = execution.add_local_slave(local)
    if slave < 0:
        raise LibcosimError(f"libcosim could not load {fmu_path}: {last_error()}")
    index = _variable_index(execution, slave)
    if outputs is None:
        from libcosimpy.CosimEnums import CosimVariableCausality
        outputs = [n for n, (_, kind, c) in index.items()
                   if c == CosimVariableCausality.OUTPUT.value and kind != "String"]
    unknown = [n for n in [*(inputs or {}), *(start_values or {}), *outputs] if n not in index]
    if unknown:
        raise LibcosimError(f"unknown variables {unknown}")
    for name, value in (start_values or {}).items():
        _set_initial(execution, slave, index, name, value)
    convert = {"Real": float, "Integer": int, "Boolean": bool}
    series = {}
    for name, value in (inputs or {}).items():
        kind = index[name][1]
        values = [convert[kind](x) for x in np.broadcast_to(np.asarray(value), (n_steps,))]
        series[name] = values
        _set_initial(execution, slave, index, name, values[0])
    observer = CosimObserver.CosimObserver.create_last_value()
    execution.add_observer(observer)
    manipulator = CosimManipulator.CosimManipulator.create_override()
    execution.add_manipulator(manipulator)
    times, rows = [], []
    for k in range(n_steps):
        for name, values in series.items():
            vr, kind, _ = index[name]
            setter = {"Real": manipulator.slave_real_values, "Integer": manipulator.slave_integer_values,
                      "Boolean": manipulator.slave_boolean_values}[kind]
            setter(slave, [vr], [values[k]])
        if not execution.step():
            partial = _cosim_result(times, rows, outputs)
            raise LibcosimError(_with_slave_log(f"libcosim step {k} (t={k * step_size!r}) failed: "
                                                f"{last_error()}", records), partial)
        times.append(execution.status().current_time * 1e-9)
        rows.append(_read(observer, slave, index, outputs))
    return _cosim_result(times, rows, outputs)


def _cosim_result(times, rows, names) -> CosimResult:
    columns = list(zip(*rows)) if rows else [[] for _ in names]
    return CosimResult(np.asarray(times, dtype=float),
                       {name: np.asarray(col) for name, col in zip(names, columns)})


def write_osp_system_structure(path: str | os.PathLike, simulators: Mapping[str, str | os.PathLike], *,
                               base_step_size: float,
                               connections: Iterable[tuple[str, str]] = (),
                               initial_values: Mapping[str, Mapping[str, Any]] | None = None,
                               start_time: float = 0.0) -> Path:
    """Write an OspSystemStructure.xml: ``simulators`` instance -> FMU path, ``connections`` as
    ``("instance.output", "instance.input")`` pairs, ``initial_values`` instance -> {variable: value}.
    """
    path = Path(path)
    ns = "http://opensimulationplatform.com/MSMI/OSPSystemStructure"
    root = ET.Element("OspSystemStructure", {"xmlns": ns, "version": "0.1"})
    ET.SubElement(root, "StartTime").text = repr(float(start_time))
    ET.SubElement(root, "BaseStepSize").text = repr(float(base_step_size))
    ET.SubElement(root, "Algorithm").text = "fixedStep"
    sims = ET.SubElement(root, "Simulators")
    for name, fmu in simulators.items():
        source = os.path.relpath(Path(fmu).resolve(), path.parent.resolve()).replace(os.sep, "/")
        sim = ET.SubElement(sims, "Simulator", {"name": name, "source": source})
        values = (initial_values or {}).get(name)
        if values:
            iv = ET.SubElement(sim, "InitialValues")
            for var, value in values.items():
                node = ET.SubElement(iv, "InitialValue", {"variable": var})
                kind = "Boolean" if isinstance(value, bool) else "Integer" if isinstance(value, int) else "Real"
                text = ("true" if value else "false") if kind == "Boolean" else (
                    str(value) if kind == "Integer" else repr(float(value)))
                ET.SubElement(node, kind, {"value": text})
    conns = list(connections)
    if conns:
        node = ET.SubElement(root, "Connections")
        for source, target in conns:
            vc = ET.SubElement(node, "VariableConnection")
            for end in (source, target):
                instance, _, variable = end.partition(".")
                ET.SubElement(vc, "Variable", {"simulator": instance, "name": variable})
    ET.indent(root, space="  ")
    path.write_bytes(b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode())
    return path


def run_osp_system(osp_path: str | os.PathLike, *, n_steps: int, observe: Sequence[str],
                   step_size: float | None = None, log_level: str = "error") -> CosimResult:
    """Run a system of FMUs in libcosim for ``n_steps`` base steps and sample ``observe``
    (``"instance.variable"`` names) after each step.

    ``osp_path``: an OspSystemStructure.xml (or its folder), or an SSP SystemStructure.ssd / .ssp
    (then ``step_size`` in seconds gives libcosim's fixed step).
    """
    CosimExecution, _, _, CosimObserver, _, last_error = _cosim_modules()
    _set_cosim_log_level(log_level)
    with _fmu_hygiene(), captured_slave_log() as records:
        try:
            if Path(osp_path).suffix in (".ssd", ".ssp"):
                execution = CosimExecution.CosimExecution.from_ssp_file(
                    str(osp_path), None if step_size is None else int(round(step_size * 1e9)))
            else:
                execution = CosimExecution.CosimExecution.from_osp_config_file(str(osp_path))
        except AssertionError as exc:
            raise LibcosimError(str(exc)) from exc
        slaves = {info.name.decode(): info.index for info in execution.slave_infos()}
        indexes = {name: _variable_index(execution, idx) for name, idx in slaves.items()}
        targets = []
        for item in observe:
            instance, _, variable = item.partition(".")
            if instance not in slaves or variable not in indexes[instance]:
                raise LibcosimError(f"unknown variable {item!r}")
            targets.append((instance, variable))
        observer = CosimObserver.CosimObserver.create_last_value()
        execution.add_observer(observer)
        times, rows = [], []
        for k in range(n_steps):
            if not execution.step():
                raise LibcosimError(_with_slave_log(f"libcosim step {k} failed: {last_error()}", records),
                                    _cosim_result(times, rows, list(observe)))
            times.append(execution.status().current_time * 1e-9)
            rows.append([_read(observer, slaves[i], indexes[i], [v])[0] for i, v in targets])
        return _cosim_result(times, rows, list(observe))
