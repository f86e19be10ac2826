"""Speed of each FMU through fmpy's FMU2Slave against its in-process computation, as ratios.

    python bench/bench_fmu.py [--build-dir build] [--n 1000] [--passes 7]

The three FMUs are built into ``--build-dir`` first if missing (:func:`cosim.fmus.fmu_set.build_fmus`).
The host imports ``solver`` and ``dynamics`` before loading the FMUs (as any host that runs them
repeatedly should), so the FMUs run this process's compiled kernels.  The machine is shared: every
figure is a median, and each FMU pass alternates with an in-process pass over the same inputs, so
that a ratio compares times measured in the same minutes of the same run.  Prints:

- the DK FMU file size and its instantiation time (the first of the process, later ones);
- **DK**: per communication step over the paper's circle (``solver.circle_path(n)`` -> ``ik``
  posture 1, h = 1 ms), ``fmi2SetReal(q1..q3) + fmi2DoStep + fmi2GetReal(x, y, phi)`` with the
  value references and value buffers made once (what the master does), against the in-process
  ``Tracker.step(q, dt=h)`` on the same map and joints; ratio (target <= 1.1: the loader's fast lane
  answers the three calls with the compiled step, :mod:`fmu_src.fast_lane`).  Also the cycle that
  reads all 11 outputs (three more calls), the same cycle through fmpy's convenience
  ``setReal``/``getReal`` (which build ctypes arrays at every call), the first cycle with the slave's
  tracker on its ``TrackerState`` path (``Tracker._objects``: every step packed and rebuilt in Python,
  the step before the compiled stepper; the same process, passes alternating), the same cycle with
  the loader's fast lane off (``RRR_DK_FAST_LANE=0``: every call through pythonfmu's wrapper into the
  slave's Python), and whether the poses are identical;
- **DK for FMI 3.0**: the step of ``<build-dir>/fmi3/RRRDirectKinematics.fmu`` (``q``, ``pose`` arrays)
  beside the FMI 2.0 DK FMU's, in the same run (:mod:`fmu3_step`; target <= 1.2x);
- **plant** and **controller**: the inputs of a closed-loop run (``cosim.ClosedLoop``,
  default scenario) replayed into each FMU alone: the ``fmi2DoStep`` call against the in-process
  computation it wraps (``PlantStepper.step`` / ``ControllerStepper.step`` with the same inputs),
  target at most 2 us more (the loader's fast lane runs the compiled step); and the whole set +
  doStep + get cycle.
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

import dynamics  # noqa: F401  (first: the FMUs then use the host's packages)
import fmu3_step
import solver
from cosim.fmus.fmu_set import build_fmus
from cosim.unit import FMUUnit, exit_process
from solver import Manipulator, MapTensor, Tracker, circle_path

ROOT = Path(__file__).resolve().parents[1]
H = 1e-3


def _arrays(unit, names, ctype):
    return unit.vr_array(*names), (ctype * len(names))()


def _median_us(times) -> float:
    return float(np.median(times) * 1e6)


def bench_dk(unit: FMUUnit, n: int, passes: int) -> dict:
    """DK: the FMU cycles and the in-process tracker, alternating passes over the circle."""
    model = Manipulator.paper()
    X = circle_path(n)
    Q = solver.ik(model, X, 1)
    rows = [tuple(map(float, q)) for q in Q]
    start = {"x0": X[0][0], "y0": X[0][1], "phi0": X[0][2], "q1": Q[0][0], "q2": Q[0][1], "q3": Q[0][2]}
    io = _io(unit)
    tracker = Tracker(model, MapTensor.load(Path(unit.unzip_dir) / "resources" / "maps" / "posture1.npz"))
    t = {"minimal": [], "all": [], "convenience": [], "tracker": [], "objects": [], "python": []}
    poses_fmu, poses_tr = np.empty((n, 3)), np.empty((n, 3))

    def fresh():
        unit.reset()
        unit.initialize(0.0, start)
        return unit.fmu.component

    for _ in range(passes):
        _fmu_pass(unit.fmu, fresh(), rows, io, t["minimal"], poses_fmu, everything=False)
        tracker.reset(X[0], Q[0])
        step, pc = tracker.step, time.perf_counter
        for k in range(n):
            t0 = pc()
            Xk, _ = step(Q[k], H)
            t["tracker"].append(pc() - t0)
            poses_tr[k] = Xk
        _fmu_pass(unit.fmu, fresh(), rows, io, t["all"], None, everything=True)
        os.environ["RRR_DK_FAST_LANE"] = "0"   # the same FMU without the loader's fast lane (all in Python)
        try:
            _fmu_pass(unit.fmu, fresh(), rows, io, t["python"], None, everything=False)
        finally:
            del os.environ["RRR_DK_FAST_LANE"]
        Tracker._objects = True                # the slave's tracker (the host's class) on the TrackerState path
        try:
            _fmu_pass(unit.fmu, fresh(), rows, io, t["objects"], None, everything=False)
        finally:
            Tracker._objects = False
        fresh()
        q_list, x_list = list(io["q"][0]), list(io["x"][0])
        for k, q in enumerate(rows):
            t0 = pc()
            unit.fmu.setReal(q_list, q)
            unit.fmu.doStep(k * H, H)
            unit.fmu.getReal(x_list)
            t["convenience"].append(pc() - t0)
    out = {k: _median_us(v) for k, v in t.items()}
    out["identical"] = bool(np.array_equal(poses_fmu, poses_tr))
    return out


def _io(unit) -> dict:
    """The value references and buffers of the DK FMU's raw calls, made once."""
    from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real

    return {"q": _arrays(unit, ("q1", "q2", "q3"), fmi2Real), "x": _arrays(unit, ("x", "y", "phi"), fmi2Real),
            "real": _arrays(unit, ("x", "y", "phi", "cond", "uncertain_since"), fmi2Real),
            "int": _arrays(unit, ("region", "n_real", "status"), fmi2Integer),
            "bool": _arrays(unit, ("near_border", "ambiguous", "certain"), fmi2Boolean)}


