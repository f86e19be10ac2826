"""One communication step of the plant and of the computed-torque controller: what the FMU slaves run.

Built once (at the slave's initialization), each stepper holds its constants packed for the
compiled step (:mod:`dynamics._kernels.steps`) and a work buffer, so that :meth:`step` -- called
at every communication step, typically every 1 ms -- is one compiled call that writes into the
caller's preallocated array and allocates nothing.  A refused step raises
:class:`dynamics.DynamicsError` (``where``: the RK4 step, or the part of a controller step).

>>> from solver import Manipulator
>>> plant = PlantStepper(DynamicParameters(), Manipulator.paper(), posture=1)
>>> out = np.empty(PlantStepper.OUT_SIZE)
>>> plant.step(0.1, 0.0, -0.1, 1e-3, 1, np.array([0.45, 0.3, -0.7, 0.0, 0.0, 0.0]), out)
>>> q, dq, energy = out[6:9], out[9:12], out[12]
"""
from __future__ import annotations

import math

import numpy as np

from solver import Manipulator, SolverInputError, check_posture
from solver.checks import check_instance

from ._checks import check_pair
from ._packs import arm_pack, bodies_pack, circle_pack, gains_pack
from ._kernels.layout import (BAD_SHAPE, CONTROLLER_OUT_SIZE, CONTROLLER_PHASE_REFERENCE, OUTSIDE, PLANT_OUT_SIZE,
                              PLANT_OUT_STATE, STEP_WORK_SIZE, refusal)
from ._kernels.c_entry import IO_TOL, controller_entry, make_table, plant_entry
from ._kernels.steps import controller_step, plant_step
from .control import ComputedTorqueGains
from .errors import DynamicsError, REASONS, outside_text, refused
from .geometry import ASSEMBLY_TOL
from .parameters import DynamicParameters
from .trajectory import CircleTrajectory

__all__ = ["PlantStepper", "ControllerStepper"]


class PlantStepper:
    """The plant's step: RK4 of the task-space dynamics with the torques held, then the sensors.

    Parameters
    ----------
    params : DynamicParameters
        The real robot's parameters.
    model : Manipulator
    posture : int
        Posture 1..8 of the robot (motor angles by inverse kinematics).

    The state is ``x = (X, dX)`` (6,): pose (m, m, rad) and its rate.  :meth:`step` writes into
    ``out`` (:attr:`OUT_SIZE`,): the new state ``out[0:6]``, the motor angles ``q = out[6:9]``
    (with the operations of :func:`solver.ik`), their rates ``dq = J_q dX = out[9:12]`` and the
    total energy ``out[12]`` (:func:`dynamics.total_energy`).
    """

    #: length of the output array of :meth:`step`
    OUT_SIZE = PLANT_OUT_SIZE

    def __init__(self, params: DynamicParameters, model: Manipulator, posture: int = 1):
        check_pair(params, model)
        self.params, self.model, self.posture = params, model, int(check_posture(posture))
        self._pack = np.concatenate([arm_pack(model), bodies_pack(params)])
        self._bits = self.posture - 1
        self._work = np.empty(STEP_WORK_SIZE)

    def step(self, tau1: float, tau2: float, tau3: float, h: float, n: int, x, out) -> None:
        """``n`` RK4 steps of ``h`` (s) from the state ``x`` (6,) with the motor torques (N m) held,
        then the outputs, into ``out``; ``x`` is not modified (``n = 0``: the outputs of ``x``).

        Raises
        ------
        DynamicsError
            A Runge-Kutta stage was refused (the platform left the tool space, ``where`` the
            step 0..n-1, the message names the stage's pose), or the outputs of the new state
            (``where = n``).  ``out`` is then undefined.
        SolverInputError
            ``x`` or ``out`` of the wrong length (checked by the compiled step, at no cost).
        """
        code = plant_step(self._pack, self._bits, tau1, tau2, tau3, h, n, x, out, self._work)
        if code:
            if code == BAD_SHAPE:
                raise SolverInputError(f"x, out: expected float arrays of shapes (6,) and ({self.OUT_SIZE},), "
                                       f"got {np.shape(x)} and {np.shape(out)}")
            raise self._refused(code, (tau1, tau2, tau3), out)

    def outputs(self, x, out) -> None:
        """The outputs of the state ``x`` into ``out`` (:meth:`step` with no substep)."""
        self.step(0.0, 0.0, 0.0, 0.0, 0, x, out)

    def c_step(self, x, io, real, slots):
        """The step for a C caller (the plant FMU's loader): ``(address, table)`` of
        :func:`dynamics._kernels.c_entry.plant_entry` over the state ``x`` (6,), which it advances in
        place, the scalars ``io`` (``c_entry.IO_SIZE``,: substeps in, time and count out) and the Real
        value array ``real`` with the value references ``slots`` (``c_entry.PLANT_SLOTS`` order)."""
        self._c_out = np.empty(self.OUT_SIZE)
        table = make_table(self._bits, self._pack, self._work, self._c_out, io, real, slots, x)
        return plant_entry().address, table

    def _refused(self, code, tau, out):
        status, k = refusal(code)
        state = out[PLANT_OUT_STATE:PLANT_OUT_STATE + 6].copy()
        exc = refused(status, {"X": state[:3], "dX": state[3:], "tau": np.array(tau, dtype=float)},
                      model=self.model, posture=self.posture)
        return DynamicsError(str(exc), exc.reason, k)


