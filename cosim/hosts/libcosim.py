"""Running FMUs in DNV libcosim through libcosimpy (host side).

:func:`run_libcosim` runs one FMU; :func:`write_osp_system_structure` + :func:`run_osp_system` run a
system of FMUs described by an OspSystemStructure.xml (or an SSP file).  pythonfmu FMUs run
in-process there: the FMU's binary does not link libpython, it uses the interpreter of the host
process (libcosimpy calls libcosimc through ctypes.CDLL, which releases the GIL, and pythonfmu takes
it with PyGILState_Ensure from libcosim's worker threads).  So the host interpreter must be able to
import what the slave imports (numpy, scipy, numba... from its own environment; project packages
bundled in ``resources/`` come first on ``sys.path`` unless a module of that name is already
imported).  The ``cosim`` command-line tool (a C++ process without Python) cannot load pythonfmu
FMUs: the binary leaves its 45 ``Py*`` symbols undefined (it would need libpython preloaded and
PYTHONHOME/PYTHONPATH pointing at this environment).  Both runners restore ``sys.path`` and forget
the modules imported from the FMU's temporary folder when they return
(:func:`cosim.unit.import_hygiene`).
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..unit import captured_slave_log, import_hygiene, with_slave_log

__all__ = ["LibcosimError", "CosimResult", "run_libcosim", "write_osp_system_structure", "run_osp_system"]


class LibcosimError(RuntimeError):
    """libcosim failed (e.g. a slave refused a step); ``.partial`` holds the samples until then."""

    def __init__(self, message: str, partial: "CosimResult | None" = None):
        super().__init__(message)
        self.partial = partial


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
    with import_hygiene(), captured_slave_log() as records:
        return _run_libcosim(fmu_path, step_ns, n_steps, inputs, start_values, outputs, instance_name, records)


def _run_libcosim(fmu_path, step_ns, n_steps, inputs, start_values, outputs, instance_name, records):
    CosimExecution, _, CosimManipulator, CosimObserver, CosimSlave, last_error = _cosim_modules()
    step_size = step_ns * 1e-9
    execution = CosimExecution.CosimExecution.from_step_size(step_ns)
    local = CosimSlave.CosimLocalSlave(fmu_path=str(Path(fmu_path).resolve()), instance_name=instance_name)
    if not local.ptr():
        # the FMU could not be loaded or instantiated (libcosimpy 0.0.6 would pass the NULL slave
        # on to cosim_execution_add_slave, which crashes the process)
        raise LibcosimError(with_slave_log(f"libcosim could not instantiate {fmu_path}: {last_error()}", records))
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
            raise LibcosimError(with_slave_log(f"libcosim step {k} (t={k * step_size!r}) failed: "
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
    with import_hygiene(), captured_slave_log() as records:
        try:
            if Path(osp_path).suffix in (".ssd", ".ssp"):
                execution = CosimExecution.CosimExecution.from_ssp_file(
                    str(osp_path), None if step_size is None else int(round(step_size * 1e9)))
            else:
                execution = CosimExecution.CosimExecution.from_osp_config_file(str(osp_path))
        except AssertionError as exc:
            raise LibcosimError(with_slave_log(f"{exc} {osp_path}: {last_error()}", records)) from exc
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
                raise LibcosimError(with_slave_log(f"libcosim step {k} failed: {last_error()}", records),
                                    _cosim_result(times, rows, list(observe)))
            times.append(execution.status().current_time * 1e-9)
            rows.append([_read(observer, slaves[i], indexes[i], [v])[0] for i, v in targets])
        return _cosim_result(times, rows, list(observe))
