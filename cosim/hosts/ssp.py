"""A system of FMUs as an SSP 1.0 package (host side; never bundled into an FMU).

:func:`write_ssp` writes ``<name>.ssp``: a zip with ``SystemStructure.ssd`` and the FMUs under
``resources/``.  The system structure (:func:`system_structure`) lists

* one ``ssd:Component`` per instance, ``source="resources/<Model>.fmu"``, with one ``ssd:Connector``
  per input, output, parameter and calculated parameter of the FMU (kind = FMI causality, type and
  unit from its modelDescription.xml);
* one inline ``ssd:ParameterBinding`` per instance holding an ``ssv:ParameterSet`` named
  :data:`PARAMETER_SET`: the start values of its parameters *and inputs* (an input's start value
  is legal to set before initialization, SSP 1.0 section "ParameterBindings"), so a host that
  applies the set hands every FMU consistent values before it initializes;
* the ``ssd:Connections`` (``"instance.output" -> "instance.input"``);
* the ``ssd:Units`` the connectors use (from the FMUs' UnitDefinitions);
* ``ssd:DefaultExperiment`` (start and stop time) with the communication step as an OSP annotation
  (``osp:Algorithm/osp:FixedStepAlgorithm baseStepSize``, libcosim's fixed-step master; Ecos takes
  the step as an argument);
* with a step, the system's OMSimulator annotation (``ssd:System/ssd:Annotations/ssc:Annotation
  type="org.openmodelica"/oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster
  description="oms-ma" stepSize``): OMSimulator's command line takes the system's type (here a
  weakly coupled system with its fixed-step master) only from that annotation and cannot import
  the system without it.  It must be the system's first ``ssc:Annotation`` (OMSimulator reads only
  that one).

The element prefixes are ``ssd:``, ``ssc:``, ``ssv:`` exactly: Ecos matches element names with
their prefix.  :func:`schema_problems` checks an SSD against the SSP 1.0 XML schemas
(``SystemStructureDescription.xsd``, and ``SystemStructureParameterValues.xsd`` for the inline
parameter sets, which the SSD schema accepts as any XML), taken from the ``pyssp-standard``
package (a test dependency; the normative schemas of the Modelica Association, which it ships).

Same FMU files and values give a byte-identical package.
"""
from __future__ import annotations

import os
import zipfile
from importlib import resources as importlib_resources
from pathlib import Path
from typing import Any, Iterable, Mapping
from xml.etree import ElementTree as ET

__all__ = ["PARAMETER_SET", "OMS", "OMS_ANNOTATION_TYPE", "OMS_FIXED_STEP_MASTER", "SSPError", "SchemaUnavailable",
           "system_structure", "write_ssp", "read_system_structure", "schema_problems"]

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
#: Namespace of OMSimulator's vendor annotations (the one OMSimulator writes; it matches the
#: ``oms:`` prefix, not the URI).
OMS = "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"
#: ``ssc:Annotation type`` of OMSimulator's annotations.
OMS_ANNOTATION_TYPE = "org.openmodelica"
#: OMSimulator's name of its fixed-step master (a weakly coupled system's solver ``oms-ma``).
OMS_FIXED_STEP_MASTER = "oms-ma"
_PREFIXES = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "osp": OSP, "oms": OMS}
#: Name of the parameter set of start values (Ecos applies a set only by name: ``init(parameter_set=...)``).
PARAMETER_SET = "initial"
_KINDS = ("input", "output", "parameter", "calculatedParameter")
_BASE_UNIT = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)

for _prefix, _uri in _PREFIXES.items():
    ET.register_namespace(_prefix, _uri)


class SSPError(ValueError):
    """A system that cannot be written as given; the message names the instance/variable/value."""


class SchemaUnavailable(RuntimeError):
    """The SSP 1.0 schemas are not installed (``pip install pyssp-standard``)."""


def _q(prefix: str, tag: str) -> str:
    return f"{{{_PREFIXES[prefix]}}}{tag}"


