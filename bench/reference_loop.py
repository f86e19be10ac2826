"""The closed loop without FMI: plant RK4, computed torque and Newton DK in one compiled loop.

    python bench/reference_loop.py [--t-end 2.5] [--h 0.001] [--repeat 7]

The limit the FMI closed loop (``python -m cosim``, ``bench/bench_cosim.py``) is measured against: the
default scenario's math (the plant FMU's RK4 step, :func:`dynamics._kernels.steps.plant_step`; the
controller FMU's computed-torque law on the circle, :func:`dynamics._kernels.steps.controller_step`; the
DK by Newton from the previous pose, :func:`solver._kernels.stepper.baseline_advance`), in the master's
Gauss-Seidel order (DK, controller, plant) at time ``t0 + k h``, as one compiled loop: no FMI, no
Python per step.  Prints the wall time per step (median over ``--repeat`` runs), the real-time factor
and the RMS joint error against the reference after the ramp (the loop is the closed loop, not a
stand-in: it must track the circle).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np
from numba import njit

from dynamics import CircleTrajectory, ComputedTorqueGains, DynamicParameters
from dynamics._kernels.steps import controller_step, plant_step
from dynamics.steppers import ControllerStepper, PlantStepper
from dynamics.geometry import ASSEMBLY_TOL
from solver import Manipulator, ik
from solver._kernels.stepper import baseline_advance
from solver.baselines import NewtonTracker


@njit
def closed_loop(n, h, t0, plant, ctrl, bits, x, newton_kind, rule, a, pk, model_pack, sample_to_sextic,
                newton_params, out_real, out_int, out_p, out_c, work_p, work_c, err):
    """``n`` steps of the closed loop from the plant state ``x`` (6,) (its DK state ``a``: Newton's flat
    state at the plant's joints); ``err[k]`` the largest joint error to the reference at step ``k``.
    Returns 0, or the step at which a kernel refused (-(k + 1))."""
    q = np.empty(3)
    if plant_step(plant, bits, 0.0, 0.0, 0.0, 0.0, 0, x, out_p, work_p) != 0:
        return -1
    for k in range(n):
        t = t0 + k * h
        for i in range(3):
            q[i] = out_p[6 + i]
        baseline_advance(newton_kind, rule, q, h, a, pk, model_pack, sample_to_sextic, newton_params, out_real,
                         out_int, False)
        if controller_step(ctrl, bits, t, q[0], q[1], q[2], out_p[9], out_p[10], out_p[11], out_real[0],
                           out_real[1], out_real[2], ASSEMBLY_TOL, out_c, work_c) != 0:
            return -(k + 1)
        e = 0.0
        for i in range(3):
            d = q[i] - out_c[6 + i]
            d = abs(d - 2.0 * math.pi * round(d / (2.0 * math.pi)))
            e = max(e, d)
        err[k] = e
        for i in range(6):
            x[i] = out_p[i]
        if plant_step(plant, bits, out_c[0], out_c[1], out_c[2], h, 1, x, out_p, work_p) != 0:
            return -(k + 1)
    return 0


def run(t_end: float = 2.5, h: float = 1e-3) -> tuple[float, np.ndarray]:
    """One run of the default scenario's loop: (wall seconds of the loop, max joint error per step, rad)."""
    model, params = Manipulator.paper(), DynamicParameters()
    traj = CircleTrajectory()
    plant = PlantStepper(params, model, traj.posture)
    ctrl = ControllerStepper(params, model, ComputedTorqueGains.design(50.0, 1.0), traj)
    X0 = traj.task(np.array([0.0]))[0][0]
    x = np.concatenate([X0, np.zeros(3)])
    dk = NewtonTracker(model)
    dk.reset(X0, ik(model, X0, traj.posture))
    n = int(round(t_end / h))
    out_p, out_c, err = np.empty(PlantStepper.OUT_SIZE), np.empty(ControllerStepper.OUT_SIZE), np.zeros(n)
    t0 = time.perf_counter()
    code = closed_loop(n, h, 0.0, plant._pack, ctrl._pack, plant._bits, x, dk.kind, dk._rule, dk._flat_state(),
                       dk._state_pack, dk._model_pack, dk._sample_to_sextic, dk._params, dk._out_real, dk._out_int,
                       out_p, out_c, plant._work, ctrl._work, err)
    seconds = time.perf_counter() - t0
    if code:
        raise RuntimeError(f"the reference loop stopped at step {-code - 1}: a kernel refused its inputs")
    return seconds, err


def measure(t_end: float = 2.5, h: float = 1e-3, repeat: int = 7) -> dict:
    """Median wall time per step (us), real-time factor and the RMS joint error after the ramp (rad)."""
    run(0.01, h)                                              # compiled before the timing
    runs = [run(t_end, h) for _ in range(repeat)]
    per_step = float(np.median([s for s, _ in runs])) / int(round(t_end / h))
    err = runs[0][1][int(round(0.5 / h)):]
    return {"us": 1e6 * per_step, "real_time": h / per_step, "rms": float(np.sqrt(np.mean(err ** 2)))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--t-end", type=float, default=2.5, help="simulated seconds (default %(default)s)")
    ap.add_argument("--h", type=float, default=1e-3, help="step, s (default %(default)s)")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs (default %(default)s)")
    args = ap.parse_args(argv)
    m = measure(args.t_end, args.h, args.repeat)
    print(f"compiled reference loop (plant RK4, computed torque, Newton DK; no FMI), h = {args.h:g} s: "
          f"{m['us']:.2f} us a step, {m['real_time']:.0f}x real time; RMS joint error after 0.5 s "
          f"{m['rms']:.3g} rad")


if __name__ == "__main__":
    main()
