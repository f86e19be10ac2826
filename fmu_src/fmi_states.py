"""The FMI 2.0 Co-Simulation state machine of a table slave: the mixin :class:`FmiStates`; FMI 3.0's
table of the FMI 3.0 DK FMU where it differs (:data:`ALLOWED3`).

Part of the FMU runtime (bundled into every FMU): it imports the standard library and pythonfmu
only.  One table, :data:`ALLOWED`, says in which states each FMI function that reaches the Python
slave may be called (FMI 2.0.5, section 4.2.4, "Co-Simulation: state machine of the calling
sequence"; the same masks as the Modelica Association's Reference FMUs).  The slaves never return
fmi2Pending, so the states ``stepInProgress`` and ``stepCanceled`` never occur.

States and transitions (``->`` after a successful call)::

    instantiated       --fmi2EnterInitializationMode-->   initializationMode
    initializationMode --fmi2ExitInitializationMode-->    stepComplete, or error (a parameter or
                                                          start value refused, with the reason)
    stepComplete       --fmi2DoStep (fmi2OK)-->           stepComplete
    stepComplete       --fmi2DoStep (fmi2Discard)-->      stepFailed (state kept at the step's start)
    stepComplete, stepFailed --fmi2Terminate-->           terminated
    any                --fmi2SetFMUstate-->               the state the FMU state was taken in
    any                --fmi2Reset-->                     instantiated (pythonfmu: a new Python instance)

What a refused call returns.  FMI 2.0 prescribes fmi2Error for a call its table forbids.
pythonfmu 0.7 alone has no path from Python to fmi2Error: its C wrapper maps a normal return to
fmi2OK, ``do_step`` returning False to fmi2Discard, and *any* Python exception to fmi2Fatal (and
then releases the Python instance).  Every FMU built here on Linux has the project's C loader in
front of that wrapper (``fmu_src/loader/``), and the loader answers for the states:

* it keeps the same table per instance and refuses a forbidden call itself: fmi2Error and one
  log message (status fmi2Error, always sent to the host's logger) naming the call, the state and
  the states that allow it; the call never reaches Python;
* the slave hands its state and the status of the current call over to the loader
  (:meth:`FmiStates._hand_off`: a log message of category :data:`HAND_OFF_CATEGORY`,
  ``"<state> <status>[ <reason>]"``, which the loader consumes and never shows to the host), so a
  call allowed in the state that the slave refuses returns fmi2Error too: fmi2ExitInitializationMode
  with an invalid parameter or start value (the instance goes to state error), fmi2Set* of a
  variable not settable in the state, fmi2Get* of an unknown value reference;
* an allowed ``fmi2DoStep`` that the slave cannot complete (a non-finite or out-of-range input or
  parameter, a negative step, a refused step) returns fmi2Discard (FMI 2.0: the step was not
  carried out, the state is kept at its start, fmi2GetRealStatus(fmi2LastSuccessfulTime) tells
  where; the instance is in stepFailed: fmi2SetFMUstate, fmi2Terminate or fmi2Reset).  A doStep
  the state table forbids (in stepFailed, error, terminated, ...) returns fmi2Error like every
  forbidden call.

Without the loader (an FMU built without a C compiler, in a Python host) the slave refuses a
forbidden call itself, changes nothing and logs the same message; pythonfmu then returns fmi2OK
(fmi2Discard for doStep), and a refused ``fmi2Get*`` answers NaN for each Real
(:data:`REFUSED_STATUS`).

Only an instance made by an FMI host keeps the table strictly: pythonfmu's C wrapper constructs the
slave with a ``logger`` argument.  A slave class constructed directly in Python (unit tests, the
build's own check; no FMI host, so no FMI state table) is lenient: a call the table forbids is
logged as a warning and then carried out as it would be in the state the call expects.

Calls that never reach Python cannot be refused here: fmi2Reset (pythonfmu re-creates the
instance), fmi2FreeInstance, fmi2SetDebugLogging, fmi2FreeFMUstate, fmi2(De)SerializeFMUstate and
the fmi2Get*Status functions (answered by the C wrapper in every state); the loader refuses
fmi2CancelStep (allowed in stepInProgress only, which never occurs).
"""
from __future__ import annotations

