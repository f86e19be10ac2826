"""Checks of a built FMU (host side): :func:`validate` (static) and :func:`smoke_check` (run it).

:func:`validate` is fmpy's ``validate_fmu`` plus this project's rules (explicit output
dependencies, units on every Real interface variable, the pythonfmu layout, no compiled Python).
:func:`smoke_check` runs the FMU through the shared driver (:class:`cosim.unit.FMUUnit`) and
lists what a master would trip over: refused steps, non-finite outputs, an FMU state that misses
part of the internal state, fmi2Reset that does not return to the start, logged warnings.
"""
from __future__ import annotations

import contextlib
import math
import os
import zipfile
from typing import Any, Mapping, Sequence

import numpy as np

from ..unit import FMUUnit, import_hygiene

__all__ = ["validate", "value_references", "smoke_check"]


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


class _RunError(RuntimeError):
    pass


class _Run:
    """The input schedule of :func:`smoke_check` applied to :class:`FMUUnit` instances."""

    def __init__(self, fmu_path, inputs, start_values, n_steps, step_size):
        self.fmu_path, self.h = fmu_path, step_size
        self.units: list[FMUUnit] = []
        self.inputs = {n: np.broadcast_to(np.asarray(v), (n_steps,)) for n, v in inputs.items()}
        self.start_values = dict(start_values)

    def instance(self, name) -> FMUUnit:
        unit = FMUUnit(self.fmu_path, name, logging_on=True)
        self.units.append(unit)
        unknown = [n for n in [*self.inputs, *self.start_values] if n not in unit.vars]
        if unknown:
            raise _RunError(f"unknown variables {unknown}")
        self.output_names = [v.name for v in unit.md.modelVariables if v.causality == "output"]
        self.initialize(unit)
        return unit

    def initialize(self, unit: FMUUnit):
        unit.initialize(0.0, {**self.start_values, **{n: v[0] for n, v in self.inputs.items()}})

    def run(self, unit: FMUUnit, k0, k1):
        from fmpy.fmi1 import FMICallException

        rows = []
        for k in range(k0, k1):
            unit.set_values({name: values[k] for name, values in self.inputs.items()})
            try:
                unit.fmu.doStep(k * self.h, self.h)
            except FMICallException as exc:
                log = "; ".join(m for _, m in unit.messages[-3:])
                raise _RunError(f"{unit.name}: doStep at t={k * self.h!r} returned status {exc.status}: {log}")
            rows.append(tuple(unit.get_values(self.output_names)))
        return rows


def smoke_check(fmu_path: str | os.PathLike, *, n_steps: int = 20, step_size: float = 1e-3,
                inputs: Mapping[str, Sequence[float] | float] | None = None,
                start_values: Mapping[str, Any] | None = None) -> list[str]:
    """Run an FMU through fmpy's FMU2Slave and list what is wrong (empty list: nothing).

    Checks that ``n_steps`` steps succeed with finite outputs; that getFMUstate/setFMUstate in the
    middle of the run and serialize/deserialize into a second instance reproduce the outputs bit for
    bit (a state not fully covered shows here); that fmi2Reset reproduces the first run; and that
    the FMU logged no warning or error.  ``inputs``: name -> constant or ``n_steps`` values.
    """
    problems: list[str] = []
    run = _Run(fmu_path, inputs or {}, start_values or {}, n_steps, step_size)
    with import_hygiene():
        try:
            a = run.instance("smoke-a")
            try:
                first = run.run(a, 0, n_steps)
            except _RunError as exc:
                return [str(exc)]
            bad = [name for name, value in zip(run.output_names, first[-1] if first else ())
                   if isinstance(value, float) and not math.isfinite(value)]
            if bad:
                problems.append(f"non-finite outputs after {n_steps} steps: {bad}")
            try:
                problems += _state_and_reset(run, a, first, n_steps)
            except _RunError as exc:
                problems.append(str(exc))
            for unit in run.units:
                problems += [f"{unit.name} logged: {m}" for status, m in unit.messages if status >= 1]
            return problems
        finally:
            for unit in run.units:
                with contextlib.suppress(Exception):
                    unit.close()


def _state_and_reset(run: _Run, a: FMUUnit, first: list, n_steps: int) -> list[str]:
    """The FMU-state and fmi2Reset part of :func:`smoke_check`."""
    problems = []
    b = run.instance("smoke-b")
    half = n_steps // 2
    run.run(b, 0, half)
    state = b.fmu.getFMUstate()
    blob = b.fmu.serializeFMUstate(state) if b.md.coSimulation.canSerializeFMUstate else None
    rest = run.run(b, half, n_steps)
    b.fmu.setFMUstate(state)
    b.fmu.freeFMUstate(state)
    if run.run(b, half, n_steps) != rest:
        problems.append("getFMUstate/setFMUstate does not reproduce the outputs: the FMU state "
                        "misses part of the internal state")
    if blob is not None:
        c = run.instance("smoke-c")
        restored = c.fmu.deSerializeFMUstate(blob)
        c.fmu.setFMUstate(restored)
        c.fmu.freeFMUstate(restored)
        if run.run(c, half, n_steps) != rest:
            problems.append("a deserialized FMU state does not reproduce the outputs in another instance")
    a.fmu.reset()
    run.initialize(a)
    if run.run(a, 0, n_steps) != first:
        problems.append("fmi2Reset does not return to the initial state")
    return problems
