"""The fmpy master of the paper's Figs 2 and 3: :class:`ClosedLoop` and :func:`simulate_fig3`.

The master knows the FMUs only through fmpy's ``FMU2Slave`` (driven by :class:`fmu_src.unit.FMUUnit`).
Value references are looked up by name once; time is ``t0 + k h``, never accumulated.

Closed loop (Fig. 2), :meth:`ClosedLoop.run`
--------------------------------------------
Initialization, in the FMI phases' order: instantiate, setupExperiment(t0), enterInitializationMode,
parameters and the inputs at ``t0`` (:func:`dynamics.cosim.wiring.start_values`: the plant starts at
rest at the circle's first point; the DK FMU gets that pose as ``x0, y0, phi0`` and the plant's
initial joints as inputs; the controller the plant's initial outputs), exitInitializationMode.

Each macro step ``[t_k, t_k + h)``, ``order="gauss-seidel"`` (the default)::

    q, dq, X_true   <- plant outputs at t_k                       (sensors)
    DK:         set q;            doStep(t_k, h);  X <- pose of q (t_k)
    controller: set q, dq, X;     doStep(t_k, h);  tau <- tau(t_k), held over the step
    plant:      set tau;          doStep(t_k, h);  state at t_k + h

Every link carries the value at ``t_k``: no delay beyond the controller's zero-order hold.
``order="jacobi"``: all inputs are set from the outputs available at ``t_k`` before any doStep,
so the DK pose and the torque each lag one step (the controller sees the pose of ``q_{k-1}``, the
plant gets ``tau_{k-1}``).  Which input comes from which output is :data:`~dynamics.cosim.wiring.
CONNECTIONS`, nothing else.  The ModelStructure of each FMU declares which outputs depend on which
inputs (the DK pose on q1..q3; the plant's outputs on no input; the controller's held torque on no
input at the communication point), so a master that sorts the graph finds no algebraic loop.

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

import functools
import time

import numpy as np

from dynamics import forward_dynamics, rk4_step
from fmu_src.unit import FMUUnit
from solver import Manipulator

from .results import COLUMN_SOURCES, COLUMNS, ClosedLoopResult
from .scenario import Scenario
from .wiring import INSTANCES, copy_plan, inputs_of, outputs_of, sources_of, start_values

__all__ = ["ClosedLoop", "Port", "simulate_fig3"]


class Port:
    """One instance's FMI calls in a step: its connected inputs and the outputs the master reads.

    ``u``: the input values (ctypes, in :func:`~dynamics.cosim.wiring.inputs_of` order);
    ``buffers``: {FMI type: ctypes array} of the outputs read (:func:`~dynamics.cosim.wiring.outputs_of`,
    grouped by type, order kept); ``where``: ``"instance.output"`` -> (buffer, index).
    """

    def __init__(self, instance: str, unit: FMUUnit):
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real, fmi2ValueReference

        def refs(names):
            return (fmi2ValueReference * len(names))(*unit.vr(*names))

        self.instance, self.unit = instance, unit
        inputs = inputs_of(instance)
        if any(unit.vars[n].type != "Real" for n in inputs):
            raise TypeError(f"{instance}: connected inputs must be Real")
        self.n_in, self.in_vr, self.u = len(inputs), refs(inputs), (fmi2Real * len(inputs))()
        groups: dict[str, list[str]] = {}
        for name in outputs_of(instance):
            groups.setdefault(unit.vars[name].type, []).append(name)
        ctype = {"Real": fmi2Real, "Integer": fmi2Integer, "Boolean": fmi2Boolean}
        self.buffers = {kind: (ctype[kind] * len(names))() for kind, names in groups.items()}
        self._reads = [(kind, refs(names), len(names)) for kind, names in groups.items()]
        self.where = {f"{instance}.{name}": (self.buffers[kind], i)
                      for kind, names in groups.items() for i, name in enumerate(names)}
        self.feed = ()

    def bind(self, ports: dict) -> None:
        """Plan the copies that fill ``u`` from the other ports' buffers (the connections)."""
        where = {k: v for p in ports.values() for k, v in p.where.items()}
        self.feed = copy_plan(sources_of(self.instance), where)

    def read_calls(self) -> tuple:
        """One ``(FMI type, call)`` per type of the outputs read: ``call()`` fills that type's buffer."""
        fmu = self.unit.fmu
        getters = {"Real": fmu.fmi2GetReal, "Integer": fmu.fmi2GetInteger, "Boolean": fmu.fmi2GetBoolean}
        return tuple((kind, functools.partial(getters[kind], fmu.component, vrs, m, self.buffers[kind]))
                     for kind, vrs, m in self._reads)

    def calls(self):
        """The FMI calls of the current instance: ``set_inputs()``, ``step(t, h, fmi2True)``, ``read()``."""
        fmu = self.unit.fmu
        c = fmu.component
        u, feed, n, vr = self.u, self.feed, self.n_in, self.in_vr
        set_real = fmu.fmi2SetReal
        reads = tuple(call for _, call in self.read_calls())

        def set_inputs():
            for a, b, buf, c0, d in feed:
                u[a:b] = buf[c0:d]
            set_real(c, vr, n, u)

        def read():
            for call in reads:
                call()
        return set_inputs, functools.partial(fmu.fmi2DoStep, c), read


