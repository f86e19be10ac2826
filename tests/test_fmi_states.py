"""Random FMI call sequences on the three built FMUs, every status checked against the state table.

A seeded generator drives fresh instances of ``RRRDirectKinematics``, ``RRRPlant`` and
``ComputedTorqueController`` through fmpy's ``FMU2Slave`` (:class:`cosim.unit.FMUUnit`, loggingOn)
with calls a careless master makes: setupExperiment, enter/exitInitializationMode, setReal of the
inputs (valid, NaN, huge), a parameter set to a valid or an invalid value, doStep with a positive,
zero and negative step, getReal, get/setFMUstate, terminate, and a new instance.  An oracle
(:data:`fmu_src.fmi_states.ALLOWED`) knows the state after every call and checks:

* the status (checked, not only the log): never fmi2Fatal; every call FMI 2.0 forbids in the state
  returns fmi2Error (the FMU's C loader answers it, ``fmu_src/loader/``), including fmi2Set* of a
  variable not settable in the state; an allowed doStep with a non-finite input or a negative step
  returns fmi2Discard; every other allowed call fmi2OK;
* exactly one message "<call> refused in state <state>" for every forbidden call, none otherwise;
* a forbidden call changes nothing (the oracle's state, then the statuses of the next calls, agree);
  a refused getReal returns fmi2Error (fmpy raises), not values;
* exitInitializationMode with an invalid parameter or start value returns fmi2Error, logs the reason
  and goes to state error (the next doStep is refused there with the reason);
* after every sequence a fresh instance runs a legal initialization and steps without a refusal.
"""
from __future__ import annotations

import math
import random

import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error, fmi2OK

from fmu_src.fmi_states import (ALLOWED, ERROR, INITIALIZATION_MODE, INSTANTIATED, STEP_COMPLETE, STEP_FAILED,
                                TERMINATED)
from cosim.unit import FMUUnit

from host_support import run_python, session_fmus

SEED = 17
SEQUENCES = 70            # per FMU
CALLS = 45                # per sequence
H = 1e-3

#: per FMU: a parameter set to an invalid value (name, FMI type, value), chosen at random
BAD = {
    "RRRDirectKinematics": [("posture", "Integer", 9), ("joint_tolerance", "Real", -1.0), ("mode", "Integer", 5)],
    "RRRPlant": [("posture", "Integer", 9), ("mass_scale", "Real", 0.0), ("substeps", "Integer", 0)],
    "ComputedTorqueController": [("posture", "Integer", 0), ("bandwidth", "Real", -1.0), ("radius", "Real", 0.0)],
}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