def _value_text(kind: str, value: Any, where: str) -> str:
    if kind == "Real":
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise SSPError(f"{where}: expected a Real, got {value!r}") from None
        if v != v or v in (float("inf"), float("-inf")):
            raise SSPError(f"{where}: expected a finite Real, got {value!r}")
        return repr(v)
    if kind == "Integer":
        if isinstance(value, bool) or int(value) != value:
            raise SSPError(f"{where}: expected an Integer, got {value!r}")
        return str(int(value))
    if kind == "Boolean":
        if value not in (True, False, 0, 1):
            raise SSPError(f"{where}: expected a Boolean, got {value!r}")
        return "true" if value else "false"
    if kind == "String":
        return str(value)
    raise SSPError(f"{where}: unsupported variable type {kind}")


def _variables(md) -> dict:
    return {v.name: v for v in md.modelVariables}


def system_structure(fmus: Mapping[str, Any], *, connections: Iterable[tuple[str, str]] = (),
                     parameter_values: Mapping[str, Mapping[str, Any]] | None = None,
                     name: str = "System", start_time: float = 0.0, stop_time: float | None = None,
                     step_size: float | None = None, sources: Mapping[str, str] | None = None) -> bytes:
    """``SystemStructure.ssd`` (SSP 1.0) of a system of FMUs (see the module docstring).

    Parameters
    ----------
    fmus : {instance: FMU path}
        The components, in this order.
    connections : iterable of ("instance.output", "instance.input")
    parameter_values : {instance: {variable: value}}
        Start values of parameters and inputs, written as the parameter set :data:`PARAMETER_SET`.
    name : str
        Name of the SSD and of its system.
    start_time, stop_time : float
        ``ssd:DefaultExperiment``.
    step_size : float, optional
        The communication step, s (annotations ``osp:FixedStepAlgorithm`` of the default experiment
        and ``oms:FixedStepMaster`` of the system).
    sources : {instance: source URI}, optional
        Default ``resources/<file name>``.

    Raises
    ------
    SSPError
        An unknown instance or variable, a connection between variables of the wrong causality or
        type, a value of the wrong type, a variable that must not be set before initialization.
    """
    from fmpy import read_model_description

    mds = {inst: read_model_description(str(path)) for inst, path in fmus.items()}
    variables = {inst: _variables(md) for inst, md in mds.items()}
    values = dict(parameter_values or {})
    unknown = sorted(set(values) - set(fmus))
    if unknown:
        raise SSPError(f"parameter_values: unknown instances {unknown}; expected some of {list(fmus)}")
    conns = _checked_connections(connections, variables)
    root = ET.Element(_q("ssd", "SystemStructureDescription"), {"version": "1.0", "name": name})
    system = ET.SubElement(root, _q("ssd", "System"), {"name": name})
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    units_used: dict[str, Any] = {}
    for inst, path in fmus.items():
        source = (sources or {}).get(inst, f"resources/{Path(path).name}")
        comp = _component(elements, inst, source, mds[inst], units_used)
        _parameter_binding(comp, inst, variables[inst], values.get(inst, {}))
    if conns:
        node = ET.SubElement(system, _q("ssd", "Connections"))
        for a, u, b, v in conns:
            ET.SubElement(node, _q("ssd", "Connection"),
                          {"startElement": a, "startConnector": u, "endElement": b, "endConnector": v})
    if step_size is not None:
        _omsimulator_annotation(system, step_size)
    if units_used:
        _units(root, units_used)
    _default_experiment(root, start_time, stop_time, step_size)
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode() + b"\n"


def _checked_connections(connections, variables: dict) -> list[tuple[str, str, str, str]]:
    """``(instance, output, instance, input)`` of each connection, checked against the variables."""
    def end(text: str, causality: str) -> tuple[str, str]:
        inst, _, var = text.partition(".")
        if inst not in variables or var not in variables[inst]:
            raise SSPError(f"connection end {text!r}: no such instance.variable")
        if variables[inst][var].causality != causality:
            raise SSPError(f"connection end {text!r}: expected an {causality}, "
                           f"got a {variables[inst][var].causality}")
        return inst, var

    conns = []
    for src, dst in connections:
        (a, u), (b, v) = end(src, "output"), end(dst, "input")
        if variables[a][u].type != variables[b][v].type:
            raise SSPError(f"connection {src} -> {dst}: types {variables[a][u].type} and {variables[b][v].type}")
        conns.append((a, u, b, v))
    return conns