import sys
from pathlib import Path

from pythonfmu.enums import Fmi2Status

__all__ = ["FmiStates", "ALLOWED", "STATES", "INSTANTIATED", "INITIALIZATION_MODE", "STEP_COMPLETE",
           "STEP_FAILED", "TERMINATED", "ERROR", "settable", "REFUSED_STATUS", "HAND_OFF_CATEGORY", "behind_loader",
           "ALLOWED3", "STATE_NAMES3"]

INSTANTIATED = "instantiated"
INITIALIZATION_MODE = "initializationMode"
STEP_COMPLETE = "stepComplete"
STEP_FAILED = "stepFailed"
TERMINATED = "terminated"
ERROR = "error"
#: the states a slave can be in (FMI 2.0.5 names)
STATES = (INSTANTIATED, INITIALIZATION_MODE, STEP_COMPLETE, STEP_FAILED, TERMINATED, ERROR)

_ALL = frozenset(STATES)
_GET = frozenset((INITIALIZATION_MODE, STEP_COMPLETE, STEP_FAILED, TERMINATED, ERROR))
_SET = frozenset((INSTANTIATED, INITIALIZATION_MODE, STEP_COMPLETE))

#: FMI function -> the states in which FMI 2.0.5 allows it (Co-Simulation, the functions pythonfmu
#: passes on to Python).  fmi2Set* is further limited per variable, see :func:`settable`.
ALLOWED: dict[str, frozenset] = {
    "fmi2SetupExperiment": frozenset((INSTANTIATED,)),
    "fmi2EnterInitializationMode": frozenset((INSTANTIATED,)),
    "fmi2ExitInitializationMode": frozenset((INITIALIZATION_MODE,)),
    "fmi2DoStep": frozenset((STEP_COMPLETE,)),
    "fmi2Terminate": frozenset((STEP_COMPLETE, STEP_FAILED)),
    "fmi2GetReal": _GET, "fmi2GetInteger": _GET, "fmi2GetBoolean": _GET, "fmi2GetString": _GET,
    "fmi2SetReal": _SET, "fmi2SetInteger": _SET, "fmi2SetBoolean": _SET, "fmi2SetString": _SET,
    "fmi2GetFMUstate": _ALL, "fmi2SetFMUstate": _ALL,
    # not refusable (never reach Python; listed for the documentation and the tests)
    "fmi2Reset": _ALL, "fmi2FreeInstance": _ALL,
}

#: FMI 3.0 Co-Simulation (the FMI 3.0 DK FMU: no Event Mode, no Configuration Mode) in the core's FMI
#: 2.0 states, as its C loader keeps it (``fmu_src/loader/fmi3_loader.c``): where the versions agree,
#: the FMI 2.0 entry itself.  They differ in get (FMI 3.0 reads start values in Instantiated) and in
#: stepFailed, which FMI 3.0 has not: a doStep that returns fmi3Discard leaves the FMU in StepMode
#: (:class:`fmu_src.fmi3_adapter.Fmi3Adapter` moves its core back to stepComplete), so terminate is
#: allowed in StepMode only.  Error is FMI 3.0's Terminated entered by an fmi3Error (a refused
#: initialization), where FMI 3.0 allows what Terminated allows.
ALLOWED3: dict[str, frozenset] = {
    "fmi3EnterInitializationMode": ALLOWED["fmi2EnterInitializationMode"],
    "fmi3ExitInitializationMode": ALLOWED["fmi2ExitInitializationMode"],
    "fmi3DoStep": ALLOWED["fmi2DoStep"],
    "fmi3Terminate": frozenset((STEP_COMPLETE,)),
    **{f"fmi3Get{t}": (_GET - {STEP_FAILED}) | {INSTANTIATED} for t in ("Float64", "Int32", "Boolean")},
    **{f"fmi3Set{t}": ALLOWED["fmi2SetReal"] for t in ("Float64", "Int32", "Boolean")},
    "fmi3GetFMUState": _ALL - {STEP_FAILED}, "fmi3SetFMUState": _ALL - {STEP_FAILED},
    "fmi3Reset": _ALL - {STEP_FAILED}, "fmi3FreeInstance": _ALL - {STEP_FAILED},
}
#: the FMI 3.0 name of each state of :data:`ALLOWED3` (the C loader's messages)
STATE_NAMES3 = {INSTANTIATED: "Instantiated", INITIALIZATION_MODE: "InitializationMode", STEP_COMPLETE: "StepMode",
                TERMINATED: "Terminated", ERROR: "Terminated after an fmi3Error"}

