"""FMU infrastructure: fmu_src's runtime and host side, proven on tests/fmu_fixtures/FmuInfraProbe.

The FMU is built once per module into a temporary folder; every test runs it for real (fmpy
FMU2Slave / simulate_fmu, libcosim through libcosimpy) in this process.
"""
from __future__ import annotations

import logging
import math
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error, fmi2LastSuccessfulTime, fmi2Terminated
from fmpy.validation import validate_fmu

from cosim.fmus.checks import smoke_check, validate, value_references
from cosim.hosts.libcosim import LibcosimError, run_libcosim, run_osp_system, write_osp_system_structure
from cosim.fmus.packaging import BuildError, build_fmu
from cosim.simulation import StepRefusedError, input_table, simulate
from fmu_src.table_slave import TableError, TableSlave, Var, check_table
from cosim.unit import FMUUnit

FIXTURE = ROOT / "tests" / "fmu_fixtures" / "FmuInfraProbe.py"
DT = 0.01
K, LEVER, LIMIT = 1.0, 0.5, 1.0
OUT_REAL = ("angle", "force", "elapsed")


def reference(omegas, torques, k=K, lever=LEVER, limit=LIMIT, dt=DT):
    """Outputs after each step, computed here independently of the slave."""
    angle, elapsed, prev, rows = 0.0, 0.0, None, []
    for i, (om, tq) in enumerate(zip(omegas, torques)):
        p = om if prev is None else prev
        angle += k * 0.5 * (p + om) * dt
        prev = om
        elapsed += dt
        rows.append((angle, tq / lever, elapsed, i + 1, abs(angle) > limit))
    return rows


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(autouse=True)
def restore_sys_path():
    """Each FMU instantiation prepends its resources folder to sys.path (pythonfmu's C wrapper)."""
    saved = list(sys.path)
    yield
    sys.path[:] = saved


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    return build_fmu(FIXTURE, tmp_path_factory.mktemp("fmu"))


@pytest.fixture(scope="module")
def md(fmu):
    return read_model_description(str(fmu))


@pytest.fixture(scope="module")
def unzipdir(fmu, tmp_path_factory):
    return extract(str(fmu), unzipdir=str(tmp_path_factory.mktemp("unzipped")))


class Instance(FMUUnit):
    """A minimal custom master on the shared FMU2Slave driver that keeps the FMU's log messages."""

    def __init__(self, fmu, unzipdir, name="inst", **params):
        super().__init__(fmu, name, unzip_dir=unzipdir, logging_on=True)
        self.refs = {v.name: v.valueReference for v in self.md.modelVariables}   # looked up once
        self.initialize(**params)

    def initialize(self, **params):
        super().initialize(0.0, params)
        self.t = 0.0

    def set(self, **values):
        self.set_values(values)

    def step(self, omega, torque):
        self.set(omega=omega, torque=torque)
        self.fmu.doStep(self.t, DT)
        self.t += DT
        return self.outputs()

    def outputs(self):
        reals = self.fmu.getReal([self.refs[n] for n in OUT_REAL])
        return (*reals, self.fmu.getInteger([self.refs["steps"]])[0],
                self.fmu.getBoolean([self.refs["saturated"]])[0])


@pytest.fixture
def make(fmu, unzipdir):
    made = []

    def factory(name="inst", **params):
        made.append(Instance(fmu, unzipdir, name, **params))
        return made[-1]

    yield factory
    for inst in made:
        inst.close()


def inputs(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-2, 2, n).tolist(), rng.uniform(-1, 1, n).tolist()


def bits(rows):
    return np.array([r[:3] for r in rows], dtype=float).tobytes(), [r[3:] for r in rows]