class Oracle:
    """The state an FMU instance must be in, and what it must answer (module docstring)."""

    def __init__(self, unit: FMUUnit, name: str, rng: random.Random):
        self.unit, self.name, self.rng = unit, name, rng
        self.inputs = [v for v in unit.md.modelVariables if v.causality == "input"]
        self.outputs = [v.valueReference for v in unit.md.modelVariables
                        if v.causality == "output" and v.type == "Real"]
        self.start = {v.name: v.start for v in unit.md.modelVariables if v.causality in ("input", "parameter")}
        self.fresh()
        self.calls = 0
        self.refusals = 0
        self.forbidden_ok = 0         # forbidden calls answered fmi2OK (the target: none)

    def fresh(self):
        self.state, self.bad_param, self.bad_input = INSTANTIATED, frozenset(), False
        self.saved: list[tuple] = []
        self.t = 0.0

    # ------------------------------------------------------------------ one call
    def call(self, fmi_name: str, fn, *args, expect_discard=False, may_discard=False, expect_error=False,
             allowed=None):
        """Make the call; check the status and the refusal messages; return (status, result, allowed,
        new messages).  ``allowed``: the oracle's verdict when the variables matter (fmi2Set*)."""
        allowed = self.state in ALLOWED[fmi_name] if allowed is None else allowed
        before = len(self.unit.messages)
        result = None
        try:
            result = fn(*args)
            status = fmi2OK
        except FMICallException as exc:
            status = exc.status
        new = self.unit.messages[before:]
        where = f"{self.name}: {fmi_name}{args!r} in state {self.state}"
        assert all(s < 4 for s, _ in new), f"{where}: fatal {new}"
        assert status < 4, f"{where}: status {status}"
        refusals = [m for s, m in new if f"{fmi_name} refused in state {self.state}" in m]
        if not allowed:
            self.forbidden_ok += status == fmi2OK
            assert status == fmi2Error, f"{where}: status {status}"
            assert len(refusals) == 1 and all(s == fmi2Error for s, m in new if m in refusals), f"{where}: {new}"
            self.refusals += 1
        else:
            assert not refusals, f"{where}: {refusals}"
            if expect_error:
                assert status == fmi2Error, f"{where}: status {status} {new}"
            elif expect_discard:
                assert status == fmi2Discard, f"{where}: status {status}"
            elif not may_discard:
                assert status == fmi2OK, f"{where}: status {status} {new}"
        self.calls += 1
        return status, result, allowed, new

    # ------------------------------------------------------------------ the calls a master makes
    def setup_experiment(self):
        self.call("fmi2SetupExperiment", lambda: self.unit.fmu.setupExperiment(startTime=0.0))

    def enter(self):
        _, _, ok, _ = self.call("fmi2EnterInitializationMode", self.unit.fmu.enterInitializationMode)
        if ok:
            self.state = INITIALIZATION_MODE

    def exit(self):
        bad = bool(self.bad_param or self.bad_input)
        status, _, ok, new = self.call("fmi2ExitInitializationMode", self.unit.fmu.exitInitializationMode,
                                       expect_error=bad)
        if not ok:
            return
        failed = [m for s, m in new if s == fmi2Error and "initialization failed" in m]
        if bad:
            assert failed and status == fmi2Error, f"{self.name}: invalid values accepted at exit: {status} {new}"
            self.state = ERROR
        else:
            assert not failed, f"{self.name}: valid values refused: {failed}"
            self.state = STEP_COMPLETE

    def set_inputs(self):
        kind = self.rng.choice(("good", "good", "nan", "huge"))
        values = {"good": lambda v: float(self.start[v.name]), "nan": lambda v: self.rng.choice([math.nan, math.inf]),
                  "huge": lambda v: 1e300}[kind]
        refs, vals = [v.valueReference for v in self.inputs], [values(v) for v in self.inputs]
        _, _, ok, _ = self.call("fmi2SetReal", self.unit.fmu.setReal, refs, vals)
        if ok:
            self.bad_input = kind == "nan"

    def set_parameter(self):
        good = self.rng.random() < 0.5
        name, kind, bad = self.rng.choice(BAD[self.name])
        value = self.start[name] if good else bad
        vr = self.unit.vars[name].valueReference
        fn = self.unit.fmu.setInteger if kind == "Integer" else self.unit.fmu.setReal
        conv = int if kind == "Integer" else float
        # a fixed parameter: settable in instantiated and initializationMode only (FMI 2.0.5 footnotes)
        allowed = self.state in (INSTANTIATED, INITIALIZATION_MODE)
        _, _, ok, new = self.call("fmi2Set" + kind, fn, [vr], [conv(value)], allowed=allowed)
        if ok:
            self.bad_param = self.bad_param - {name} if good else self.bad_param | {name}
        elif self.state == STEP_COMPLETE:   # the call is allowed there, the variable is not: the slave says
            assert any("not settable in this state" in m for _, m in new), f"{self.name}: {name} in {self.state}"

    def step(self):
        dt = self.rng.choice((H, H, H, 0.0, -H))
        expect = self.state == STEP_COMPLETE and (self.bad_input or dt < 0)
        status, _, ok, _ = self.call("fmi2DoStep", self.unit.fmu.doStep, self.t, dt,
                                     expect_discard=expect, may_discard=True)
        if ok:
            if status == fmi2OK:
                self.t += dt
            else:
                self.state = STEP_FAILED

    def get(self):
        status, values, ok, _ = self.call("fmi2GetReal", self.unit.fmu.getReal, self.outputs)
        if not ok:
            assert status == fmi2Error and values is None, f"{self.name}: a refused getReal answered {values}"

    def get_state(self):
        _, handle, _, _ = self.call("fmi2GetFMUstate", self.unit.fmu.getFMUstate)
        self.saved.append((handle, self.state, self.bad_param, self.bad_input, self.t))

    def set_state(self):
        if not self.saved:
            return self.get_state()
        handle, state, bad_param, bad_input, t = self.rng.choice(self.saved)
        self.call("fmi2SetFMUstate", self.unit.fmu.setFMUstate, handle)
        self.state, self.bad_param, self.bad_input, self.t = state, bad_param, bad_input, t

    def terminate(self):
        _, _, ok, _ = self.call("fmi2Terminate", self.unit.fmu.terminate)
        if ok:
            self.state = TERMINATED

    def new_instance(self):
        self.unit.reset()                  # fmi2FreeInstance + fmi2Instantiate (unit.reset: not fmi2Reset)
        self.fresh()

    # ------------------------------------------------------------------ the legal run afterwards
    def legal_run(self, steps: int = 20):
        self.new_instance()
        before = len(self.unit.messages)
        self.unit.initialize(0.0, {})
        self.state = STEP_COMPLETE
        for k in range(steps):
            self.unit.fmu.doStep(k * H, H)
        values = self.unit.fmu.getReal(self.outputs)
        assert all(math.isfinite(v) for v in values)
        errors = [m for s, m in self.unit.messages[before:] if s >= fmi2Discard]
        assert not errors, f"{self.name}: the legal run after a sequence logged {errors}"


ACTIONS = ("setup_experiment", "enter", "exit", "set_inputs", "set_inputs", "set_parameter", "step", "step",
           "step", "get", "get_state", "set_state", "terminate")


