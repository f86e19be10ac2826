"""The fmpy master of the paper's Figs 2 and 3: :class:`ClosedLoop` and :func:`simulate_fig3`.

The master knows the FMUs only through fmpy's ``FMU2Slave`` (driven by :class:`cosim.unit.FMUUnit`).
Value references are looked up by name once; time is ``t0 + k h``, never accumulated.

Closed loop (Fig. 2), :meth:`ClosedLoop.run`
--------------------------------------------
Initialization, in the FMI phases' order: instantiate, setupExperiment(t0), enterInitializationMode,
parameters and the inputs at ``t0`` (:func:`cosim.loop.wiring.start_values`: the plant starts at
rest at the circle's first point; the DK FMU gets that pose as ``x0, y0, phi0`` and the plant's
initial joints as inputs; the controller the plant's initial outputs), exitInitializationMode.

Each macro step ``[t_k, t_k + h)``, ``order="gauss-seidel"`` (the default)::

    q, dq, X_true   <- plant outputs at t_k                       (sensors)
    DK:         set q;            doStep(t_k, h);  X <- pose of q (t_k)
    controller: set q, dq, X;     doStep(t_k, h);  tau <- tau(t_k), held over the step
    plant:      set tau;          doStep(t_k, h);  state at t_k + h

Every link carries the value at ``t_k``: no delay beyond the controller's zero-order hold.
Per step and instance the master makes one fmi2SetReal (all its connected inputs), one fmi2DoStep
and one fmi2GetReal (every Real output the loop or the result needs), with value references and
value buffers made once: 9 FMI calls a step, 11 when the DK's Integer and Boolean outputs are
recorded too (``run(..., flags=True)``, the default; the CSV has them).  Inputs that are one run
of one instance's output buffer are passed as a view of it (the DK's q, the plant's tau), the
controller's are copied from two; each step's output buffers are kept as rows and the result's
columns are built once at the end (:data:`SAMPLE_ROW`).
``order="jacobi"``: all inputs are set from the outputs available at ``t_k`` before any doStep,
so the DK pose and the torque each lag one step (the controller sees the pose of ``q_{k-1}``, the
plant gets ``tau_{k-1}``).
``order="omsimulator"``: OMSimulator's fixed-step master (``oms-ma``): the inputs are set along the
connections in the data-flow order, each direct-feedthrough output read after its inputs are set,
and then all instances step; so the controller sees the pose of ``q_k`` (the DK answers its
fmi2GetReal for the new joints) but the plant gets ``tau_{k-1}`` (the controller's held torque).
Which input comes from which output is :data:`~cosim.loop.wiring.CONNECTIONS`, nothing else.
The ModelStructure of each FMU declares which outputs depend on which inputs (the DK pose on
q1..q3; the plant's outputs on no input; the controller's held torque on no input at the
communication point), so a master that sorts the graph finds no algebraic loop.

Dynamics simulation (Fig. 3), :func:`simulate_fig3`
--------------------------------------------------
The joint-space dynamics ``ddq = M^-1 (tau - C dq - G - F)`` (eq. 7) integrated by classic RK4
(:func:`dynamics.rk4_step`) in the master; at every Runge-Kutta stage the DK FMU turns the stage's
joints into the pose that ``M, C, G`` need.  A stage must not advance the tracker: the master saves
the FMU state at the step's start (``getFMUstate``), evaluates each stage from it (``setFMUstate``,
set q, ``doStep`` over the stage's time offset), and finally commits the step's end joints from the
same saved state.
"""
from __future__ import annotations

import ctypes
import functools
import time

import numpy as np

from dynamics import forward_dynamics, rk4_step
from cosim.fmus.robot_build import fmu_robot
from cosim.unit import FMUUnit
from solver import Manipulator

from .calls import WORST_ACCEPTED as WORST, check, hot_call, step_sequence
from .results import COLUMN_SOURCES, FLAG_COLUMNS, ClosedLoopResult
from .scenario import Scenario, robot_scenario
from .wiring import INSTANCES, copy_plan, inputs_of, outputs_of, sources_of, start_values

__all__ = ["ClosedLoop", "Port", "SAMPLE_ROW", "simulate_fig3"]


#: Row of an instance's reads that holds its value at ``t_k``: reads after step ``k`` are row ``k + 1``
#: (row 0: the reads at initialization).  The DK's pose of ``q(t_k)`` and the controller's torque held
#: from ``t_k`` come from step ``k``; the plant's outputs after step ``k`` are those at ``t_{k+1}``.
SAMPLE_ROW = {"dk": 1, "controller": 1, "plant": 0}

