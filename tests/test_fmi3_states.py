"""Random FMI 3.0 call sequences on the FMI 3.0 DK FMU, every status checked against the state table.

The FMI 3.0 sibling of tests/test_fmi_states.py: a seeded generator drives fresh instances of
``RRRDirectKinematics3`` through fmpy's ``FMU3Slave`` (loggingOn) with calls a careless importer
makes: enter/exitInitializationMode, fmi3SetFloat64 of q (valid, NaN, huge), a fixed parameter set to
a valid or an invalid value, doStep with a positive, zero and negative step, fmi3GetFloat64 and
fmi3GetInt32 of outputs, a get of an unknown value reference, get/setFMUState, terminate, fmi3Reset,
fmi3EnterEventMode (a feature the FMU lacks) and a new instance.  An oracle
(:data:`fmu_src.fmi_states.ALLOWED3`, the table of the FMU's C loader ``fmu_src/loader/fmi3_loader.c``)
knows the state after every call and checks:

* never fmi3Fatal, never a crash; every call FMI 3.0 forbids in the state returns fmi3Error with
  exactly one message "<call> refused in state <state>" (status fmi3Error), and changes nothing;
* a call allowed in the state that the slave refuses returns fmi3Error: a fixed parameter set in
  StepMode, a get of an unknown value reference, exitInitializationMode with an invalid parameter or
  start value (the instance then is in Terminated after an fmi3Error, with the reason);
* an allowed doStep with a NaN input or a negative step returns fmi3Discard, the time and the outputs
  kept, and the instance stays in StepMode (FMI 3.0: the state before the call);
* every other allowed call fmi3OK; after every sequence a fresh instance initializes and steps without
  a refusal.
"""
from __future__ import annotations

import math
import random
import re
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave

from fmu_src.fmi_states import (ALLOWED3, ERROR, INITIALIZATION_MODE, INSTANTIATED, STATE_NAMES3, STEP_COMPLETE,
                                TERMINATED)

SEED = 17
SEQUENCES = 100
CALLS = 45
H = 1e-3
OK, DISCARD, ERR = 0, 2, 3
#: fixed parameters set to an invalid value (name, kind, value)
BAD = [("posture", "Int32", 9), ("joint_tolerance", "Float64", -1.0), ("mode", "Int32", 5)]


@pytest.fixture(scope="module")
def dk3(tmp_path_factory):
    from cosim.fmus import fmi3_build, references

    tmp = tmp_path_factory.mktemp("fmi3_states")
    built = fmi3_build.build_dk3(tmp / "fmu3", postures=(1,), resolution=references.REFERENCE["resolution"],
                                 cache_dir=tmp / "maps", log=lambda m: None, check=False)
    return read_model_description(str(built.fmu)), extract(str(built.fmu), unzipdir=str(tmp / "unzipped"))