# ---------------------------------------------------------------------- table and build rules
@pytest.mark.parametrize("row, rule", [
    (Var("n", "Integer", "output", "continuous", depends_on=()), "only Real"),
    (Var("y", "Real", "output", unit="m"), "depends_on"),
    (Var("y", "Real", "output", depends_on=("p",)), "inputs"),
    (Var("u", "Real", "input", initial="exact", start=0.0), "initial"),
    (Var("u", "Real", "input"), "start value is required"),
    (Var("y", "Real", "output", start=1.0, depends_on=()), "calculated"),
    (Var("p", "Real", "parameter", "continuous", start=1.0), "not allowed"),
    (Var("b", "Boolean", "parameter", start=1), "True or False"),
    (Var("p", "Real", "parameter", start=math.nan), "finite"),
    (Var("p", "Real", "parameter", start=2.0, max=1.0), "outside"),
])
def test_table_rules(row, rule):
    base = (Var("u", "Real", "input", start=0.0), Var("p", "Real", "parameter", start=1.0))
    with pytest.raises(TableError, match=rule):
        check_table(tuple(v for v in base if v.name != row.name) + (row,))


def test_feedthrough_needs_evaluate():
    with pytest.raises(TableError, match="evaluate"):
        class NoEvaluate(TableSlave):  # noqa: F841
            VARIABLES = (Var("u", "Real", "input", start=0.0), Var("y", "Real", "output", depends_on=("u",)))

            def step(self, t, dt):
                pass


SCRIPT = """
from fmu_src.table_slave import TableSlave, Var

class {cls}(TableSlave):
    VARIABLES = (Var("u", "Real", "input", start=0.0, unit="{unit}"),
                 Var("y", "Real", "output", unit="m", depends_on=()))

    def setup(self):
        {setup}

    def step(self, t, dt):
        self.y += self.u * dt
"""


@pytest.mark.parametrize("module, cls, unit, setup, rule", [
    ("ProbeA", "ProbeB", "m", "pass", "name it 'ProbeA'"),
    ("json", "json", "m", "pass", "standard-library"),
    ("ProbeC", "ProbeC", "furlong", "pass", "not defined"),
    ("ProbeD", "ProbeD", "m", "self.cache = []", "cache"),
])
def test_build_rejects(tmp_path, module, cls, unit, setup, rule):
    script = tmp_path / f"{module}.py"
    script.write_text(textwrap.dedent(SCRIPT.format(cls=cls, unit=unit, setup=setup)))
    with pytest.raises(BuildError, match=rule):
        build_fmu(script, tmp_path / "out")
    assert module not in sys.modules or module == "json"


# ---------------------------------------------------------------------- model description
def test_fmu_validates(fmu):
    assert validate_fmu(str(fmu)) == []
    assert validate(fmu) == []