@pytest.mark.parametrize("name", ["RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"])
def test_random_call_sequences_keep_the_state_table(fmus, name):
    rng = random.Random(f"{SEED}-{name}")
    unit = FMUUnit(fmus[name], f"seq-{name}", logging_on=True)
    try:
        oracle = Oracle(unit, name, rng)
        for _ in range(SEQUENCES):
            oracle.new_instance()
            for _ in range(CALLS):
                # mostly the legal next call, often any call: the forbidden ones are many
                getattr(oracle, rng.choice(ACTIONS))()
            oracle.legal_run()
        print(f"{name}: {oracle.calls} calls, {oracle.refusals} forbidden, all refused with fmi2Error; "
              f"{oracle.forbidden_ok} forbidden calls answered fmi2OK")
        assert oracle.forbidden_ok == 0
        assert oracle.calls >= SEQUENCES * CALLS and oracle.refusals > SEQUENCES
    finally:
        unit.close()


@pytest.mark.parametrize("name", ["RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"])
def test_invalid_parameter_is_refused_at_initialization_and_the_instance_recovers(fmus, name):
    """The issue's case: an invalid parameter makes fmi2ExitInitializationMode return fmi2Error (fmpy
    raises), with the variable named; a doStep in state error is refused with fmi2Error and the
    reason; the same instance, reset, initializes with valid values."""
    unit = FMUUnit(fmus[name], f"bad-{name}", logging_on=True)
    try:
        for param, _, value in BAD[name]:
            before = len(unit.messages)
            with pytest.raises(FMICallException) as info:
                unit.initialize(0.0, {param: value})
            assert info.value.status == fmi2Error and "fmi2ExitInitializationMode" in str(info.value)
            failed = [m for s, m in unit.messages[before:] if s == fmi2Error and "initialization failed" in m]
            assert failed and param in failed[0] and "state error" in failed[0], (param, unit.messages[before:])
            with pytest.raises(FMICallException) as info:
                unit.fmu.doStep(0.0, H)
            assert info.value.status == fmi2Error
            assert "fmi2DoStep refused in state error" in unit.messages[-1][1] and param in unit.messages[-1][1]
            unit.fmu.reset()
            before = len(unit.messages)
            unit.initialize(0.0, {})
            for k in range(5):
                unit.fmu.doStep(k * H, H)
            assert not [m for s, m in unit.messages[before:] if s >= fmi2Discard]
            unit.reset()
    finally:
        unit.close()


#: fmpy's own driver (simulate_fmu) on an invalid parameter, in a child process (it extracts its own copy)
SIMULATE_BAD = """
    import sys
    from fmpy import simulate_fmu
    try:
        simulate_fmu(sys.argv[1], stop_time=0.01, output_interval=1e-3, start_values={sys.argv[2]: int(sys.argv[3])})
    except Exception as exc:
        print("raised", type(exc).__name__, exc)
    else:
        print("ran")
"""


def test_fmpy_simulate_reports_an_invalid_parameter(fmus):
    """fmpy.simulate_fmu (no custom master) stops at fmi2ExitInitializationMode with fmi2Error."""
    out = run_python(SIMULATE_BAD, fmus["RRRPlant"], "substeps", 0, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "raised FMICallException" in out.stdout and "fmi2ExitInitializationMode" in out.stdout, out.stdout
    assert "substeps" in out.stderr, out.stderr[-2000:]


def test_the_loader_keeps_the_same_state_table():
    """The C loader's table (``fmu_src/loader/fmi2_loader.c``, FMI2_FUNCTIONS) allows each call in the
    states of :data:`fmu_src.fmi_states.ALLOWED`, read from its source."""
    import re
    from pathlib import Path

    loader = Path(__file__).resolve().parents[1] / "fmu_src" / "loader"
    source = (loader / "fmi2_loader.c").read_text()
    header = (loader / "loader_common.h").read_text() + (loader / "fmi2_loader.h").read_text()
    bits = {f"S_{m.group(1)}": m.group(2) for m in re.finditer(r"S_([A-Z_]+) = (\d+)", header)}
    names = {"S_INSTANTIATED": INSTANTIATED, "S_INITIALIZATION_MODE": INITIALIZATION_MODE,
             "S_STEP_COMPLETE": STEP_COMPLETE, "S_STEP_FAILED": STEP_FAILED, "S_TERMINATED": TERMINATED,
             "S_ERROR": ERROR}
    assert set(names) <= set(bits), bits
    groups = {g: set(re.search(rf"#define {g} \(([^)]*)\)", header).group(1).replace(" ", "").split("|"))
              for g in ("S_ANY", "S_GET", "S_SET")}
    table = {m.group(1): m.group(2) for m in re.finditer(r"X\((fmi2\w+), ([^,]+),", source)}
    for call, states in ALLOWED.items():
        if call == "fmi2FreeInstance":
            continue                                  # answered apart (always allowed)
        masks = set(table[call].replace(" ", "").split("|"))
        c_states = {names[b] for m in masks for b in groups.get(m, {m})}
        assert c_states == set(states), (call, c_states, set(states))