def _component(elements, inst: str, source: str, md, units_used: dict):
    """The ``ssd:Component`` of one FMU with a connector per input, output and parameter; the units
    its Real connectors use are added to ``units_used``."""
    comp = ET.SubElement(elements, _q("ssd", "Component"), {
        "name": inst, "type": "application/x-fmu-sharedlibrary", "source": source,
        "implementation": "CoSimulation"})
    connectors = ET.SubElement(comp, _q("ssd", "Connectors"))
    for v in md.modelVariables:
        if v.causality not in _KINDS:
            continue
        node = ET.SubElement(connectors, _q("ssd", "Connector"), {"name": v.name, "kind": v.causality})
        attrib = {}
        if v.type == "Real" and v.unit:
            attrib["unit"] = v.unit
            units_used[v.unit] = next((u for u in md.unitDefinitions if u.name == v.unit), None)
        ET.SubElement(node, _q("ssc", v.type), attrib)
    return comp


def _units(root, units_used: dict) -> None:
    """``ssd:Units``: each unit used, with its SI base-unit exponents, factor and offset."""
    units = ET.SubElement(root, _q("ssd", "Units"))
    for unit_name in sorted(units_used):
        unit = ET.SubElement(units, _q("ssc", "Unit"), {"name": unit_name})
        base = getattr(units_used[unit_name], "baseUnit", None)
        attrib = {}
        for key in _BASE_UNIT:
            value = getattr(base, key, None) if base is not None else None
            if value is not None and value != (1.0 if key == "factor" else 0):
                attrib[key] = repr(float(value)) if key in ("factor", "offset") else str(int(value))
        ET.SubElement(unit, _q("ssc", "BaseUnit"), attrib)


def _default_experiment(root, start_time: float, stop_time: float | None, step_size: float | None) -> None:
    """``ssd:DefaultExperiment``, with the communication step as an OSP fixed-step annotation."""
    experiment = {"startTime": repr(float(start_time))}
    if stop_time is not None:
        experiment["stopTime"] = repr(float(stop_time))
    ex = ET.SubElement(root, _q("ssd", "DefaultExperiment"), experiment)
    if step_size is not None:
        annotations = ET.SubElement(ex, _q("ssd", "Annotations"))
        annotation = ET.SubElement(annotations, _q("ssc", "Annotation"), {"type": "com.opensimulationplatform"})
        algorithm = ET.SubElement(annotation, _q("osp", "Algorithm"))
        ET.SubElement(algorithm, _q("osp", "FixedStepAlgorithm"), {"baseStepSize": repr(float(step_size))})


def _omsimulator_annotation(system, step_size: float) -> None:
    """The system's OMSimulator annotation: a weakly coupled system stepped by OMSimulator's
    fixed-step master at ``step_size`` s (``ssd:Annotations`` closes ``ssd:System``)."""
    annotations = ET.SubElement(system, _q("ssd", "Annotations"))
    annotation = ET.SubElement(annotations, _q("ssc", "Annotation"), {"type": OMS_ANNOTATION_TYPE})
    info = ET.SubElement(ET.SubElement(annotation, _q("oms", "Annotations")), _q("oms", "SimulationInformation"))
    ET.SubElement(info, _q("oms", "FixedStepMaster"),
                  {"description": OMS_FIXED_STEP_MASTER, "stepSize": repr(float(step_size))})