def probe_class():
    """The fixture module, loaded without registering it in sys.modules."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("FmuInfraProbe", FIXTURE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pythonfmu_alone_does_not_validate(tmp_path):
    """What pythonfmu 0.7 emits for the same slave: no InitialUnknowns, Outputs without dependencies."""
    root = probe_class().FmuInfraProbe(instance_name="raw", resources=str(tmp_path)).to_xml()
    (tmp_path / "modelDescription.xml").write_bytes(ET.tostring(root))
    problems = validate_fmu(str(tmp_path))
    assert any("InitialUnknowns" in p for p in problems)
    assert all("dependencies" not in u.attrib for u in root.find("ModelStructure/Outputs"))
    assert root.find("UnitDefinitions") is None


def test_model_structure_matches_table(fmu, md):
    table = probe_class().FmuInfraProbe._table
    variables = md.modelVariables
    assert [(v.name, v.valueReference, v.causality, v.variability) for v in variables] == \
        [(v.name, i, v.causality, v.variability) for i, v in enumerate(table)]
    declared = {v.name: set(v.depends_on) for v in table if v.causality == "output"}
    assert {u.variable.name: {d.name for d in u.dependencies} for u in md.outputs} == declared
    assert declared["force"] == {"torque"} and declared["angle"] == set()
    assert all(kind == "dependent" for u in md.outputs for kind in u.dependenciesKind)
    # InitialUnknowns: every calculated output, depending on its inputs and (conservatively) the parameters
    params = {v.name for v in table if v.causality == "parameter"}
    assert {u.variable.name: {d.name for d in u.dependencies} for u in md.initialUnknowns} == \
        {name: deps | params for name, deps in declared.items()}
    assert all(v.initial == "calculated" and v.start is None for v in variables if v.causality == "output")
    assert {v.name: v.unit for v in variables if v.type == "Real"} == \
        {v.name: v.unit for v in table if v.type == "Real"}
    assert all(v.variability != "continuous" for v in variables if v.type in ("Integer", "Boolean"))
    assert {v.name: v.variability for v in variables if v.name in ("steps", "saturated")} == \
        {"steps": "discrete", "saturated": "discrete"}
    units = {u.name: u.baseUnit for u in md.unitDefinitions}
    assert (units["N.m"].kg, units["N.m"].m, units["N.m"].s) == (1, 2, -2)
    assert (units["rad/s"].rad, units["rad/s"].s) == (1, -1)
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert value_references(fmu) == {v.name: i for i, v in enumerate(table)}


def test_build_is_deterministic(fmu, tmp_path):
    again = build_fmu(FIXTURE, tmp_path)
    assert again.read_bytes() == fmu.read_bytes()
    with zipfile.ZipFile(fmu) as z:
        infos = z.infolist()
        assert [i.filename for i in infos] == sorted(i.filename for i in infos)
        assert {i.date_time for i in infos} == {(1980, 1, 1, 0, 0, 0)}
        assert b"generationDateAndTime" not in z.read("modelDescription.xml")
        assert not any("__pycache__" in i.filename for i in infos)


# ---------------------------------------------------------------------- running it
def test_simulate_fmu_with_input_table(fmu):
    n = 100
    t = np.arange(n + 1) * DT
    omega, torque = 1.0 + 2.0 * t, 3.0 - t       # linear: fmpy's interpolation is exact on the grid
    table = input_table(t, omega=omega, torque=torque)
    raw = fmpy.simulate_fmu(str(fmu), stop_time=n * DT, output_interval=DT, input=table)
    path = list(sys.path)
    ours = simulate(fmu, stop_time=n * DT, step_size=DT, inputs=table)
    assert sys.path == path                       # the helper undoes the C wrapper's sys.path insert
    ref = np.array([r[:3] for r in reference(omega[:n], torque[:n])])
    flags = [r[3:] for r in reference(omega[:n], torque[:n])]
    for result in (raw, ours):
        assert len(result) == n + 1 and result["time"][-1] == pytest.approx(n * DT)
        assert (result["angle"][0], result["force"][0], result["steps"][0]) == (0.0, torque[0] / LEVER, 0)
        np.testing.assert_allclose(result["angle"][1:], ref[:, 0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(result["force"][1:], ref[:, 1], rtol=1e-12)
        np.testing.assert_allclose(result["elapsed"][1:], ref[:, 2], rtol=1e-12)
        assert [(int(a), bool(b)) for a, b in zip(result["steps"][1:], result["saturated"][1:])] == flags
    assert not ours["saturated"][1] and ours["saturated"][-1]


def test_direct_feedthrough_only_where_declared(make):
    inst = make()
    inst.step(1.0, 1.0)
    angle, force = inst.outputs()[:2]
    inst.set(torque=2.0, omega=5.0)                  # no doStep
    assert inst.outputs()[1] == 2.0 / LEVER != force  # force depends on torque: updated at once
    assert inst.outputs()[0] == angle                 # angle depends on no input: unchanged


def test_fmu_state_round_trip_is_bit_for_bit(make):
    omega, torque = inputs(40)
    inst = make()
    for i in range(10):
        inst.step(omega[i], torque[i])
    state = inst.fmu.getFMUstate()
    first = [inst.step(omega[i], torque[i]) for i in range(10, 40)]
    inst.fmu.setFMUstate(state)
    again = [inst.step(omega[i], torque[i]) for i in range(10, 40)]
    assert bits(again) == bits(first)
    # the serialized state continues identically in another instance
    blob = inst.fmu.serializeFMUstate(state)
    other = make("other")
    restored = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(restored)
    other.t = 10 * DT
    assert bits([other.step(omega[i], torque[i]) for i in range(10, 40)]) == bits(first)
    inst.fmu.freeFMUstate(state)
    other.fmu.freeFMUstate(restored)
    assert bits(first) == bits(reference(omega, torque)[10:])


def test_reset_returns_to_the_initial_state(make):
    omega, torque = inputs(20, seed=1)
    inst = make()
    initial = inst.outputs()
    first = [inst.step(o, q) for o, q in zip(omega, torque)]
    inst.fmu.reset()
    inst.initialize()
    assert inst.outputs() == initial
    assert bits([inst.step(o, q) for o, q in zip(omega, torque)]) == bits(first)


def test_two_instances_in_one_process_are_independent(make):
    (oa, ta), (ob, tb) = inputs(30, seed=2), inputs(30, seed=3)
    a, b = make("a"), make("b", k=3.0)
    rows_a, rows_b = [], []
    for i in range(30):
        rows_a.append(a.step(oa[i], ta[i]))
        rows_b.append(b.step(ob[i], tb[i]))
    assert bits(rows_a) == bits(reference(oa, ta))
    assert bits(rows_b) == bits(reference(ob, tb, k=3.0))


@pytest.mark.parametrize("name, value", [("omega", math.nan), ("torque", math.inf), ("omega", -math.inf)])
def test_non_finite_input_refuses_the_step(make, caplog, name, value):
    omega, torque = inputs(12, seed=4)
    inst = make()
    for i in range(5):
        inst.step(omega[i], torque[i])
    before = inst.outputs()
    state = inst.fmu.getFMUstate()
    bad = dict(omega=omega[5], torque=torque[5]) | {name: value}
    with pytest.raises(FMICallException) as info:
        inst.step(**bad)
    assert info.value.status == fmi2Discard                      # not fmi2Error, never fmi2Fatal
    text = f"'{name}' = {value!r}"
    assert any(s == 3 and text in m and "refused" in m for s, m in inst.messages)  # FMI logger
    assert any(text in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)  # Python logging
    # pythonfmu 0.7: the discard sets the (sticky) terminated flag; the last successful time is t
    assert inst.fmu.getBooleanStatus(fmi2Terminated) is True
    assert inst.fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(inst.t)
    assert inst.outputs()[0] == before[0] and inst.outputs()[2:] == before[2:]
    # the instance is in state stepFailed: FMI 2.0 forbids fmi2SetReal and fmi2DoStep there (refused by
    # the FMU's loader with fmi2Error, logged with the call and the state, nothing changed) ...
    with pytest.raises(FMICallException) as again:
        inst.step(omega[5], torque[5])
    assert again.value.status == fmi2Error
    assert any("fmi2SetReal refused in state stepFailed" in m for _, m in inst.messages)
    with pytest.raises(FMICallException) as again:
        inst.fmu.doStep(inst.t, DT)
    assert again.value.status == fmi2Error
    assert any("fmi2DoStep refused in state stepFailed" in m for _, m in inst.messages)
    assert inst.outputs()[0] == before[0] and inst.outputs()[2:] == before[2:]
    # ... roll back with setFMUstate and continue: as if the bad step never was
    inst.fmu.setFMUstate(state)
    inst.t = 5 * DT
    cont = [inst.step(omega[i], torque[i]) for i in range(5, 12)]
    assert bits(cont) == bits(reference(omega, torque)[5:])
    inst.fmu.freeFMUstate(state)


def test_internal_exception_is_refused_not_fatal(make):
    omega, torque = inputs(10, seed=5)
    inst = make()
    for i in range(4):
        inst.step(omega[i], torque[i])
    before = inst.outputs()
    state = inst.fmu.getFMUstate()
    inst.set(fail_at_step=5)
    with pytest.raises(FMICallException) as info:
        inst.step(omega[4], torque[4])
    assert info.value.status == fmi2Discard   # the step was not made (FMI 2.0); never fmi2Fatal
    logged = [m for s, m in inst.messages if "RuntimeError" in m]
    assert logged and "test failure at step 5 (100% reproducible, not %s)" in logged[-1]
    after = inst.outputs()                    # force follows the new torque (feedthrough); the state
    assert (after[0], *after[2:]) == (before[0], *before[2:])   # was rolled back: angle not corrupted
    inst.fmu.setFMUstate(state)               # stepFailed -> stepComplete (fail_at_step back at -1)
    inst.fmu.freeFMUstate(state)
    inst.t = 4 * DT
    assert bits([inst.step(omega[i], torque[i]) for i in range(4, 10)]) == bits(reference(omega, torque)[4:])


def test_simulate_fmu_with_a_bad_input_table(fmu, caplog):
    t = np.arange(21) * DT
    omega = np.ones_like(t)
    omega[10] = np.nan
    table = input_table(t, omega=omega, torque=np.zeros_like(t))
    # what fmpy does: fmi2Discard + fmi2Terminated is a normal early end -> a truncated result ...
    raw = fmpy.simulate_fmu(str(fmu), stop_time=20 * DT, output_interval=DT, input=table)
    assert raw["time"][-1] == pytest.approx(10 * DT) and len(raw) == 12   # last row repeats t=0.1
    # ... so the slave always also writes to Python logging (stderr unless the host configured logging)
    assert any("'omega' = nan" in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)
    # and the project's helper turns it into an exception
    with pytest.raises(StepRefusedError, match="'omega' = nan") as info:
        simulate(fmu, stop_time=20 * DT, step_size=DT, inputs=table)
    assert info.value.result["time"][-1] == pytest.approx(10 * DT)


def test_libcosim_runs_the_fmu(fmu):
    omega, torque = inputs(25, seed=6)
    result = run_libcosim(fmu, step_size=DT, n_steps=25, inputs={"omega": omega, "torque": torque},
                          start_values={"k": 2.0})
    np.testing.assert_allclose(result.time, (np.arange(25) + 1) * DT, rtol=1e-12)
    ref = reference(omega, torque, k=2.0)
    # libcosim hands the FMU dt = difference of nanosecond time points converted to double, which is
    # not always the double 0.01: agreement to rounding, not bit for bit
    np.testing.assert_allclose(np.column_stack([result["angle"], result["force"], result["elapsed"]]),
                               np.array([r[:3] for r in ref]), rtol=1e-12, atol=1e-15)
    assert list(zip(result["steps"], result["saturated"])) == [r[3:] for r in ref]
    bad = list(omega)
    bad[7] = math.nan
    with pytest.raises(LibcosimError, match="Step not complete") as info:
        run_libcosim(fmu, step_size=DT, n_steps=25, inputs={"omega": bad, "torque": torque})
    assert "'omega' = nan" in str(info.value)
    assert len(info.value.partial.time) == 7


def test_osp_system_structure_runs_in_libcosim(fmu, tmp_path):
    osp = write_osp_system_structure(tmp_path / "OspSystemStructure.xml", {"a": fmu, "b": fmu},
                                     base_step_size=DT, connections=[("a.force", "b.omega")],
                                     initial_values={"a": {"torque": 1.0}, "b": {"k": 0.5}})
    result = run_osp_system(osp, n_steps=10, observe=["a.force", "b.omega", "b.angle", "b.steps"])
    assert np.all(result["a.force"] == 1.0 / LEVER) and np.all(result["b.omega"] == 1.0 / LEVER)
    np.testing.assert_allclose(result["b.angle"], 0.5 * (1.0 / LEVER) * DT * np.arange(1, 11), rtol=1e-12)
    assert list(result["b.steps"]) == list(range(1, 11))


def test_libcosim_stops_at_a_refused_step(fmu):
    """Raw libcosimpy: a refused step fails ex.step() without advancing time.  The FMU is then in
    state stepFailed, where FMI 2.0 forbids fmi2SetReal and fmi2DoStep; libcosim does not roll back
    (no fmi2SetFMUstate), so every later step is refused too, with the state-table message."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    from libcosimpy._internal import get_last_error_message

    log_output_level(CosimLogLevel.FATAL)
    ex = CosimExecution.from_step_size(int(DT * 1e9))
    slave = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="p"))
    observer = CosimObserver.create_last_value()
    manipulator = CosimManipulator.create_override()
    ex.add_observer(observer)
    ex.add_manipulator(manipulator)
    vr = value_references(fmu)
    angles = []
    for k, omega in enumerate([1.0, 1.0, math.nan, 1.0, 1.0]):
        manipulator.slave_real_values(slave, [vr["omega"]], [omega])
        ok = ex.step()
        assert ok == (k < 2)
        if not ok:            # the refused step, then the input set in stepFailed (fmi2Error, FMU's loader)
            message = get_last_error_message()
            assert "Step not complete" in message if k == 2 else \
                ("fmi2SetReal refused in state stepFailed" in message and "(fmi2Error)" in message), message
            assert ex.status().current_time == int(2 * DT * 1e9)
            continue
        angles.append(observer.last_real_values(slave, [vr["angle"]])[0])
    assert angles == pytest.approx([DT, 2 * DT], rel=1e-12)
    assert observer.last_integer_values(slave, [vr["steps"]]) == [2]


