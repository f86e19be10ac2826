"""Speed of the dynamics core: one RK4 step of the joint-space plant, one computed-torque evaluation.

    python bench/bench_dynamics.py [--steps 2000] [--repeat 5]

Prints the median time (over ``--repeat`` runs of ``--steps`` calls, states
along the paper's circle) of

* one RK4 step of the joint-space dynamics (eq. 7) with the pose supplied by
  the DK at each of the four stages (``NearestPoseDK``: ``dk_all`` + nearest real solution);
* one DK call of that supplier alone, and one ``forward_dynamics`` evaluation alone;
* one computed-torque evaluation given the pose, and with the DK call included
  (what a controller period costs);
* the task-space form (no DK): one ``forward_dynamics_task`` evaluation, one
  ``rk4_step`` of ``task_space_rhs`` with constant torques, and the cost per
  step of ``rk4`` over ``--steps`` steps of free motion;
* what the FMU slaves run at every communication step: one ``PlantStepper.step``
  (one RK4 step and the outputs) and one ``ControllerStepper.step``.

The dynamics run compiled kernels (``dynamics/_kernels/``); they are compiled
(or loaded from numba's cache) before the timing starts.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from solver import Manipulator
from dynamics import (CircleTrajectory, ComputedTorqueGains, ControllerStepper, DynamicParameters, NearestPoseDK,
                      PlantStepper, computed_torque, forward_dynamics, forward_dynamics_task, joint_space_rhs, rk4,
                      rk4_step, task_space_rhs)


def _median_us(fn, n, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for k in range(n):
            fn(k)
        times.append((time.perf_counter() - t0) / n)
    return 1e6 * float(np.median(times))


def _warm_up(params, model, gains, traj, dk, f, q, dq, ddq, X, dX, states, tau, t) -> None:
    """Compile (first run) or load from numba's cache every kernel before timing."""
    dk(q[0])
    forward_dynamics(params, model, q[0], dq[0], X[0], tau)
    computed_torque(params, model, gains, q[0], dq[0], X[0], q[0], dq[0], ddq[0])
    forward_dynamics_task(params, model, X[0], dX[0], tau)
    rk4(task_space_rhs(params, model, traj.posture), 0.0, np.concatenate([X[0], dX[0]]), 1e-3, 1)
    rk4_step(f, t[0], states[0], 1e-3)


def _task_loop_us(params, model, traj, steps: int, repeat: int) -> float:
    """rk4 of free motion from the circle's centre (0.1 m/s, 0.5 rad/s; clear of singularities for
    2 s), us per step, median of ``repeat`` runs."""
    free = task_space_rhs(params, model, traj.posture)
    x_start = np.array([0.45, 0.30, np.deg2rad(-45.0), 0.10, 0.0, 0.5])
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        rk4(free, 0.0, x_start, 1e-3, steps)
        runs.append((time.perf_counter() - t0) / steps)
    return 1e6 * float(np.median(runs))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=2000, help="states along the circle (1 ms apart)")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs of each; the median is reported")
    args = ap.parse_args(argv)
    model, params = Manipulator.paper(), DynamicParameters()
    gains = ComputedTorqueGains.design(50.0, 1.0)
    traj = CircleTrajectory()
    t = 1e-3 * np.arange(args.steps)
    X, dX, _ = traj.task(t)
    q, dq, ddq = traj.joint(model, t)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    dk = NearestPoseDK(model, X[0])
    tau = np.array([0.1, -0.2, 0.05])
    f = joint_space_rhs(params, model, dk, tau)
    states, task_states = np.concatenate([q, dq], axis=1), np.concatenate([X, dX], axis=1)
    _warm_up(params, model, gains, traj, dk, f, q, dq, ddq, X, dX, states, tau, t)
    q_des = q + 1e-4                                           # a small tracking error
    ft = task_space_rhs(params, model, traj.posture, tau)
    # the FMU slaves' steps: the plant from the circle's states, the controller on the reference
    plant, controller = PlantStepper(params, model, traj.posture), ControllerStepper(params, model, gains, traj)
    out_p, out_c = np.empty(PlantStepper.OUT_SIZE), np.empty(ControllerStepper.OUT_SIZE)
    inputs = np.concatenate([t[:, None], q_des, dq, X], axis=1).tolist()    # Python floats, as a slave passes

    def at(k, fn):                                             # the DK continues from the circle's pose
        dk.pose = X[k]
        return fn()

    cases = [
        ("RK4 step, joint-space dynamics with the DK at 4 stages", lambda k: at(k, lambda: rk4_step(f, t[k], states[k], 1e-3))),
        ("DK pose supplier call (dk_all + nearest)", lambda k: at(k, lambda: dk(q[k]))),
        ("forward_dynamics (eq. 7), pose given", lambda k: forward_dynamics(params, model, q[k], dq[k], X[k], tau)),
        ("computed-torque evaluation, pose given",
         lambda k: computed_torque(params, model, gains, q[k], dq[k], X[k], q_des[k], dq[k], ddq[k])),
        ("computed-torque evaluation with the DK call", lambda k: at(k, lambda: computed_torque(
            params, model, gains, q[k], dq[k], dk(q[k]), q_des[k], dq[k], ddq[k]))),
        ("task space: forward_dynamics_task, q by IK", lambda k: forward_dynamics_task(params, model, X[k], dX[k], tau)),
        ("task space: rk4_step of task_space_rhs", lambda k: rk4_step(ft, t[k], task_states[k], 1e-3)),
        ("task space: rk4, per step", None),
        ("plant FMU's step: PlantStepper.step (one RK4 step)",
         lambda k: plant.step(0.1, -0.2, 0.05, 1e-3, 1, task_states[k], out_p)),
        ("controller FMU's step: ControllerStepper.step", lambda k: controller.step(*inputs[k], out_c)),
    ]
    rows = [(label, _task_loop_us(params, model, traj, args.steps, args.repeat) if fn is None
             else _median_us(fn, args.steps, args.repeat)) for label, fn in cases]
    print(f"states: {args.steps} along the circle, median of {args.repeat} runs")
    for label, us in rows:
        print(f"{label:56s}: {us:8.1f} us")
    _report(args, rows)


def _report(args, rows):
    """The timings into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    publish("dynamics", table(["call", "median time per call"], [(name, f"{us:.1f} us") for name, us in rows]),
            note=f"{args.steps} states along the circle, median of {args.repeat} runs.")


if __name__ == "__main__":
    main()