#: How the master makes its FMI calls in a step (:class:`Port`): "direct", the default, or "fmpy".
CALL_PATHS = ("direct", "fmpy")


class Port:
    """One instance's FMI calls in a step: its connected inputs and the outputs the master reads.

    Value references and value buffers are ctypes arrays made once.  ``buffers``: {FMI type: ctypes
    array} of the outputs read (:func:`~cosim.loop.wiring.outputs_of`, grouped by type, order
    kept; the Real ones come first); ``where``: ``"instance.output"`` -> (FMI type, index).
    ``set_inputs`` is bound by :meth:`bind`.  Every call returns its FMI status (:func:`.calls.check`).
    ``calls``: "direct" (the FMU's C functions with their arguments bound once, :func:`.calls.hot_call`)
    or "fmpy" (fmpy's methods, which check and raise themselves).
    """

    def __init__(self, instance: str, unit: FMUUnit, calls: str = "direct"):
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real

        if calls not in CALL_PATHS:
            raise ValueError(f"calls: expected one of {CALL_PATHS}, got {calls!r}")
        refs = lambda names: unit.vr_array(*names)               # noqa: E731
        self.instance, self.unit, self.calls = instance, unit, calls
        inputs = inputs_of(instance)
        if any(unit.vars[n].type != "Real" for n in inputs):
            raise TypeError(f"{instance}: connected inputs must be Real")
        self.n_in, self.in_vr = len(inputs), refs(inputs)
        groups: dict[str, list[str]] = {"Real": []}
        for name in outputs_of(instance):
            groups.setdefault(unit.vars[name].type, []).append(name)
        ctype = {"Real": fmi2Real, "Integer": fmi2Integer, "Boolean": fmi2Boolean}
        self.buffers = {kind: (ctype[kind] * len(names))() for kind, names in groups.items()}
        self._reads = {kind: (refs(names), len(names)) for kind, names in groups.items()}
        self.where = {f"{instance}.{name}": (kind, i) for kind, names in groups.items() for i, name in enumerate(names)}
        self.set_inputs = None

    def call(self, name: str, *fixed):
        """``call(*rest) -> status``: this instance's FMI function ``name`` with ``fixed`` bound after
        the instance (by this port's ``calls`` path)."""
        fmu = self.unit.fmu
        if self.calls == "direct":
            return hot_call(fmu, name, fmu.component, *fixed)
        return functools.partial(getattr(fmu, name), fmu.component, *fixed)

    def bind(self, ports: dict) -> None:
        """Plan ``set_inputs()``: one fmi2SetReal of the inputs, taken from the other ports' buffers.

        Inputs that are one run of one Real buffer are passed as a view of it (no copy); otherwise
        they are copied into this port's input buffer first (the connections,
        :func:`~cosim.loop.wiring.copy_plan`).
        """
        from fmpy.fmi2 import fmi2Real

        where = {}
        for p in ports.values():
            for key, (kind, i) in p.where.items():
                if kind == "Real":
                    where[key] = (p.buffers["Real"], i)
        plan = copy_plan(sources_of(self.instance), where)
        vr, n = self.in_vr, self.n_in
        if len(plan) == 1 and plan[0][:2] == (0, n):
            _, _, buf, c0, _ = plan[0]
            view = (fmi2Real * n).from_buffer(buf, c0 * ctypes.sizeof(fmi2Real))
            self.set_inputs = self.call("fmi2SetReal", vr, n, view)
            return
        u = (fmi2Real * n)()
        set_real = self.call("fmi2SetReal", vr, n, u)
        # each run of the plan as a pair of numpy views made once: `dst[...] = src` is one C copy (0.1 us;
        # slices of the ctypes arrays cost 0.3-0.4 us a run, measured)
        u_np = np.ctypeslib.as_array(u)
        runs = tuple((u_np[a:b], np.ctypeslib.as_array(buf)[c0:d]) for a, b, buf, c0, d in plan)

        def set_inputs():                           # (the views keep the ctypes arrays they look into)
            for dst, src in runs:
                dst[...] = src
            return set_real()
        self.set_inputs = set_inputs

    def read_calls(self, flags: bool = True) -> tuple:
        """One ``(FMI type, call)`` per type of the outputs read, Real first: ``call()`` fills that
        type's buffer.  ``flags=False``: the Real one only."""
        return tuple((kind, self.call(f"fmi2Get{kind}", vrs, m, self.buffers[kind]))
                     for kind, (vrs, m) in self._reads.items() if m and (flags or kind == "Real"))

    def step_call(self):
        """``step(t, h, fmi2True) -> status``: this instance's fmi2DoStep."""
        return self.call("fmi2DoStep")