class ClosedLoop:
    """The Fig. 2 loop of three FMUs driven by fmpy (see the module docstring).

    Instances are reusable: :meth:`run` re-instantiates the FMUs (:meth:`FMUUnit.reset`) and
    initializes them for the scenario, so a batch can run many scenarios without extracting the
    FMUs again.

    Parameters
    ----------
    fmus : dict
        {"RRRDirectKinematics": path, "ComputedTorqueController": path, "RRRPlant": path}.
    """

    def __init__(self, fmus: dict):
        self.units = {}
        try:
            for name in INSTANCES.values():
                self.units[name] = FMUUnit(fmus[name], name)
        except Exception:
            self.close()
            raise
        self.ports = {inst: Port(inst, self.units[name]) for inst, name in INSTANCES.items()}
        for port in self.ports.values():
            port.bind(self.ports)
        where = {k: v for p in self.ports.values() for k, v in p.where.items()}
        #: the copies that fill a result row from the ports' buffers (column 0, the time, apart)
        self.record = copy_plan(list(COLUMN_SOURCES.values()), where)
        self._fresh = True

    def close(self):
        for unit in self.units.values():
            unit.close()
        self.units = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def initialize(self, sc: Scenario, t0: float) -> None:
        """Fresh instances (after the first run), initialized for ``sc`` at ``t0``."""
        values = start_values(sc)
        if not self._fresh:
            for unit in self.units.values():
                unit.reset()
        self._fresh = False
        for inst in ("plant", "dk", "controller"):
            self.units[INSTANCES[inst]].initialize(t0, values[inst])

    def fill_row(self, row, t) -> None:
        """One result row (:data:`~dynamics.cosim.results.COLUMNS`) from the ports' buffers at ``t``."""
        row[0] = t
        for a, b, buf, c, d in self.record:
            row[a:b] = buf[c:d]

    def run(self, scenario: Scenario | None = None, t0: float = 0.0) -> ClosedLoopResult:
        """Run one scenario from ``t0``; returns the time series (one row per communication point)."""
        sc = Scenario() if scenario is None else scenario
        self.initialize(sc, t0)
        n, h = sc.n_steps, sc.h
        out = np.zeros((n, len(COLUMNS)))
        # fmpy's getReal/setReal build two ctypes arrays per call (~1.5 us each): the value references
        # and the value buffers are ctypes arrays made once; the fmi2* calls check the status as before
        from fmpy.fmi2 import fmi2True

        (dk_set, dk_step, dk_read), (ct_set, ct_step, ct_read), (pl_set, pl_step, pl_read) = (
            self.ports[inst].calls() for inst in INSTANCES)
        fill_row = self.fill_row
        for read in (pl_read, dk_read, ct_read):
            read()
        gauss_seidel = sc.order == "gauss-seidel"
        wall = time.perf_counter()
        for k in range(n):
            t = t0 + k * h
            if gauss_seidel:
                dk_set()
                dk_step(t, h, fmi2True)
                dk_read()
                ct_set()
                ct_step(t, h, fmi2True)
                ct_read()
                pl_set()
                pl_step(t, h, fmi2True)
            else:
                dk_set()
                ct_set()
                pl_set()
                dk_step(t, h, fmi2True)
                ct_step(t, h, fmi2True)
                pl_step(t, h, fmi2True)
                dk_read()
                ct_read()
            fill_row(out[k], t)
            pl_read()
        wall = time.perf_counter() - wall
        return ClosedLoopResult(sc, {name: out[:, i] for i, name in enumerate(COLUMNS)}, wall)


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
    with FMUUnit(dk_fmu, "dk-fig3") as unit:
        q0 = np.asarray(q0, float)
        start = {"q1": q0[0], "q2": q0[1], "q3": q0[2], "posture": posture, "mode": 0 if mode == "default" else 1}
        if X0 is not None:
            start.update(x0=X0[0], y0=X0[1], phi0=X0[2])
        unit.initialize(0.0, start)
        fmu = unit.fmu
        vin, vout = unit.vr("q1", "q2", "q3"), unit.vr("x", "y", "phi")
        n = int(round(t_end / h))
        t = np.arange(n + 1) * h
        Q, DQ, XX = np.zeros((n + 1, 3)), np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
        fmu.setReal(vin, q0)
        Q[0], DQ[0] = q0, dq0
        XX[0] = fmu.getReal(vout)

        def pose(saved, t_n, q, dt):
            fmu.setFMUstate(saved)
            fmu.setReal(vin, q)
            fmu.doStep(t_n, dt)
            return np.array(fmu.getReal(vout))

        for k in range(n):
            tk = t[k]
            saved = fmu.getFMUstate()
            # rk4_step evaluates f at tk, tk + h/2, tk + h/2, tk + h: the pose of the first stage is
            # the committed one, the others are the DK FMU's answer from the saved state
            offsets = iter((None, 0.5 * h, 0.5 * h, h))

            def f(t_s, x, saved=saved, tk=tk, k=k, offsets=offsets):
                q, dq = x[:3], x[3:]
                dt = next(offsets)
                X = XX[k] if dt is None else pose(saved, tk, q, dt)
                u = np.zeros(3) if tau is None else np.asarray(tau(t_s, q, dq), float)
                return np.concatenate([dq, forward_dynamics(params, model, q, dq, X, u)])

            x = rk4_step(f, tk, np.concatenate([Q[k], DQ[k]]), h)
            Q[k + 1], DQ[k + 1] = x[:3], x[3:]
            XX[k + 1] = pose(saved, tk, Q[k + 1], h)          # commit the step's end
            fmu.freeFMUstate(saved)
        return t, Q, DQ, XX