class Oracle3:
    """The state an FMI 3.0 instance must be in, and what it must answer (module docstring)."""

    def __init__(self, md, folder, rng: random.Random):
        self.md, self.folder, self.rng = md, folder, rng
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.start = {v.name: v.start for v in md.modelVariables}
        self.q0 = [float(x) for x in self.start["q"].split()]
        self.messages: list[tuple[int, str]] = []
        self.fmu = None
        self.calls = self.forbidden = self.refused = self.discards = 0
        self.forbidden_ok = self.refused_ok = 0           # the target: none

    def _log(self, env, status, category, message):
        self.messages.append((int(status), message.decode() if message else ""))

    def fresh(self):
        self.state, self.bad_param, self.bad_input, self.t, self.saved = INSTANTIATED, frozenset(), False, 0.0, []

    def new_instance(self):
        if self.fmu is not None:
            self.fmu.freeInstance()
        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=self.folder, modelIdentifier="RRRDirectKinematics3",
                             instanceName=f"seq{self.calls}")
        self.fmu.instantiate(loggingOn=True, logMessage=self._log)
        self.fresh()

    # ------------------------------------------------------------------ one call
    def call(self, name, fn, *args, expect=OK, may_discard=False):
        """Make the call; check status and messages against the table; return (status, result, allowed, new)."""
        allowed = self.state in ALLOWED3.get(name, frozenset())
        before = len(self.messages)
        result = None
        try:
            result, status = fn(*args), OK
        except FMICallException as exc:
            status = exc.status
        new = self.messages[before:]
        where = f"{name}{args!r} in state {STATE_NAMES3[self.state]}"
        assert status < 4 and all(s < 4 for s, _ in new), f"{where}: fatal {status} {new}"
        refusals = [m for s, m in new if f"{name} refused in state {STATE_NAMES3[self.state]}" in m]
        self.calls += 1
        if not allowed:
            self.forbidden += 1
            self.forbidden_ok += status == OK
            assert status == ERR and len(refusals) == 1 and len(new) == 1 and new[0][0] == ERR, f"{where}: {status} {new}"
        else:
            assert expect == ERR or not refusals, f"{where}: {refusals}"
            if expect == ERR:
                self.refused += 1
                self.refused_ok += status == OK
            self.discards += status == DISCARD
            ok = status == expect or (may_discard and status == DISCARD)
            assert ok, f"{where}: status {status}, expected {expect} {new}"
        return status, result, allowed, new

    # ------------------------------------------------------------------ the calls an importer makes
    def enter(self):
        if self.call("fmi3EnterInitializationMode", self.fmu.enterInitializationMode)[2]:
            self.state = INITIALIZATION_MODE

    def exit(self):
        bad = bool(self.bad_param or self.bad_input)
        status, _, ok, new = self.call("fmi3ExitInitializationMode", self.fmu.exitInitializationMode,
                                       expect=ERR if bad else OK)
        if ok:
            failed = [m for s, m in new if s == ERR and "initialization failed" in m]
            assert bool(failed) == bad, f"exit with bad={bad}: {new}"
            self.state = ERROR if bad else STEP_COMPLETE

    def set_q(self):
        kind = self.rng.choice(("good", "good", "nan", "huge"))
        value = {"good": self.q0, "nan": [self.q0[0], math.nan, self.q0[2]], "huge": [1e300] * 3}[kind]
        if self.call("fmi3SetFloat64", self.fmu.setFloat64, [self.vr["q"]], value)[2]:
            self.bad_input = kind == "nan"

    def set_parameter(self):
        good = self.rng.random() < 0.5
        name, kind, bad = self.rng.choice(BAD)
        value = (int if kind == "Int32" else float)(self.start[name] if good else bad)
        # a fixed parameter: the call is allowed in StepMode, the variable is not settable there
        refused = self.state == STEP_COMPLETE
        _, _, ok, new = self.call("fmi3Set" + kind, getattr(self.fmu, "set" + kind), [self.vr[name]], [value],
                                  expect=ERR if refused else OK)
        if ok and refused:
            assert any("not settable in this state" in m for _, m in new), new
        elif ok:
            self.bad_param = self.bad_param - {name} if good else self.bad_param | {name}

    def step(self):
        dt = self.rng.choice((H, H, H, 0.0, -H))
        discard = self.state == STEP_COMPLETE and (self.bad_input or dt < 0)
        before = self.fmu.getFloat64([self.vr["pose"]], nValues=3) if self.state == STEP_COMPLETE else None
        status, _, ok, _ = self.call("fmi3DoStep", self.fmu.doStep, self.t, dt, expect=DISCARD if discard else OK,
                                     may_discard=True)
        if ok and status == OK:
            self.t += dt
        elif ok:                                        # discarded: StepMode, time and outputs kept
            after = self.fmu.getFloat64([self.vr["pose"]], nValues=3)
            assert after == before or any(map(math.isnan, before)), (before, after)

    def get(self):
        self.call("fmi3GetFloat64", self.fmu.getFloat64, [self.vr["pose"], self.vr["cond"]], 4)
        self.call("fmi3GetInt32", self.fmu.getInt32, [self.vr["status"]])

    def get_unknown(self):
        self.call("fmi3GetFloat64", self.fmu.getFloat64, [999], 1, expect=ERR)

    def get_state(self):
        _, handle, _, _ = self.call("fmi3GetFMUState", self.fmu.getFMUState)
        self.saved.append((handle, self.state, self.bad_param, self.bad_input, self.t))

    def set_state(self):
        if not self.saved:
            return self.get_state()
        handle, state, bad_param, bad_input, t = self.rng.choice(self.saved)
        self.call("fmi3SetFMUState", self.fmu.setFMUState, handle)
        self.state, self.bad_param, self.bad_input, self.t = state, bad_param, bad_input, t

    def terminate(self):
        if self.call("fmi3Terminate", self.fmu.terminate)[2]:
            self.state = TERMINATED

    def reset(self):
        self.call("fmi3Reset", self.fmu.reset)
        self.fresh()

    def event_mode(self):
        self.call("fmi3EnterEventMode", self.fmu.enterEventMode)      # no Event Mode: forbidden everywhere

    def legal_run(self, steps: int = 20):
        self.new_instance()
        before = len(self.messages)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        for k in range(steps):
            self.fmu.doStep(k * H, H)
        assert all(map(math.isfinite, self.fmu.getFloat64([self.vr["pose"]], nValues=3)))
        assert not [m for s, m in self.messages[before:] if s >= DISCARD], self.messages[before:]


ACTIONS = ("enter", "exit", "set_q", "set_q", "set_parameter", "step", "step", "step", "get", "get_unknown",
           "get_state", "set_state", "terminate", "reset", "event_mode")