def one_block(ports: dict):
    """Every port's output buffers moved into one ctypes block (the widest elements first, so each
    buffer stays aligned), so that a step's outputs are kept with one copy of its bytes.

    Returns (the block, {(instance, FMI type): (byte offset, ctypes array type)}); each port's
    ``buffers`` then holds views of the block (before :meth:`Port.bind`, which takes views of them).
    """
    items = sorted(((p, kind, buf) for p in ports.values() for kind, buf in p.buffers.items()),
                   key=lambda item: -ctypes.sizeof(item[2]._type_))
    block = (ctypes.c_char * max(sum(ctypes.sizeof(buf) for _, _, buf in items), 1))()
    layout, offset = {}, 0
    for p, kind, buf in items:
        p.buffers[kind] = type(buf).from_buffer(block, offset)
        layout[p.instance, kind] = (offset, type(buf))
        offset += ctypes.sizeof(buf)
    return block, layout


class ClosedLoop:
    """The Fig. 2 loop of three FMUs driven by fmpy (see the module docstring).

    Instances are reusable: :meth:`run` re-instantiates the FMUs (:meth:`FMUUnit.reset`) and
    initializes them for the scenario, so a batch can run many scenarios without extracting the
    FMUs again.

    Parameters
    ----------
    fmus : dict
        {"RRRDirectKinematics": path, "ComputedTorqueController": path, "RRRPlant": path}.
    calls : {"direct", "fmpy"}
        How a step's FMI calls are made: the FMUs' C functions as fmpy loaded them, their arguments
        bound once and each status checked by the master as fmpy does (:mod:`cosim.loop.calls`; with
        an FMI call logger set, fmpy's methods), or fmpy's methods.  The same calls, values and
        errors either way; "direct" spends 0.6-1.2 us less a call.

    Every :meth:`initialize` (each run) makes fresh instances and frees the old ones, and
    :meth:`close` frees them: a :meth:`step_function` made before refuses to step (RuntimeError)
    rather than call an instance that no longer exists.
    """

    def __init__(self, fmus: dict, calls: str = "direct"):
        if calls not in CALL_PATHS:
            raise ValueError(f"calls: expected one of {CALL_PATHS}, got {calls!r}")
        self._generation = 0                # the instances' generation: +1 at each initialize and at close
        self._closed = False
        self.units = {}
        try:
            for name in INSTANCES.values():
                self.units[name] = FMUUnit(fmus[name], name)
        except Exception:
            self.close()
            raise
        self.ports = {inst: Port(inst, self.units[name], calls) for inst, name in INSTANCES.items()}
        self._block, self._layout = one_block(self.ports)
        self._fresh = True
        #: the robot description the DK FMU carries (None: the paper's robot) and its geometry
        self.robot = fmu_robot(self.units[INSTANCES["dk"]].path)
        self.model = self.robot.model if self.robot is not None else Manipulator.paper()

    def close(self):
        self._generation += 1
        self._closed = True
        for unit in self.units.values():
            unit.close()
        self.units = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def initialize(self, sc: Scenario, t0: float) -> None:
        """Fresh instances (after the first run), initialized for ``sc`` at ``t0``; binds the ports
        to them."""
        if self._closed:
            raise RuntimeError("ClosedLoop: closed (close() or the end of its with block freed the FMU "
                               "instances); make a new ClosedLoop")
        values = start_values(sc, self.model)
        self._generation += 1               # the step functions of the instances freed below stop here
        if not self._fresh:
            for unit in self.units.values():
                unit.reset()
        self._fresh = False
        for inst in ("plant", "dk", "controller"):
            self.units[INSTANCES[inst]].initialize(t0, values[inst])
        for port in self.ports.values():
            port.bind(self.ports)

    def run(self, scenario: Scenario | None = None, t0: float = 0.0, flags: bool = True) -> ClosedLoopResult:
        """Run one scenario from ``t0``; returns the time series (one row per communication point).

        Per step and instance: one fmi2SetReal (its connected inputs), fmi2DoStep and one
        fmi2GetReal (its Real outputs that the loop or the result needs).  ``flags``: also read the
        DK's Integer and Boolean outputs (status, region, n_real, near_border, ambiguous: two more
        calls per step); without it the result has no such columns (:data:`FLAG_COLUMNS`).
        """
        sc = robot_scenario(self.robot) if scenario is None else scenario
        self.initialize(sc, t0)
        n, h = sc.n_steps, sc.h
        ports = [self.ports[inst] for inst in INSTANCES]
        reads = [p.read_calls(flags) for p in ports]
        dk_int, dk_bool = ([call for _, call in reads[0][1:]] + [None, None])[:2]   # after the Real read
        for p, r in zip(ports, reads):                    # the outputs at initialization: row 0
            for kind, call in r:
                check(call(), p.instance, f"fmi2Get{kind}")
        block = self._block                               # every port's outputs (:func:`one_block`)
        rows = [bytes(block)]
        advance = self._step_calls(sc.order)             # made now, for these instances
        cpu = time.process_time()
        wall = time.perf_counter()
        for k in range(n):
            advance(t0 + k * h, h)
            if flags:
                if (s := dk_int()) > WORST:
                    check(s, "dk", "fmi2GetInteger")
                if (s := dk_bool()) > WORST:
                    check(s, "dk", "fmi2GetBoolean")
            rows.append(bytes(block))                     # the step's outputs, one copy of their bytes
        columns = self._columns(rows, t0, n, h, flags)
        wall = time.perf_counter() - wall
        return ClosedLoopResult(sc, columns, wall, time.process_time() - cpu)

    def step_function(self, order: str = "gauss-seidel"):
        """``advance(t, h)``: one communication step of the initialized loop, from ``t`` to ``t + h``.

        Per instance one fmi2SetReal (its connected inputs), fmi2DoStep and one fmi2GetReal (its Real
        outputs, into the ports' buffers), in the order of ``order``: "gauss-seidel" (DK, controller,
        plant, each seeing the outputs of those before it), "jacobi" (all inputs from time ``t``) or
        "omsimulator" (inputs set in the data-flow order, the DK's pose read for the new joints
        before the controller's inputs are set, then all step: the controller sees the pose at ``t``,
        the plant the torque held from ``t - h``; one more fmi2GetReal of the DK and of the
        controller a step).

        It steps the instances of the last :meth:`initialize` only: after the next one, or after
        :meth:`close`, it raises RuntimeError (those instances are freed; make a new step function).
        """
        if self._closed:
            raise RuntimeError("ClosedLoop.step_function: the loop is closed; make a new ClosedLoop")
        if self._generation == 0:
            raise RuntimeError("ClosedLoop.step_function: no initialized instances; call initialize(scenario, "
                               "t0) first")
        advance, made = self._step_calls(order), self._generation

        def checked(t, h):
            if self._generation != made:
                raise RuntimeError("ClosedLoop.step_function: the loop was initialized again or closed since "
                                   "this step function was made, and its FMU instances are freed; call "
                                   "step_function() again")
            advance(t, h)
        return checked

    def _step_calls(self, order: str):
        """:meth:`step_function` without its check (:meth:`run` makes it right after initializing)."""
        calls = {}
        for p in self.ports.values():
            calls[p.instance, "set"] = p.set_inputs
            calls[p.instance, "step"] = p.step_call()
            calls[p.instance, "get"] = p.read_calls(False)[0][1]
        return step_sequence(calls, order)

    def _columns(self, rows: list, t0: float, n: int, h: float, flags: bool) -> dict:
        """The result's columns (float64, :data:`COLUMNS` order) from the rows the run kept (the output
        block's bytes at initialization and after each step)."""
        where = {k: (p.instance, *v) for p in self.ports.values() for k, v in p.where.items()}
        raw = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(len(rows), ctypes.sizeof(self._block))
        tables = {}
        for key, (offset, array_type) in self._layout.items():
            width = ctypes.sizeof(array_type)
            dtype = np.dtype(array_type._type_)
            tables[key] = raw[:, offset:offset + width].copy().view(dtype).astype(float)
        columns = {"time": t0 + np.arange(n) * h}                    # t0 + k h, as in the loop
        for name, source in COLUMN_SOURCES.items():
            if source is None or (not flags and name in FLAG_COLUMNS):
                continue
            inst, kind, j = where[source]
            r = SAMPLE_ROW[inst]
            columns[name] = tables[inst, kind][r:r + n, j].copy()
        return columns


