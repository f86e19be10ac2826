"""The modelDescription.xml of a table slave, generated from its variable table (host side).

pythonfmu 0.7 emits Outputs ``<Unknown index=..>`` without ``dependencies`` (i.e. "depends on every
input"), no ``InitialUnknowns`` (fmpy: "does not contain the expected set of variables"), no units,
no variability for Integer/Boolean outputs (defaults to continuous: illegal; FMI Library/libcosim
log "Only Real variables can have variability='continuous'"), a time-based ``uuid1`` GUID and
``generationDateAndTime`` (never the same twice).  :func:`model_description_xml` writes instead,
from the table: units and UnitDefinitions, explicit variability/initial, ModelStructure/Outputs
with ``dependencies``/``dependenciesKind``, InitialUnknowns, FMU-state capability flags, the GUID
it is given, no timestamp.  :func:`cross_check` makes sure pythonfmu registered exactly the table.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from fmu_src.table_slave import TableSlave
from fmu_src.variables import Var

__all__ = ["UNIT_DEFINITIONS", "model_description_xml", "cross_check", "ModelDescriptionError"]


class ModelDescriptionError(RuntimeError):
    """pythonfmu's model description disagrees with the slave's table."""


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
BASE_UNIT_ORDER = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")


def cross_check(raw_root: ET.Element, cls: type[TableSlave]) -> None:
    """pythonfmu registered exactly the table, in order (value reference = row number)."""
    raw = [(sv.get("name"), int(sv.get("valueReference")), sv.get("causality"))
           for sv in raw_root.find("ModelVariables")]
    mine = [(v.name, i, v.causality) for i, v in enumerate(cls._table)]
    if raw != mine:
        raise ModelDescriptionError(f"pythonfmu registered {raw}, the table says {mine}")
    cs = raw_root.find("CoSimulation")
    if cs is None or cs.get("modelIdentifier") != cls.__name__:
        raise ModelDescriptionError("pythonfmu's modelIdentifier differs from the class name")


def _fmt(v: Var, value) -> str:
    if v.type == "Boolean":
        return "true" if value else "false"
    if v.type == "Integer":
        return str(int(value))
    return repr(float(value))


def model_description_xml(cls: type[TableSlave], *, guid: str, can_serialize_state: bool = True) -> bytes:
    """modelDescription.xml of a TableSlave class, generated from its table (deterministic).

    Parameters
    ----------
    cls : TableSlave subclass
        The slave; its ``_table`` (the variable rows), ``UNITS``, ``log_categories`` and
        ``default_experiment`` are written.
    guid : str
        The FMU's GUID (the packaging derives it from the FMU's content).
    can_serialize_state : bool
        The CoSimulation capability ``canSerializeFMUstate``.

    Returns
    -------
    bytes
        The XML document, UTF-8, indented, LF line ends.
    """
    root = ET.Element("fmiModelDescription", _header(cls, guid))
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
    table = cls._table
    _unit_definitions(root, {**UNIT_DEFINITIONS, **cls.UNITS}, sorted({v.unit for v in table if v.unit is not None}))
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
        _scalar_variable(variables, i, v)
    _model_structure(root, table)
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode() + b"\n"


def _header(cls, guid: str) -> dict[str, str]:
    """The attributes of ``fmiModelDescription``."""
    from pythonfmu import __version__ as pythonfmu_version

    attrib = {"fmiVersion": "2.0", "modelName": cls.__name__, "guid": guid}
    for key in ("description", "author", "version", "copyright", "license"):
        value = getattr(cls, key, None)
        if isinstance(value, str) and value:
            attrib[key] = value
    attrib.update(generationTool=f"PythonFMU {pythonfmu_version} + cosim.fmus.packaging",
                  variableNamingConvention="structured", numberOfEventIndicators="0")
    return attrib


def _unit_definitions(root, units: dict, used: list[str]) -> None:
    """``UnitDefinitions``: each unit in ``used`` with its SI base-unit exponents, factor, offset."""
    if not used:
        return
    unit_defs = ET.SubElement(root, "UnitDefinitions")
    for name in used:
        unit = ET.SubElement(unit_defs, "Unit", {"name": name})
        base = units[name]
        ET.SubElement(unit, "BaseUnit", {k: repr(base[k]) if k in ("factor", "offset") else str(int(base[k]))
                                         for k in BASE_UNIT_ORDER if k in base})


def _scalar_variable(variables, i: int, v: Var) -> None:
    """The ``ScalarVariable`` of table row ``v`` with value reference ``i``."""
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
    for key in ("min", "max", "start"):
        value = getattr(v, key)
        if value is not None:
            typed[key] = _fmt(v, value)
    ET.SubElement(node, v.type, typed)


def _model_structure(root, table) -> None:
    """``ModelStructure``: the outputs with their dependencies, and the initial unknowns."""
    index = {v.name: i + 1 for i, v in enumerate(table)}   # ScalarVariable indices are 1-based
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


def _unknown(idx: int, deps: list[int]) -> dict[str, str]:
    return {"index": str(idx), "dependencies": " ".join(map(str, deps)),
            "dependenciesKind": " ".join(["dependent"] * len(deps))}