#: the log category of the slave's hand-off to the C loader (the loader's ``STATUS_CATEGORY``)
HAND_OFF_CATEGORY = "rrrdkCallStatus"
#: the Python wrapper beside the loader, by platform folder: pythonfmu's in an FMI 2.0 FMU, pythonfmu3's
#: in the FMI 3.0 one (:data:`cosim.fmus.native.WRAPPER_NAME`, :data:`cosim.fmus.native.WRAPPER3_NAME`)
_WRAPPERS = (("linux64", "libpythonfmu-export.so"), ("x86_64-linux", "libpythonfmu3-export.so"))

#: what pythonfmu 0.7 returns for a refused call without the loader (FMI prescribes fmi2Error; the
#: loader returns it)
REFUSED_STATUS = {name: (Fmi2Status.discard if name == "fmi2DoStep" else Fmi2Status.ok) for name in ALLOWED}


def behind_loader(resources) -> bool:
    """Whether an instance whose FMU's ``resources`` folder is ``resources`` runs behind the project's C
    loader: on Linux, when pythonfmu's wrapper sits in ``binaries/linux64/`` beside the loader, or
    pythonfmu3's in ``binaries/x86_64-linux/`` (the FMI 3.0 FMU); the builds put them there only with
    the loader (:mod:`cosim.fmus.native`)."""
    if not resources or not sys.platform.startswith("linux"):
        return False
    binaries = Path(resources).parent / "binaries"
    return any((binaries / platform / wrapper).is_file() for platform, wrapper in _WRAPPERS)


def settable(var, state: str) -> bool:
    """Whether FMI 2.0.5 allows fmi2Set* of ``var`` (a checked :class:`fmu_src.variables.Var`) in ``state``.

    Footnotes of the state table: in ``instantiated`` a variable with ``initial`` exact or approx;
    in ``initializationMode`` one with ``initial`` exact, or an input; in ``stepComplete`` an input
    or a tunable parameter; never a constant, and never in the other states.
    """
    if var.variability == "constant":
        return False
    if state == INSTANTIATED:
        # an input has no ``initial`` in FMI 2.0 but a required start value that the master may
        # overwrite before initialization (fmpy's simulate_fmu does): read as ``approx``
        return var.initial in ("exact", "approx") or var.causality == "input"
    if state == INITIALIZATION_MODE:
        return var.initial == "exact" or var.causality == "input"
    if state == STEP_COMPLETE:
        return var.causality == "input" or (var.causality == "parameter" and var.variability == "tunable")
    return False