def simulate_fig3(dk_fmu, params, q0, dq0, t_end: float, h: float, tau=None, X0=None, posture: int = 1,
                  mode: str = "default"):
    """Joint-space dynamics (eq. 7) by RK4 in the master, the DK FMU at every stage (Fig. 3).

    Parameters
    ----------
    dk_fmu : path
        The DK FMU.
    params : dynamics.DynamicParameters
    q0, dq0 : array_like (3,)
        Initial joints (rad) and rates (rad/s).
    t_end, h : float
        Duration and step, s.
    tau : None or callable ``tau(t, q, dq) -> (3,)``
        Motor torques (None: zero).
    X0 : array_like (3,), optional
        Pose at ``q0`` (the DK FMU's initial pose); default from the FMU's own initialization.

    Returns
    -------
    t : ndarray (n+1,)
    q, dq, X : ndarray (n+1, 3)
        Joints, rates and the DK FMU's pose at every step.
    """
    model = Manipulator.paper()
    q0 = np.asarray(q0, float)
    start = {"q1": q0[0], "q2": q0[1], "q3": q0[2], "posture": posture, "mode": 0 if mode == "default" else 1}
    if X0 is not None:
        start.update(x0=X0[0], y0=X0[1], phi0=X0[2])
    with FMUUnit(dk_fmu, "dk-fig3") as unit:
        unit.initialize(0.0, start)
        dk = _PoseCalls(unit)
        n = int(round(t_end / h))
        t = np.arange(n + 1) * h
        Q, DQ, XX = np.zeros((n + 1, 3)), np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
        Q[0], DQ[0], XX[0] = q0, dq0, dk.initial_pose(q0)
        for k in range(n):
            tk = t[k]
            saved = dk.fmu.getFMUstate()
            # rk4_step evaluates f at tk, tk + h/2, tk + h/2, tk + h: the pose of the first stage is
            # the committed one, the others are the DK FMU's answer from the saved state
            offsets = iter((None, 0.5 * h, 0.5 * h, h))

            def f(t_s, x, saved=saved, tk=tk, k=k, offsets=offsets):
                q, dq = x[:3], x[3:]
                dt = next(offsets)
                X = XX[k] if dt is None else dk.pose(saved, tk, q, dt)
                u = np.zeros(3) if tau is None else np.asarray(tau(t_s, q, dq), float)
                return np.concatenate([dq, forward_dynamics(params, model, q, dq, X, u)])

            x = rk4_step(f, tk, np.concatenate([Q[k], DQ[k]]), h)
            Q[k + 1], DQ[k + 1] = x[:3], x[3:]
            XX[k + 1] = dk.pose(saved, tk, Q[k + 1], h)          # commit the step's end
            dk.fmu.freeFMUstate(saved)
        return t, Q, DQ, XX