def _parameter_binding(comp, inst: str, variables: dict, values: Mapping[str, Any]) -> None:
    if not values:
        return
    bindings = ET.SubElement(comp, _q("ssd", "ParameterBindings"))
    binding = ET.SubElement(bindings, _q("ssd", "ParameterBinding"))
    holder = ET.SubElement(binding, _q("ssd", "ParameterValues"))
    pset = ET.SubElement(holder, _q("ssv", "ParameterSet"), {"version": "1.0", "name": PARAMETER_SET})
    params = ET.SubElement(pset, _q("ssv", "Parameters"))
    for var, value in values.items():
        where = f"parameter_values[{inst!r}][{var!r}]"
        v = variables.get(var)
        if v is None:
            raise SSPError(f"{where}: {inst} has no variable {var!r}")
        if v.causality not in ("parameter", "input") or v.variability == "constant":
            raise SSPError(f"{where}: a {v.causality} cannot be set before initialization "
                           "(expected a parameter or an input)")
        node = ET.SubElement(params, _q("ssv", "Parameter"), {"name": var})
        attrib = {"value": _value_text(v.type, value, where)}
        if v.type == "Real" and v.unit:
            attrib["unit"] = v.unit
        ET.SubElement(node, _q("ssv", v.type), attrib)


def write_ssp(path: str | os.PathLike, fmus: Mapping[str, str | os.PathLike], **kwargs) -> Path:
    """Write the SSP package ``path`` (``.ssp``): ``SystemStructure.ssd`` (:func:`system_structure`,
    ``kwargs`` passed on) and each FMU file once as ``resources/<file name>``; returns ``path``."""
    path = Path(path)
    if path.suffix != ".ssp":
        raise SSPError(f"path {str(path)!r}: expected a file name ending in .ssp")
    files: dict[str, Path] = {}
    for inst, fmu in fmus.items():
        fmu = Path(fmu)
        if not fmu.is_file():
            raise SSPError(f"fmus[{inst!r}] = {str(fmu)!r}: no such FMU file")
        key = f"resources/{fmu.name}"
        if files.get(key, fmu).resolve() != fmu.resolve():
            raise SSPError(f"fmus[{inst!r}]: two different files named {fmu.name}")
        files[key] = fmu
    ssd = system_structure(fmus, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    with zipfile.ZipFile(tmp, "w") as z:
        for name, data in [("SystemStructure.ssd", ssd), *((k, files[k].read_bytes()) for k in sorted(files))]:
            info = zipfile.ZipInfo(name, date_time=_ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3
            info.external_attr = (0o100644) << 16
            z.writestr(info, data, compresslevel=9)
    os.replace(tmp, path)
    return path


def read_system_structure(path: str | os.PathLike) -> bytes:
    """The ``SystemStructure.ssd`` of an ``.ssp`` package (or the ``.ssd`` file itself)."""
    path = Path(path)
    if path.suffix == ".ssd":
        return path.read_bytes()
    with zipfile.ZipFile(path) as z:
        return z.read("SystemStructure.ssd")


def _schema_dir() -> Path:
    try:
        folder = importlib_resources.files("pyssp_standard") / "resources"
    except ModuleNotFoundError:
        raise SchemaUnavailable("the SSP 1.0 XML schemas come from the package pyssp-standard: "
                                "python -m pip install pyssp-standard") from None
    folder = Path(str(folder))
    if not (folder / "SystemStructureDescription.xsd").is_file():
        raise SchemaUnavailable(f"{folder}: no SystemStructureDescription.xsd (pyssp-standard changed its layout)")
    return folder


def schema_problems(ssd: bytes | str | os.PathLike) -> list[str]:
    """What the SSP 1.0 schemas reject in an SSD (bytes, or a path to an .ssd or .ssp); [] if valid.

    The SSD is checked against ``SystemStructureDescription.xsd``; each inline ``ssv:ParameterSet``
    (accepted by that schema as any XML) against ``SystemStructureParameterValues.xsd``.
    Raises :class:`SchemaUnavailable` without the schemas.
    """
    from lxml import etree

    folder = _schema_dir()
    data = ssd if isinstance(ssd, bytes) else read_system_structure(ssd)
    doc = etree.fromstring(data)
    problems = []
    for xsd, docs in (("SystemStructureDescription.xsd", [doc]),
                      ("SystemStructureParameterValues.xsd", doc.findall(f".//{{{SSV}}}ParameterSet"))):
        schema = etree.XMLSchema(etree.parse(str(folder / xsd)))
        for d in docs:
            if not schema.validate(d if d is doc else etree.fromstring(etree.tostring(d))):
                problems += [f"{xsd}: line {e.line}: {e.message}" for e in schema.error_log]
    return problems