def test_random_fmi3_call_sequences_keep_the_state_table(dk3):
    md, folder = dk3
    rng = random.Random(f"{SEED}-RRRDirectKinematics3")
    oracle = Oracle3(md, folder, rng)
    try:
        for _ in range(SEQUENCES):
            oracle.new_instance()
            for _ in range(CALLS):
                getattr(oracle, rng.choice(ACTIONS))()
            oracle.legal_run()
    finally:
        if oracle.fmu is not None:
            oracle.fmu.freeInstance()
    print(f"RRRDirectKinematics3: {oracle.calls} calls, {oracle.forbidden} forbidden (all fmi3Error), "
          f"{oracle.refused} refused by the slave (all fmi3Error), {oracle.discards} discarded steps; "
          f"{oracle.forbidden_ok} forbidden and {oracle.refused_ok} refused calls answered fmi3OK")
    assert oracle.forbidden_ok == 0 and oracle.refused_ok == 0
    assert oracle.calls >= SEQUENCES * CALLS and oracle.forbidden > SEQUENCES and oracle.refused > SEQUENCES
    assert oracle.discards > 0


def test_refused_and_forbidden_calls_return_fmi3_error(dk3):
    """The FMI 3.0 loader: a set the slave refuses (a fixed parameter in StepMode), a get of an unknown
    value reference, a call FMI 3.0 forbids in the state, a function of a feature the FMU lacks: fmi3Error,
    one message naming the call, nothing changed; a get in Instantiated reads the start values."""
    md3, dir3 = dk3
    fmu = FMU3Slave(guid=md3.guid, unzipDirectory=dir3, modelIdentifier="RRRDirectKinematics3", instanceName="calls")
    messages = []
    fmu.instantiate(loggingOn=False, logMessage=lambda env, s, c, m: messages.append((int(s), m.decode())))
    vr = {v.name: v.valueReference for v in md3.modelVariables}
    start = {v.name: v.start for v in md3.modelVariables}
    assert fmu.getFloat64([vr["q"]], nValues=3) == [float(x) for x in start["q"].split()]
    assert fmu.getInt32([vr["posture"]]) == [int(start["posture"])]

    def refused(fn, *args, text):
        before = len(messages)
        with pytest.raises(FMICallException) as info:
            fn(*args)
        new = messages[before:]
        assert info.value.status == 3 and len(new) == 1 and new[0][0] == 3 and text in new[0][1], (text, new)

    refused(fmu.doStep, 0.0, H, text="fmi3DoStep refused in state Instantiated: FMI 3.0 allows it in StepMode only")
    refused(fmu.terminate, text="fmi3Terminate refused in state Instantiated")
    refused(fmu.exitInitializationMode, text="fmi3ExitInitializationMode refused in state Instantiated")
    refused(fmu.enterEventMode, text="fmi3EnterEventMode refused in state Instantiated: this FMU has no Event Mode")
    refused(fmu.getFloat32, [0], 1, text="fmi3GetFloat32: this FMU has no Float32 variable")
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    refused(fmu.setFloat64, [vr["pose0"]], [0.5, 0.3, 0.0],
            text="fmi3SetFloat64 refused in state StepMode: variable(s) 'pose0' not settable in this state (FMI 3.0 "
                 "sets in StepMode the inputs and the tunable parameters); nothing changed (fmi3Error)")
    refused(fmu.getFloat64, [999], 1, text="[999] are not all Float64 variables")
    refused(fmu.enterInitializationMode, text="fmi3EnterInitializationMode refused in state StepMode")
    fmu.doStep(0.0, H)                                    # nothing changed: the instance steps on
    fmu.terminate()
    refused(fmu.doStep, H, H, text="fmi3DoStep refused in state Terminated:")
    assert all(map(math.isfinite, fmu.getFloat64([vr["pose"]], nValues=3)))
    fmu.freeInstance()


def test_the_fmi3_loader_keeps_the_same_state_table():
    """The C loader's FMI 3.0 table (fmi3_loader.c, FMI3_PLAIN/FMI3_STEP; masks of loader_common.h and
    fmi3_loader.h) allows each call in the states of :data:`fmu_src.fmi_states.ALLOWED3`."""
    loader = Path(__file__).resolve().parents[1] / "fmu_src" / "loader"
    source = (loader / "fmi3_loader.c").read_text()
    header = (loader / "loader_common.h").read_text() + (loader / "fmi3_loader.h").read_text()
    bits = {f"S_{m.group(1)}": int(m.group(2)) for m in re.finditer(r"S_([A-Z_]+) = (\d+)", header)}
    names = {bits["S_INSTANTIATED"]: INSTANTIATED, bits["S_INITIALIZATION_MODE"]: INITIALIZATION_MODE,
             bits["S_STEP_COMPLETE"]: STEP_COMPLETE, bits["S_TERMINATED"]: TERMINATED, bits["S_ERROR"]: ERROR}
    groups = {m.group(1): m.group(2) for m in re.finditer(r"#define (S3?_[A-Z_]+) \(?([^)\n]*)\)?", header)}

    def states(expr: str) -> set:
        out = set()
        for part in expr.replace(" ", "").split("|"):
            out |= states(groups[part]) if part in groups else {names[bits[part]]} if bits.get(part) in names else set()
        return out

    table = {m.group(1): m.group(2) for m in re.finditer(r"X\((fmi3\w+), ([^,]+),", source)}
    for call, allowed in ALLOWED3.items():
        if call == "fmi3FreeInstance":
            continue                                  # answered apart (always allowed)
        assert states(table[call]) == set(allowed), (call, states(table[call]), set(allowed))
