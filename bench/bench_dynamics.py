"""Speed of the dynamics core: one RK4 step of the joint-space plant, one computed-torque evaluation.

    python bench/bench_dynamics.py [--steps 2000] [--repeat 5]

Prints the median time (over ``--repeat`` runs of ``--steps`` calls, states
along the paper's circle) of

* one RK4 step of the joint-space dynamics (eq. 7) with the pose supplied by
  the DK at each of the four stages (``NearestPoseDK``: ``dk_all`` + nearest real solution);
* one DK call of that supplier alone, and one ``forward_dynamics`` evaluation alone;
* one computed-torque evaluation given the pose, and with the DK call included
  (what a controller period costs).
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from solver import Manipulator
from dynamics.control import ComputedTorqueGains, computed_torque
from dynamics.integrate import NearestPoseDK, joint_space_rhs, rk4_step
from dynamics.model import DynamicParameters, forward_dynamics
from dynamics.trajectory import CircleTrajectory


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
    X, _, _ = traj.task(t)
    q, dq, ddq = traj.joint(model, t)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    dk = NearestPoseDK(model, X[0])
    dk(q[0])                                                   # compile / load the DK kernel
    tau = np.array([0.1, -0.2, 0.05])
    f = joint_space_rhs(params, model, dk, tau)
    states = np.concatenate([q, dq], axis=1)

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
    print(f"states: {args.steps} along the circle, median of {args.repeat} runs")
    print(f"RK4 step, joint-space dynamics with DK at 4 stages : {us_step:8.1f} us")
    print(f"  DK pose supplier call (dk_all + nearest)        : {us_dk:8.1f} us")
    print(f"  forward_dynamics (eq. 7), pose given            : {us_fd:8.1f} us")
    print(f"computed-torque evaluation, pose given            : {us_ct:8.1f} us")
    print(f"computed-torque evaluation incl. DK call          : {us_ct_dk:8.1f} us")


if __name__ == "__main__":
    main()