def _fmu_pass(fmu, c, rows, io, times: list, poses, everything: bool) -> None:
    """One pass of raw fmi2 calls over ``rows``: set the joints, doStep, get the pose (``everything``:
    every Real, Integer and Boolean output); each cycle's time appended to ``times``."""
    from fmpy.fmi2 import fmi2True

    pc = time.perf_counter
    set_real, do_step, get_real = fmu.fmi2SetReal, fmu.fmi2DoStep, fmu.fmi2GetReal
    get_int, get_bool = fmu.fmi2GetInteger, fmu.fmi2GetBoolean
    (q_vr, q_buf), (x_vr, x_buf) = io["q"], io["x"]
    (r_vr, r_buf), (i_vr, i_buf), (b_vr, b_buf) = io["real"], io["int"], io["bool"]
    for k, q in enumerate(rows):
        t0 = pc()
        q_buf[:] = q
        set_real(c, q_vr, 3, q_buf)
        do_step(c, k * H, H, fmi2True)
        if everything:
            get_real(c, r_vr, 5, r_buf)
            get_int(c, i_vr, 3, i_buf)
            get_bool(c, b_vr, 3, b_buf)
        else:
            get_real(c, x_vr, 3, x_buf)
        times.append(pc() - t0)
        if poses is not None:
            poses[k] = x_buf


def _closed_loop_inputs(paths) -> dict:
    """The default scenario's time series (the plant's and the controller's inputs at every step)."""
    from cosim import ClosedLoop, Scenario

    with ClosedLoop(paths) as loop:
        try:
            res = loop.run(Scenario(), flags=False)
        except TypeError:                    # a master from before issue 12 (for before/after runs)
            res = loop.run(Scenario())
    return res.columns


def _fmu_cycles(fmu, inputs, u_vr, u_buf, y_vr, y_buf, t):
    """Step an initialized FMU through ``inputs`` (n, len(u_buf)) at k*H with the raw fmi2 calls; append
    the doStep and set+doStep+get times (s) to ``t``; returns the first three outputs of every step."""
    from fmpy.fmi2 import fmi2True
    pc = time.perf_counter
    c = fmu.component
    set_real, do_step, get_real = fmu.fmi2SetReal, fmu.fmi2DoStep, fmu.fmi2GetReal
    nu, ny = len(u_buf), len(y_buf)
    first = np.empty((len(inputs), 3))
    for k, u in enumerate(inputs):
        t0 = pc()
        u_buf[:] = u
        set_real(c, u_vr, nu, u_buf)
        t1 = pc()
        do_step(c, k * H, H, fmi2True)
        t2 = pc()
        get_real(c, y_vr, ny, y_buf)
        t3 = pc()
        t["doStep"].append(t2 - t1)
        t["cycle"].append(t3 - t0)
        first[k] = y_buf[0:3]
    return first


