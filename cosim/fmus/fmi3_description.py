"""The FMI 3.0 modelDescription.xml of an FMI 3.0 adapter slave (host side; never bundled).

pythonfmu3 0.3.4 writes no ``time`` variable of causality independent (fmpy's validation asks for
one; the slave declares it, :class:`fmu_src.fmi3_adapter.Row3`), no units on Int32 rows, Outputs
without ``dependencies`` (meaning "every input"), ``canGetAndSetFMUState="false"`` unless told, a
time-based ``uuid1`` instantiation token and a timestamp (never the same twice).
:func:`model_description_xml` writes instead, from the adapter's rows and its core's table:
units and UnitDefinitions, explicit causality/variability/initial, array ``Dimension`` elements
and their start values, Outputs and InitialUnknowns with ``dependencies``, the FMU-state flags,
the token it is given, no timestamp.  Only the Co-Simulation interface is declared, with no event
mode, no intermediate update and no clocks (the adapter implements none of them).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from .model_description import BASE_UNIT_ORDER, UNIT_DEFINITIONS

__all__ = ["model_description_xml"]


def _fmt(kind: str, value) -> str:
    if kind == "Boolean":
        return "true" if value else "false"
    if kind == "Int32":
        return str(int(value))
    return repr(float(value))


def _header(cls, token: str) -> dict[str, str]:
    from pythonfmu3 import __version__ as pythonfmu3_version

    attrib = {"fmiVersion": "3.0", "modelName": cls.__name__, "instantiationToken": token}
    core = cls.CORE
    for key in ("description", "author", "version", "copyright", "license"):
        value = cls.__dict__.get(key) or getattr(core, key, None)      # the adapter's own, else its core's
        if isinstance(value, str) and value:
            attrib[key] = value
    attrib.update(generationTool=f"PythonFMU3 {pythonfmu3_version} + cosim.fmus.fmi3_build",
                  variableNamingConvention="flat")
    return attrib


def _units(root, used: list[str]) -> None:
    if not used:
        return
    node = ET.SubElement(root, "UnitDefinitions")
    for name in used:
        unit = ET.SubElement(node, "Unit", {"name": name})
        base = UNIT_DEFINITIONS[name]
        ET.SubElement(unit, "BaseUnit", {k: repr(base[k]) if k in ("factor", "offset") else str(int(base[k]))
                                         for k in BASE_UNIT_ORDER if k in base})


def _variable(parent, vr: int, row, table: dict, start: dict) -> None:
    """The ``<Float64|Int32|Boolean>`` element of ``row`` with value reference ``vr``."""
    attrib = {"name": row.name, "valueReference": str(vr)}
    if row.description:
        attrib["description"] = row.description
    if not row.core:
        attrib.update(causality="independent", variability="continuous")
        ET.SubElement(parent, row.type, attrib)
        return
    first = table[row.core[0]]
    attrib.update(causality=first.causality, variability=first.variability)
    if first.initial is not None:
        attrib["initial"] = first.initial
    if row.unit is not None:
        attrib["unit"] = row.unit
    for key in ("min", "max"):
        values = {getattr(table[n], key) for n in row.core}
        if len(values) == 1 and None not in values:
            attrib[key] = _fmt(row.type, values.pop())
    if first.start is not None:
        attrib["start"] = " ".join(_fmt(row.type, start.get(n, table[n].start)) for n in row.core)
    node = ET.SubElement(parent, row.type, attrib)
    if len(row.core) > 1:
        ET.SubElement(node, "Dimension", {"start": str(len(row.core))})


def _structure(root, rows, table: dict) -> None:
    """ModelStructure: each output with the inputs it depends on; each initial unknown with those and
    the parameters (in Initialization Mode an output may depend on every parameter)."""
    vr_of = {}
    for vr, row in enumerate(rows):
        for name in row.core:
            vr_of[name] = vr
    node = ET.SubElement(root, "ModelStructure")
    params = sorted({vr for vr, row in enumerate(rows) if row.core and table[row.core[0]].causality == "parameter"})
    outputs = [(vr, row) for vr, row in enumerate(rows) if row.core and table[row.core[0]].is_output]
    unknowns = []
    for vr, row in outputs:
        deps = sorted({vr_of[d] for name in row.core for d in table[name].depends_on})
        ET.SubElement(node, "Output", {"valueReference": str(vr), "dependencies": " ".join(map(str, deps)),
                                       "dependenciesKind": " ".join(["dependent"] * len(deps))})
        if table[row.core[0]].initial in ("approx", "calculated"):
            unknowns.append((vr, sorted(set(deps) | set(params))))
    for vr, deps in unknowns:
        ET.SubElement(node, "InitialUnknown", {"valueReference": str(vr), "dependencies": " ".join(map(str, deps)),
                                               "dependenciesKind": " ".join(["dependent"] * len(deps))})


def model_description_xml(cls, *, token: str) -> bytes:
    """modelDescription.xml (FMI 3.0, Co-Simulation) of an adapter class (deterministic).

    Parameters
    ----------
    cls : Fmi3Adapter subclass
        The slave: its ``ROWS``, ``START``, its ``CORE``'s table, ``log_categories`` and ``default_experiment``.
    token : str
        The instantiation token (the build derives it from the FMU's content).

    Returns
    -------
    bytes
        The XML document, UTF-8, indented, LF line ends.
    """
    root = ET.Element("fmiModelDescription", _header(cls, token))
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": cls.__name__,
        "needsExecutionTool": "true",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true",
        "canHandleVariableCommunicationStepSize": "true",
        "hasEventMode": "false",
        "providesIntermediateUpdate": "false",
        "canReturnEarlyAfterIntermediateUpdate": "false",
    })
    table = {v.name: v for v in cls.CORE._table}
    _units(root, sorted({r.unit for r in cls.ROWS if r.unit is not None}))
    cats = ET.SubElement(root, "LogCategories")
    for name, text in cls.log_categories.items():
        ET.SubElement(cats, "Category", {"name": name, "description": text})
    experiment = getattr(cls.CORE, "default_experiment", None)
    if experiment is not None:
        ET.SubElement(root, "DefaultExperiment", {
            key: repr(float(getattr(experiment, attr))) for key, attr in (
                ("startTime", "start_time"), ("stopTime", "stop_time"), ("tolerance", "tolerance"),
                ("stepSize", "step_size")) if getattr(experiment, attr, None) is not None})
    variables = ET.SubElement(root, "ModelVariables")
    for vr, row in enumerate(cls.ROWS):
        _variable(variables, vr, row, table, cls.START)
    _structure(root, cls.ROWS, table)
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode() + b"\n"
