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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
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
    dk(q[0])                                                   # compile / load the DK kernel
    tau = np.array([0.1, -0.2, 0.05])
    f = joint_space_rhs(params, model, dk, tau)
    states = np.concatenate([q, dq], axis=1)
    # compile (first run) or load from numba's cache every kernel before timing
    forward_dynamics(params, model, q[0], dq[0], X[0], tau)
    computed_torque(params, model, gains, q[0], dq[0], X[0], q[0], dq[0], ddq[0])
    forward_dynamics_task(params, model, X[0], dX[0], tau)
    rk4(task_space_rhs(params, model, traj.posture), 0.0, np.concatenate([X[0], dX[0]]), 1e-3, 1)
    rk4_step(f, t[0], states[0], 1e-3)

    def step(k):
        dk.pose = X[k]
        rk4_step(f, t[k], states[k], 1e-3)

    def dk_call(k):
        dk.pose = X[k]
        dk(q[k])

    us_step = _median_us(step, args.steps, args.repeat)
    us_dk = _median_us(dk_call, args.steps, args.repeat)
    us_fd = _median_us(lambda k: forward_dynamics(params, model, q[k], dq[k], X[k], tau), args.steps, args.repeat)
    q_des = q + 1e-4                                           # a small tracking error
    us_ct = _median_us(lambda k: computed_torque(params, model, gains, q[k], dq[k], X[k], q_des[k], dq[k], ddq[k]),
                       args.steps, args.repeat)

    def ct_with_dk(k):
        dk.pose = X[k]
        computed_torque(params, model, gains, q[k], dq[k], dk(q[k]), q_des[k], dq[k], ddq[k])

    us_ct_dk = _median_us(ct_with_dk, args.steps, args.repeat)
    us_fdt = _median_us(lambda k: forward_dynamics_task(params, model, X[k], dX[k], tau), args.steps, args.repeat)
    ft = task_space_rhs(params, model, traj.posture, tau)
    task_states = np.concatenate([X, dX], axis=1)
    us_task_step = _median_us(lambda k: rk4_step(ft, t[k], task_states[k], 1e-3), args.steps, args.repeat)
    # free motion from the circle's centre (0.1 m/s, 0.5 rad/s): stays clear of singularities for 2 s
    free = task_space_rhs(params, model, traj.posture)
    x_start = np.array([0.45, 0.30, np.deg2rad(-45.0), 0.10, 0.0, 0.5])
    runs = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        rk4(free, 0.0, x_start, 1e-3, args.steps)
        runs.append((time.perf_counter() - t0) / args.steps)
    us_task_loop = 1e6 * float(np.median(runs))
    # the FMU slaves' steps: the plant from the circle's states, the controller on the reference
    plant, controller = PlantStepper(params, model, traj.posture), ControllerStepper(params, model, gains, traj)
    out_p, out_c = np.empty(PlantStepper.OUT_SIZE), np.empty(ControllerStepper.OUT_SIZE)
    us_plant = _median_us(lambda k: plant.step(0.1, -0.2, 0.05, 1e-3, 1, task_states[k], out_p), args.steps,
                          args.repeat)
    inputs = np.concatenate([t[:, None], q_des, dq, X], axis=1).tolist()    # Python floats, as a slave passes
    us_ctrl = _median_us(lambda k: controller.step(*inputs[k], out_c), args.steps, args.repeat)
    print(f"states: {args.steps} along the circle, median of {args.repeat} runs")
    print(f"RK4 step, joint-space dynamics with DK at 4 stages : {us_step:8.1f} us")
    print(f"  DK pose supplier call (dk_all + nearest)        : {us_dk:8.1f} us")
    print(f"  forward_dynamics (eq. 7), pose given            : {us_fd:8.1f} us")
    print(f"computed-torque evaluation, pose given            : {us_ct:8.1f} us")
    print(f"computed-torque evaluation incl. DK call          : {us_ct_dk:8.1f} us")
    print(f"task space: forward_dynamics_task, q by IK        : {us_fdt:8.1f} us")
    print(f"task space: rk4_step of task_space_rhs            : {us_task_step:8.1f} us")
    print(f"task space: rk4, per step (of {args.steps:5d} steps)      : {us_task_loop:8.1f} us")
    print(f"FMU plant step: PlantStepper.step (1 RK4 step)    : {us_plant:8.1f} us")
    print(f"FMU controller step: ControllerStepper.step       : {us_ctrl:8.1f} us")
    _report(args, [("RK4 step, joint-space dynamics with the DK at 4 stages", us_step),
                   ("DK pose supplier call (dk_all + nearest)", us_dk),
                   ("forward_dynamics (eq. 7), pose given", us_fd),
                   ("computed-torque evaluation, pose given", us_ct),
                   ("computed-torque evaluation with the DK call", us_ct_dk),
                   ("task space: forward_dynamics_task, q by IK", us_fdt),
                   ("task space: rk4_step of task_space_rhs", us_task_step),
                   ("task space: rk4, per step", us_task_loop),
                   ("plant FMU's step: PlantStepper.step (one RK4 step)", us_plant),
                   ("controller FMU's step: ControllerStepper.step", us_ctrl)])


def _report(args, rows):
    """The timings into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    publish("dynamics", table(["call", "median time per call"], [(name, f"{us:.1f} us") for name, us in rows]),
            note=f"{args.steps} states along the circle, median of {args.repeat} runs.")


if __name__ == "__main__":
    main()