class FmiStates:
    """The state machine of :class:`fmu_src.table_slave.TableSlave` (a mixin; module docstring).

    Instance attributes: ``_fmi_state`` (one of :data:`STATES`, part of the FMU state and of the
    rollback bookkeeping) and the flags derived from it by :meth:`_enter_state`: ``_init_mode``,
    ``_initialized``, ``_can_get``, ``_can_step``, ``_settable_now`` ({FMI type: the value
    references that fmi2Set<type> may set now}) and ``_settable_real`` (its Real entry).  Class
    attribute ``_settable`` ({state: {FMI type: frozenset of value references}}) is built from the
    table by :meth:`_build_settable`.
    """

    _settable: dict = {}
    _loader = False          # behind the C loader: hand the state and the call's status over to it
    _NONE = {"Real": frozenset(), "Integer": frozenset(), "Boolean": frozenset(), "String": frozenset()}

    @classmethod
    def _build_settable(cls, table) -> None:
        cls._settable = {s: {kind: frozenset(i for i, v in enumerate(table) if v.type == kind and settable(v, s))
                             for kind in ("Real", "Integer", "Boolean", "String")} for s in STATES}

    def _enter_state(self, state: str) -> None:
        """Move to ``state`` and update the flags the per-call checks read."""
        self._fmi_state = state
        self._init_mode = state == INITIALIZATION_MODE
        self._initialized = state in (STEP_COMPLETE, STEP_FAILED, TERMINATED)
        self._can_get = state in _GET
        self._can_step = state == STEP_COMPLETE
        self._settable_now = self._settable.get(state, self._NONE)
        self._settable_real = self._settable_now["Real"]
        if self._loader:
            self._hand_off()

    def _hand_off(self, status: Fmi2Status = Fmi2Status.ok) -> None:
        """Tell the C loader the state and the least status of the current call (module docstring);
        in state error with the reason, which the loader repeats when it refuses a later call."""
        if not self._loader:
            return
        reason = f" {self._init_error}" if self._fmi_state == ERROR and self._init_error else ""
        self.log(f"{self._fmi_state} {int(status)}{reason}".replace("%", "%%"), Fmi2Status.ok,
                 category=HAND_OFF_CATEGORY)

    def _returned(self, status: Fmi2Status) -> str:
        """What the host gets for a refusal: fmi2Error through the loader, else pythonfmu's ``status``."""
        if self._loader:
            return "fmi2Error"
        name = "fmi2Discard" if status == Fmi2Status.discard else "fmi2OK"
        return f"fmi2Error by the standard; pythonfmu 0.7 returns {name}"

    def _allowed(self, call: str) -> bool:
        """True if ``call`` is allowed in the current state (or the instance is lenient, module
        docstring); otherwise log the refusal, return False."""
        if self._fmi_state in ALLOWED[call]:
            return True
        if not self._fmi_strict:
            self._report(f"{type(self).__name__} instance {self.instance_name!r}: {call} in state {self._fmi_state} "
                         "(FMI 2.0 forbids it; carried out: an in-process instance, not made by an FMI host)",
                         Fmi2Status.warning)
            return True
        self._refuse_call(call)
        return False

    def _refuse_call(self, call: str, detail: str = "") -> None:
        """Log the refusal of ``call`` in the current state (the caller changes nothing)."""
        allowed = ", ".join(s for s in STATES if s in ALLOWED[call]) or "no state"
        why = f" ({self._init_error})" if self._fmi_state == ERROR and self._init_error else ""
        msg = (f"{type(self).__name__} instance {self.instance_name!r}: {call} refused in state "
               f"{self._fmi_state}{why}{detail}: FMI 2.0 allows it in {allowed} only; nothing changed "
               f"({self._returned(REFUSED_STATUS[call])})")
        self.refused_calls += 1
        self.last_call_refusal = msg
        self._report(msg, Fmi2Status.error)
        self._hand_off(Fmi2Status.error)

    def _set_refused(self, kind: str, vrs) -> bool:
        """fmi2Set<kind> of ``vrs``: True (and logged) if the call must be refused as a whole."""
        ok = self._settable_now[kind]
        if ok.issuperset(vrs):
            return False
        call = "fmi2Set" + kind
        known = self._table
        bad = [vr for vr in vrs if vr not in ok]
        names = [f"{known[vr].name!r}" if isinstance(vr, int) and 0 <= vr < len(known) else f"unknown #{vr}"
                 for vr in bad]
        if not self._fmi_strict and set(vrs) <= set(self._attrs.get(kind, ())):
            return not self._allowed(call)       # lenient (in process): logged, carried out
        if self._fmi_state not in ALLOWED[call]:
            self._refuse_call(call)
        else:
            self._refuse_call(call, f", variable(s) {', '.join(names)} not settable in this state "
                                    f"(FMI 2.0.5 state table footnotes), or not of type {kind}")
        return True