def bench_plant(unit: FMUUnit, cols: dict, passes: int) -> dict:
    """The plant FMU replaying the closed loop's torques, against PlantStepper.step on them."""
    from fmpy.fmi2 import fmi2Real
    from dynamics import DynamicParameters, PlantStepper

    tau = np.stack([cols[f"tau{i}"] for i in (1, 2, 3)], axis=1)
    taus = [tuple(map(float, r)) for r in tau]
    X0 = (cols["x_true"][0], cols["y_true"][0], cols["phi_true"][0])
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2]}
    fmu = unit.fmu
    u_vr, u_buf = _arrays(unit, ("tau1", "tau2", "tau3"), fmi2Real)
    y_names = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true")
    y_vr, y_buf = _arrays(unit, y_names, fmi2Real)
    stepper = PlantStepper(DynamicParameters(), Manipulator.paper(), 1)
    pc = time.perf_counter
    t = {"doStep": [], "cycle": [], "in-process": []}
    same = True
    for _ in range(passes):
        unit.reset()
        unit.initialize(0.0, start)
        q_fmu = _fmu_cycles(fmu, taus, u_vr, u_buf, y_vr, y_buf, t)
        x = np.array([*X0, 0.0, 0.0, 0.0])
        outs = (np.empty(stepper.OUT_SIZE), np.empty(stepper.OUT_SIZE))
        q_in = np.empty((len(taus), 3))
        for k, u in enumerate(taus):
            out = outs[k % 2]
            t0 = pc()
            stepper.step(u[0], u[1], u[2], H, 1, x, out)
            t["in-process"].append(pc() - t0)
            x = out[:6]
            q_in[k] = out[6:9]
        same = same and bool(np.array_equal(q_fmu, q_in))
    res = {k: _median_us(v) for k, v in t.items()}
    res["identical"] = same
    return res


def bench_controller(unit: FMUUnit, cols: dict, passes: int, params: dict) -> dict:
    """The controller FMU replaying the closed loop's measurements, against ControllerStepper.step."""
    from fmpy.fmi2 import fmi2Real
    from dynamics import CircleTrajectory, ComputedTorqueGains, ControllerStepper, DynamicParameters

    names = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x", "y", "phi")
    inputs = [tuple(map(float, r)) for r in np.stack([cols[n] for n in names], axis=1)]
    fmu = unit.fmu
    u_vr, u_buf = _arrays(unit, names, fmi2Real)
    y_vr, y_buf = _arrays(unit, ("tau1", "tau2", "tau3", "x_ref", "y_ref", "phi_ref_out", "q1_ref", "q2_ref",
                                 "q3_ref"), fmi2Real)
    model = Manipulator.paper()
    traj = CircleTrajectory(center=params["center"], radius=params["radius"], phi=params["phi"], posture=1,
                            period=params["period"], ramp_time=params["ramp_time"])
    stepper = ControllerStepper(DynamicParameters(), model, ComputedTorqueGains.design(params["bandwidth"],
                                                                                        params["damping"]), traj)
    start = {"bandwidth": params["bandwidth"], "damping": params["damping"], "center_x": params["center"][0],
             "center_y": params["center"][1], "radius": params["radius"], "phi_ref": params["phi"],
             "period": params["period"], "ramp_time": params["ramp_time"],
             **dict(zip(names, inputs[0]))}
    pc = time.perf_counter
    t = {"doStep": [], "cycle": [], "in-process": []}
    out = np.empty(stepper.OUT_SIZE)
    same = True
    for _ in range(passes):
        unit.reset()
        unit.initialize(0.0, start)
        tau_fmu = _fmu_cycles(fmu, inputs, u_vr, u_buf, y_vr, y_buf, t)
        tau_in = np.empty((len(inputs), 3))
        step = stepper.step
        for k, u in enumerate(inputs):
            tk = k * H
            t0 = pc()
            step(tk, u[0], u[1], u[2], u[3], u[4], u[5], u[6], u[7], u[8], out)
            t["in-process"].append(pc() - t0)
            tau_in[k] = out[0:3]
        same = same and bool(np.array_equal(tau_fmu, tau_in))
    res = {k: _median_us(v) for k, v in t.items()}
    res["identical"] = same
    return res