class ControllerStepper:
    """The sampled computed-torque law on a circle: what the controller FMU computes at each step.

    Parameters
    ----------
    params : DynamicParameters
        The controller's model of the robot.
    model : Manipulator
    gains : ComputedTorqueGains
    trajectory : CircleTrajectory
        The reference (its posture is the robot's).

    :meth:`step` evaluates the reference at ``t`` (:meth:`CircleTrajectory.joint`), the joints of
    the measured pose ``q_X = g_j(X)`` unwrapped next to the measured ``q`` and the law of
    :func:`dynamics.computed_torque` at ``(q_X, dq, X)``; it writes into ``out``
    (:attr:`OUT_SIZE`,): the torque ``out[0:3]`` (N m), the reference pose ``out[3:6]`` and the
    reference joints ``out[6:9]``.
    """

    #: length of the output array of :meth:`step`
    OUT_SIZE = CONTROLLER_OUT_SIZE

    def __init__(self, params: DynamicParameters, model: Manipulator, gains: ComputedTorqueGains,
                 trajectory: CircleTrajectory):
        check_pair(params, model)
        check_instance("gains", gains, ComputedTorqueGains, "a ComputedTorqueGains")
        check_instance("trajectory", trajectory, CircleTrajectory, "a CircleTrajectory")
        self.params, self.model, self.gains, self.trajectory = params, model, gains, trajectory
        self._pack = np.concatenate([arm_pack(model), bodies_pack(params), gains_pack(gains),
                                     circle_pack(trajectory)])
        self._bits = trajectory.posture - 1
        self._work = np.empty(STEP_WORK_SIZE)
        # load the compiled step now, not in the first step (a refused call: the result is unused)
        controller_step(self._pack, self._bits, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                        ASSEMBLY_TOL, np.empty(self.OUT_SIZE), self._work)

    def step(self, t: float, q1: float, q2: float, q3: float, dq1: float, dq2: float, dq3: float,
             x: float, y: float, phi: float, out) -> None:
        """The law at ``t`` (s) for the measured motor angles (rad) and rates (rad/s) and the pose
        ``(x, y, phi)`` from the direct kinematics, into ``out``.

        Raises
        ------
        DynamicsError
            ``where = "reference"``: the reference at ``t`` (a non-finite time, a point outside
            the tool space); ``where = "measurement"``: the measurements (the pose outside the
            tool space, singular...).  ``out`` is then unchanged.
        SolverInputError
            ``out`` of the wrong length.
        """
        code = controller_step(self._pack, self._bits, t, q1, q2, q3, dq1, dq2, dq3, x, y, phi, ASSEMBLY_TOL,
                               out, self._work)
        if code:
            if code == BAD_SHAPE:
                raise SolverInputError(f"out: expected a float array of shape ({self.OUT_SIZE},), got {np.shape(out)}")
            raise self._refused(code, t, (q1, q2, q3), (dq1, dq2, dq3), (x, y, phi))

    def c_step(self, io, real, slots):
        """The law for a C caller (the controller FMU's loader): ``(address, table)`` of
        :func:`dynamics._kernels.c_entry.controller_entry` (arguments as :meth:`PlantStepper.c_step`,
        ``slots`` in ``c_entry.CONTROLLER_SLOTS`` order; ``io`` carries the assembly tolerance)."""
        self._c_out = np.empty(self.OUT_SIZE)
        io[IO_TOL] = ASSEMBLY_TOL
        table = make_table(self._bits, self._pack, self._work, self._c_out, io, real, slots)
        return controller_entry().address, table

    def _refused(self, code, t, q, dq, X):
        status, phase = refusal(code)
        if phase == CONTROLLER_PHASE_REFERENCE:
            try:
                self.trajectory.joint(self.model, t)
            except DynamicsError as exc:
                return DynamicsError(f"reference at t = {t!r}: {exc}", exc.reason, "reference")
            return DynamicsError(f"reference at t = {t!r}: refused", REASONS.get(status, "singular"), "reference")
        X = np.array(X, dtype=float)
        if status == OUTSIDE:
            exc = DynamicsError(outside_text(self.trajectory.posture, [X.tolist()]), "outside")
        else:
            exc = refused(status, {"q": np.array(q, dtype=float), "dq": np.array(dq, dtype=float), "X": X},
                          model=self.model, posture=self.trajectory.posture)
        return DynamicsError(str(exc), exc.reason, "measurement")