class _PoseCalls:
    """The DK FMU's calls in the Fig. 3 scheme: value references and buffers made once."""

    def __init__(self, unit: FMUUnit):
        from fmpy.fmi2 import fmi2Real, fmi2True

        self.fmu, self.true = unit.fmu, fmi2True
        self.vin, self.vout = unit.vr_array("q1", "q2", "q3"), unit.vr_array("x", "y", "phi")
        self.q_buf, self.x_buf = (fmi2Real * 3)(), (fmi2Real * 3)()

    def initial_pose(self, q0) -> np.ndarray:
        """Set the joints ``q0`` (rad) and read the pose of the initialized FMU, (3,) m, m, rad."""
        fmu, c = self.fmu, self.fmu.component
        self.q_buf[:] = q0
        fmu.fmi2SetReal(c, self.vin, 3, self.q_buf)
        fmu.fmi2GetReal(c, self.vout, 3, self.x_buf)
        return np.array(self.x_buf[:])

    def pose(self, saved, t_n: float, q, dt: float) -> np.ndarray:
        """The pose after one step from FMU state ``saved`` at ``t_n`` to joints ``q`` over ``dt`` s."""
        fmu, c = self.fmu, self.fmu.component
        fmu.setFMUstate(saved)
        self.q_buf[:] = q
        fmu.fmi2SetReal(c, self.vin, 3, self.q_buf)
        fmu.fmi2DoStep(c, t_n, dt, self.true)
        fmu.fmi2GetReal(c, self.vout, 3, self.x_buf)
        return np.array(self.x_buf[:])