def _verdict(fmu_us, inproc_us, ratio=1.5, extra_us=None) -> str:
    limit = ratio * inproc_us if extra_us is None else max(ratio * inproc_us, inproc_us + extra_us)
    return "meets" if fmu_us <= limit else "MISSES"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default=str(ROOT / "build"))
    ap.add_argument("--n", type=int, default=1000, help="points of the circle (DK)")
    ap.add_argument("--passes", type=int, default=7, help="alternating FMU / in-process passes")
    ap.add_argument("--instances", type=int, default=6, help="instantiations timed")
    args = ap.parse_args(argv)
    paths = build_fmus(args.build_dir)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}, load average {os.getloadavg()[0]:.2f}")
    dk_path = paths["RRRDirectKinematics"]
    print(f"DK FMU {dk_path}: {dk_path.stat().st_size / 1e6:.3f} MB")
    X0 = circle_path(3)[0]
    q0 = solver.ik(Manipulator.paper(), X0, 1)
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "q1": q0[0], "q2": q0[1], "q3": q0[2]}
    times, units = [], []
    for k in range(args.instances):
        t0 = time.perf_counter()
        unit = FMUUnit(dk_path, f"bench{k}")
        unit.initialize(0.0, start)
        times.append(time.perf_counter() - t0)
        units.append(unit)
    for unit in units[1:]:
        unit.close()
    print(f"DK instantiation + initialization: first {times[0] * 1e3:.1f} ms (extraction, slave module, map read "
          f"and check), later median {np.median(times[1:]) * 1e3:.1f} ms")

    dk = bench_dk(units[0], args.n, args.passes)
    # the FMI 3.0 DK FMU (q, pose as arrays) beside the FMI 2.0 one, passes alternating (bench/fmu3_step.py)
    v3 = fmu3_step.compare(units[0], fmu3_step.fmu3_path(args.build_dir), args.n, args.passes, _fmu_pass,
                           _io(units[0]))
    units[0].close()
    ratio = dk["minimal"] / dk["tracker"]
    print(f"\nDK, per step over the circle ({args.n} points x {args.passes} passes, h = 1 ms), median:")
    print(f"  FMU: fmi2SetReal(q) + fmi2DoStep + fmi2GetReal(x, y, phi)   {dk['minimal']:6.1f} us")
    print(f"  in-process Tracker.step(q, dt=h), same map and joints        {dk['tracker']:6.1f} us")
    print(f"  ratio {ratio:.2f}  (target <= 1.1: {_verdict(dk['minimal'], dk['tracker'], ratio=1.1)})")
    print(f"  FMU, reading all 11 outputs (+ getInteger, getBoolean)       {dk['all']:6.1f} us "
          f"(x{dk['all'] / dk['tracker']:.2f})")
    print(f"  FMU through fmpy's setReal/getReal (arrays per call)         {dk['convenience']:6.1f} us "
          f"(x{dk['convenience'] / dk['tracker']:.2f})")
    print(f"  FMU poses identical to the in-process tracker's: {dk['identical']}")
    print(f"  the same FMU cycle without the loader's fast lane (RRR_DK_FAST_LANE=0: the slave's Python)   "
          f"{dk['python']:6.1f} us (x{dk['python'] / dk['tracker']:.2f})")
    print(f"  the same FMU cycle with the tracker on its TrackerState path (every step packed and rebuilt in "
          f"Python, as before the compiled stepper)  {dk['objects']:6.1f} us")
    print("\nDK for FMI 3.0 (build/fmi3, FMU3Slave) beside FMI 2.0 (FMU2Slave), same run, passes alternating, median:")
    print(f"  FMI 3.0: fmi3SetFloat64(q[3]) + fmi3DoStep + fmi3GetFloat64(pose[3])  {v3['fmi3']:6.1f} us")
    print(f"  FMI 2.0: fmi2SetReal(q1..q3) + fmi2DoStep + fmi2GetReal(x, y, phi)    {v3['fmi2']:6.1f} us")
    print(f"  ratio {v3['fmi3'] / v3['fmi2']:.2f}  (target <= 1.2: {_verdict(v3['fmi3'], v3['fmi2'], ratio=1.2)}); "
          f"poses identical: {v3['identical']}")

    cols = _closed_loop_inputs(paths)
    from cosim import Scenario
    sc = Scenario()
    params = {"center": sc.center, "radius": sc.radius, "phi": sc.phi, "period": sc.period,
              "ramp_time": sc.ramp_time, "bandwidth": sc.bandwidth, "damping": sc.damping}
    n_steps = len(cols["time"])
    others = {}
    for name, fn, extra in (("RRRPlant", bench_plant, ()), ("ComputedTorqueController", bench_controller, (params,))):
        with FMUUnit(paths[name], f"bench-{name}") as unit:
            r = fn(unit, cols, args.passes, *extra)
        print(f"\n{name}, the closed loop's {n_steps} steps replayed x {args.passes} passes, median:")
        print(f"  FMU fmi2DoStep                              {r['doStep']:6.1f} us")
        print(f"  in-process step (the compiled call)         {r['in-process']:6.1f} us")
        print(f"  ratio {r['doStep'] / r['in-process']:.2f}, +{r['doStep'] - r['in-process']:.1f} us  "
              f"(target <= +2 us: {_verdict(r['doStep'], r['in-process'], ratio=1.0, extra_us=2.0)})")
        print(f"  FMU set + doStep + get cycle                {r['cycle']:6.1f} us")
        print(f"  FMU outputs identical to the in-process step's: {r['identical']}")
        others[name] = r
    _report(dk_path, times, dk, others, args, v3)
    return 0