def test_smoke_check(fmu, tmp_path):
    assert smoke_check(fmu, inputs={"omega": np.linspace(-1, 1, 20), "torque": 0.5}, start_values={"k": 2.0}) == []
    leaky = build_fmu(FIXTURE.with_name("FmuLeakyState.py"), tmp_path)   # the build cannot see the leak
    problems = smoke_check(leaky)
    assert any("misses part of the internal state" in p for p in problems)
    assert any("'_calls'" in p for p in problems)


SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="pair">
  <ssd:System name="pair">
    <ssd:Elements>
      <ssd:Component name="a" source="{fmu}">
        <ssd:Connectors><ssd:Connector name="force" kind="output"><ssc:Real/></ssd:Connector></ssd:Connectors>
      </ssd:Component>
      <ssd:Component name="b" source="{fmu}">
        <ssd:Connectors><ssd:Connector name="omega" kind="input"><ssc:Real/></ssd:Connector></ssd:Connectors>
      </ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="a" startConnector="force" endElement="b" endConnector="omega"/>
    </ssd:Connections>
  </ssd:System>
</ssd:SystemStructureDescription>
"""


def test_ssp_system_runs_in_libcosim(fmu, tmp_path):
    ssd = tmp_path / "SystemStructure.ssd"
    ssd.write_text(SSD.format(fmu=fmu.resolve().as_posix()))
    result = run_osp_system(ssd, n_steps=5, step_size=DT, observe=["a.force", "b.steps", "b.angle"])
    assert list(result["b.steps"]) == [1, 2, 3, 4, 5]
    np.testing.assert_allclose(result["a.force"], 0.0)   # torque starts at 0
    np.testing.assert_allclose(result["b.angle"], 0.0)


def test_an_fmu_is_stale_when_any_module_it_bundles_changes(tmp_path):
    """``build_fmus`` rebuilds an FMU older than any module it carries (of fmu_src, solver or dynamics)
    or than the build code, and keeps a newer one."""
    import os

    from cosim.fmus.builds import project_packages
    from cosim.fmus.fmu_set import is_stale
    from cosim.fmus.packaging import bundled_files
    from cosim.fmus.sources import SLAVE_DIR, slave_script

    fmu = tmp_path / "RRRPlant.fmu"
    assert is_stale("RRRPlant", fmu)                                     # missing
    fmu.write_bytes(b"")
    packages = {SLAVE_DIR.name: SLAVE_DIR, **{p.name: p for p in project_packages()}}
    sources = list(bundled_files(slave_script("RRRPlant"), packages).values())
    newest = max(p.stat().st_mtime for p in sources)
    os.utime(fmu, (newest + 1e6, newest + 1e6))
    assert not is_stale("RRRPlant", fmu)
    kernel = next(p for p in sources if p.parent.name == "_kernels" and p.parent.parent.name == "dynamics")
    os.utime(fmu, (kernel.stat().st_mtime - 1, kernel.stat().st_mtime - 1))
    assert is_stale("RRRPlant", fmu)                                     # a dynamics kernel is newer