def _report(dk_path, times, dk, others, args, v3):
    """The FMI path's table into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    ratio = dk["minimal"] / dk["tracker"]
    rows = [("DK FMU size", f"{dk_path.stat().st_size / 1e6:.3f} MB ({dk_path.stat().st_size:,} bytes)", ""),
            ("DK instantiation + initialization, first in the process / later (median)",
             f"{times[0] * 1e3:.0f} ms / {np.median(times[1:]) * 1e3:.0f} ms", ""),
            ("DK: `fmi2SetReal(q) + fmi2DoStep + fmi2GetReal(x, y, phi)` / in-process `Tracker.step`, medians",
             f"{dk['minimal']:.1f} / {dk['tracker']:.1f} us = {ratio:.2f}x", "<= 1.1x"),
            ("DK: the same cycle without the loader's fast lane (`RRR_DK_FAST_LANE=0`: set, doStep, get in the "
             "slave's Python)", f"{dk['python']:.1f} us = {dk['python'] / dk['tracker']:.2f}x", ""),
            ("DK, reading all outputs (+ getInteger, getBoolean)", f"{dk['all']:.1f} us", ""),
            ("DK: the same cycle with the tracker's TrackerState path (the step before the compiled stepper)",
             f"{dk['objects']:.1f} us", ""),
            ("DK poses identical to the in-process tracker's", dk["identical"], "True"),
            ("DK for FMI 3.0: `fmi3SetFloat64(q) + fmi3DoStep + fmi3GetFloat64(pose)` / the FMI 2.0 cycle, medians",
             f"{v3['fmi3']:.1f} / {v3['fmi2']:.1f} us = {v3['fmi3'] / v3['fmi2']:.2f}x", "<= 1.2x"),
            ("DK for FMI 3.0: poses identical to the FMI 2.0 FMU's", v3["identical"], "True")]
    for name, r in others.items():
        rows.append((f"{name}: `fmi2DoStep` / in-process step, medians",
                     f"{r['doStep']:.1f} / {r['in-process']:.1f} us = {r['doStep'] / r['in-process']:.2f}x "
                     f"(+{r['doStep'] - r['in-process']:.1f} us)", "<= +2 us"))
        rows.append((f"{name}: outputs identical to the in-process step's", r["identical"], "True"))
    publish("fmu", table(["what", "measured", "target"], rows),
            note=f"DK over the paper circle ({args.n} points x {args.passes} passes, h = 1 ms, map 10 mm / 2 deg); "
                 "plant and controller replay the closed loop's steps. FMU and in-process timed alternately in "
                 "the same run.",
            headline=[("DK FMU step through fmpy / the same tracker step in process", f"{ratio:.2f}x", "<= 1.1x"),
                      ("DK FMU size", f"{dk_path.stat().st_size / 1e6:.2f} MB", "")])


if __name__ == "__main__":
    exit_process(main())         # FMUs were loaded: skip the pythonfmu libraries' finalizers
