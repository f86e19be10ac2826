"""Speed of the closed loop (``python -m cosim``): per-step wall time against the tracker.

    python bench/bench_cosim.py [--build-dir build] [--rebuild] [--repeat 7] [--t-end 2.5]

The FMUs are built once into ``--build-dir`` by :func:`cosim.build_fmus` (reused when
present; ``--rebuild`` forces it).  Then, in one process (FMUs extracted and instantiated once):

1. the default scenario (2.5 s at h = 1 ms, Gauss-Seidel, three FMUs) is run ``--repeat`` times by
   the master itself (:meth:`cosim.ClosedLoop.run`, timed as ``python -m cosim``
   times it: the step loop and the result's columns, FMUs initialized), with the DK's flags
   (status, region... as ``python -m cosim`` records them) and without
   (``flags=False``: one set, doStep and get per FMU and step), with fmpy's methods for every call
   (``calls="fmpy"``, the master's path before :mod:`cosim.loop.calls`: the same calls and values)
   and with the loader's fast lanes off
   (``RRR_DK_FAST_LANE=0``: every FMI call through the slaves' Python); each run alternates with an
   in-process pass of ``solver.Tracker.step(q, dt=h)`` over the joints of the same run (the
   closed loop's own DK path, same embedded map).  Prints the wall time per step of each
   (mean over a run, median over the runs), the real-time factor and the ratio of the loop's step
   to one in-process tracker step (target: >= 30x real time; the ratio to the compiled loop without
   FMI of part 3 is the one that says how much FMI costs);
2. one more run of the same loop (the same fmpy calls in the same order as ``ClosedLoop.run``) with
   a clock around every FMU call, and a clock inside every slave's ``do_step``, ``get_*`` and
   ``set_real`` (the Python code of the slave, what the FMU's C wrapper calls); prints per call
   the median and mean over the steps, split into the slave's Python and the call overhead
   (fmpy's ctypes wrapper + pythonfmu's C wrapper + taking the GIL), the master's own overhead
   (copies between the calls, keeping the rows) and "where the time goes" as a table (mean us per
   step and share; the means include the machine's noise, the medians do not);
3. the reference: the same loop's math (plant RK4, computed torque, Newton DK) as one compiled loop
   without FMI (:mod:`reference_loop`), the limit the FMI loop is measured against, and the ratio.

The slaves import the host's ``dynamics``, ``solver`` and ``fmu_src`` runtime (imported first, as
the master does); the script also says whether the DK FMU's bundled copy of that runtime is the
working tree's (if not, the FMU predates its last change: ``--rebuild``).

The machine is shared (2 cores): the load average is printed; compare medians and ratios.
"""
from __future__ import annotations

import argparse
import os
import platform
import time
import zipfile
from pathlib import Path

import numpy as np

import dynamics  # noqa: F401  (before any FMU, as the master does)
import reference_loop                          # bench/ is on sys.path when a script there runs
from cosim import FMU_NAMES, INSTANCES, ClosedLoop, Scenario, build_fmus
from cosim.loop.calls import WORST_ACCEPTED
from cosim.fmus.packaging import bundled_files
from fmu_src.table_slave import TableSlave
from solver import Manipulator, MapTensor, Tracker

ROOT = Path(__file__).resolve().parents[1]

SHORT = {"RRRDirectKinematics": "DK", "ComputedTorqueController": "controller", "RRRPlant": "plant"}
#: the FMI calls of one Gauss-Seidel step of ClosedLoop.run (through fmpy's loaded functions), in order:
#: (label, FMU, kind)
CALLS = (("DK setReal q", "RRRDirectKinematics", "set_real"),
         ("DK doStep", "RRRDirectKinematics", "do_step"),
         ("DK getReal pose", "RRRDirectKinematics", "get_real"),
         ("DK getInteger status", "RRRDirectKinematics", "get_integer"),
         ("DK getBoolean flags", "RRRDirectKinematics", "get_boolean"),
         ("controller setReal q, dq, X", "ComputedTorqueController", "set_real"),
         ("controller doStep", "ComputedTorqueController", "do_step"),
         ("controller getReal tau, refs", "ComputedTorqueController", "get_real"),
         ("plant setReal tau", "RRRPlant", "set_real"),
         ("plant doStep", "RRRPlant", "do_step"),
         ("plant getReal q, dq, X", "RRRPlant", "get_real"))
_KIND = {"Real": "get_real", "Integer": "get_integer", "Boolean": "get_boolean"}
#: the timed runs of part 1: the master's direct calls with the DK's flags, without them, by fmpy's methods, and
#: with the loader's fast lanes off
LOOP_RUNS = ("flags", "no flags", "fmpy calls", "no lanes")


def _bundled_runtime(dk_fmu: Path) -> str:
    """Whether the DK FMU's copy of the fmu_src runtime is the working tree's."""
    here = ROOT / "fmu_src"
    files = bundled_files(ROOT / "fmu_src" / "RRRDirectKinematics.py", {"fmu_src": here})
    with zipfile.ZipFile(dk_fmu) as z:
        same = all(z.read(f"resources/{rel}") == src.read_bytes() for rel, src in files.items())
    return "same as" if same else "OLDER than"


class _SlaveClock:
    """Wraps methods of the slaves' shared base classes with a clock, bucketed per slave class name.

    The master re-instantiates the FMUs for every run (new slave class objects each time), so the
    clock goes where the methods are defined: ``TableSlave`` and pythonfmu's ``Fmi2Slave``.
    """

    def __init__(self, loop: ClosedLoop):
        self.times: dict = {}
        self._saved = []
        for meth in ("do_step", "get_real", "get_integer", "get_boolean", "set_real"):
            owner = next(c for c in TableSlave.__mro__ if meth in c.__dict__)
            self._wrap(owner, meth)

    def _wrap(self, cls, meth):
        orig = cls.__dict__[meth]
        times = self.times
        clock = time.perf_counter

        def timed(slave, *args):
            t0 = clock()
            out = orig(slave, *args)
            times.setdefault((type(slave).__name__, meth), []).append(clock() - t0)
            return out
        self._saved.append((cls, meth, orig))
        setattr(cls, meth, timed)

    def clear(self):
        for v in self.times.values():
            v.clear()

    def restore(self):
        for cls, meth, old in reversed(self._saved):
            setattr(cls, meth, old)


def instrumented_run(loop: ClosedLoop, sc: Scenario, on_start=None):
    """The loop of ClosedLoop.run (Gauss-Seidel, with the DK's flags) with a clock around every FMU
    call; ``on_start()`` is called right before the first step.

    Returns (calls (n, 11) s, step (n,) s): the duration of each call and of each whole step.
    """
    loop.initialize(sc, 0.0)
    ports = [loop.ports[inst] for inst in INSTANCES]
    (dk_set, ct_set, pl_set) = (p.set_inputs for p in ports)
    (dk_step, ct_step, pl_step) = (p.step_call() for p in ports)
    reads = [[call for _, call in p.read_calls()] for p in ports]
    (dk_real, dk_int, dk_bool), (ct_real,), (pl_real,) = reads
    assert [_KIND[k] for k, _ in loop.ports["dk"].read_calls()] == [m for _, _, m in CALLS[2:5]]
    bufs = [p.buffers[kind] for p in ports for kind in p.buffers]
    kept = [[] for _ in bufs]
    n, h = sc.n_steps, sc.h
    calls = np.zeros((n, len(CALLS)))
    step = np.zeros(n)
    clock = time.perf_counter
    for group in reads:
        for read in group:
            read()
    if on_start is not None:
        on_start()
    worst = 0                                                # the calls' worst FMI status, checked at the end
    for k in range(n):
        c = calls[k]
        t = k * h
        s0 = clock()
        a = clock(); s1 = dk_set()
        b = clock(); s2 = dk_step(t, h, 1)
        d = clock(); s3 = dk_real()
        e = clock(); s4 = dk_int()
        f = clock(); s5 = dk_bool()
        g = clock(); c[0], c[1], c[2], c[3], c[4] = b - a, d - b, e - d, f - e, g - f
        a = clock(); s6 = ct_set()
        b = clock(); s7 = ct_step(t, h, 1)
        d = clock(); s8 = ct_real()
        e = clock(); c[5], c[6], c[7] = b - a, d - b, e - d
        a = clock(); s9 = pl_set()
        b = clock(); s10 = pl_step(t, h, 1)
        d = clock(); s11 = pl_real()
        e = clock(); c[8], c[9], c[10] = b - a, d - b, e - d
        for buf, rows in zip(bufs, kept):
            rows.append(buf[:])
        step[k] = clock() - s0
        worst = max(worst, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10, s11)
    if worst > WORST_ACCEPTED:
        raise SystemExit(f"an FMI call of the instrumented run answered status {worst} (worse than fmi2Warning)")
    return calls, step


def tracker_pass(tracker, res, h: float) -> tuple[float, float]:
    """Mean wall and CPU time (s) of ``tracker.step(q, dt=h)`` over the joints of a closed-loop run."""
    Q = np.stack([res["q1"], res["q2"], res["q3"]], axis=1)
    X0 = np.array([res["x"][0], res["y"][0], res["phi"][0]])
    tracker.reset(X0, Q[0])
    step = tracker.step
    c0 = time.process_time()
    t0 = time.perf_counter()
    for k in range(1, len(Q)):
        step(Q[k], h)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return wall / (len(Q) - 1), cpu / (len(Q) - 1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default=str(ROOT / "build"), help="folder of the FMUs (built there if stale)")
    ap.add_argument("--rebuild", action="store_true", help="rebuild the three FMUs")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs of the default scenario")
    ap.add_argument("--t-end", type=float, default=Scenario.t_end, help="simulated time of each run, s")
    args = ap.parse_args(argv)

    paths = build_fmus(args.build_dir, force=args.rebuild)
    sc = Scenario(t_end=args.t_end)
    print(f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"scenario: {sc.t_end:g} s at h = {sc.h * 1e3:g} ms, {sc.order}, {sc.n_steps} steps; FMUs in "
          f"{Path(args.build_dir)}; the DK FMU's fmu_src runtime is "
          f"{_bundled_runtime(paths['RRRDirectKinematics'])} the working tree's")

    with ClosedLoop(paths) as loop:
        t0 = time.perf_counter()
        loop.run(Scenario(t_end=0.05))                       # numba caches loaded, first calls done
        print(f"warm-up (instantiate + first steps): {time.perf_counter() - t0:.2f} s")
        med, m = _timed_runs(loop, sc, args.repeat)
        clock = _SlaveClock(loop)
        try:
            instrumented_run(loop, Scenario(t_end=0.05))
            calls, step = instrumented_run(loop, sc, on_start=clock.clear)
        finally:
            clock.restore()
    parts, total = _breakdown(calls, step, clock)
    ref = reference_loop.measure(sc.t_end, sc.h, args.repeat)
    print(f"\n3. the same loop compiled, without FMI (bench/reference_loop.py: plant RK4, computed torque, "
          f"Newton DK): {ref['us']:.2f} us a step, {ref['real_time']:.0f}x real time (RMS joint error after "
          f"0.5 s {ref['rms']:.3g} rad); the FMI loop takes {med['flags', 'wall'] * 1e6 / ref['us']:.1f}x as long")
    _report(sc, med, m, parts, total, args, ref)


def _timed_runs(loop, sc, repeat: int):
    """Part 1: the master's loop with and without flags, alternating with the in-process tracker on
    each run's joints; returns the medians per step {(kind, clock): s} and the last run's metrics."""
    dk_dir = loop.units["RRRDirectKinematics"].unzip_dir
    tracker = Tracker(Manipulator.paper(), MapTensor.load(Path(dk_dir) / "resources" / "maps" / "posture1.npz"))
    print(f"\n1. the master's loop (ClosedLoop.run, as `python -m cosim`), {repeat} runs each, "
          f"alternating with the in-process tracker on each run's joints:")
    per = {(key, clock): [] for key in (*LOOP_RUNS, "tracker") for clock in ("wall", "cpu")}
    for r in range(repeat):
        for key, kw in (("flags", {}), ("no flags", {"flags": False}), ("fmpy calls", {}), ("no lanes", {})):
            if key == "no lanes":                         # every FMI call through the slaves' Python
                os.environ["RRR_DK_FAST_LANE"] = "0"
            for port in loop.ports.values():             # (a port binds its calls at each run)
                port.calls = "fmpy" if key == "fmpy calls" else "direct"
            try:
                res = loop.run(sc, **kw)
            finally:
                os.environ.pop("RRR_DK_FAST_LANE", None)
                for port in loop.ports.values():
                    port.calls = "direct"
            per[key, "wall"].append(res.wall_seconds / sc.n_steps)
            per[key, "cpu"].append(res.cpu_seconds / sc.n_steps)
            wall, cpu = tracker_pass(tracker, res, sc.h)
            per["tracker", "wall"].append(wall)
            per["tracker", "cpu"].append(cpu)
        m = res.metrics()
        print(f"   run {r + 1}: wall per step {1e6 * per['flags', 'wall'][-1]:.1f} us with flags, "
              f"{1e6 * per['no flags', 'wall'][-1]:.1f} without, {1e6 * per['fmpy calls', 'wall'][-1]:.1f} by fmpy's "
              f"methods, {1e6 * per['no lanes', 'wall'][-1]:.1f} without the fast lanes, "
              f"tracker {1e6 * per['tracker', 'wall'][-1]:.1f} us"
              f"  (RMS joint error after 0.5 s {m['rms_joint_error_after_0.5s']:.3e} rad, "
              f"max |DK - true| {m['max_dk_vs_true']:.1e})")
    med = {k: float(np.median(v)) for k, v in per.items()}
    for clock_name in ("wall", "cpu"):
        trk = med["tracker", clock_name]
        print(f"   {clock_name} time (median of the runs' mean per step), one in-process tracker step "
              f"{1e6 * trk:.1f} us:")
        for key in LOOP_RUNS:
            v = med[key, clock_name]
            ratio = v / trk
            print(f"     {key:10s}: {1e6 * v:6.1f} us per step = {sc.h / v:5.2f}x real time, {ratio:.2f}x the "
                  f"tracker step  [target >= 30x real time: {'meets' if sc.h / v >= 30 else 'MISSES'}]")
    print("   (CPU time leaves out what other processes took; on an idle machine the two agree)")
    return med, m


def _call_rows(calls, inner) -> list:
    """Per fmpy call of a step: (label, fmu, method, call time, the slave's own time, overhead), us."""
    counted, rows = {}, []
    for j, (label, fmu, meth) in enumerate(CALLS):
        # per-call slave time: the k-th slave call of this (fmu, meth) in step order
        key = (fmu, meth)
        times = inner.get(key, np.zeros(0))
        per_step = sum(1 for _, f2, m2 in CALLS if (f2, m2) == key)
        i0 = counted.get(key, 0)
        counted[key] = i0 + 1
        mine = times[i0::per_step][:len(calls)] if per_step and len(times) else np.zeros(len(calls))
        if len(mine) < len(calls):
            mine = np.zeros(len(calls))
        rows.append((label, fmu, meth, calls[:, j], mine, calls[:, j] - mine))
    return rows


def _breakdown(calls, step, clock):
    """Part 2: one instrumented run, per fmpy call and per part of a step; returns the parts (name,
    us per step) and the mean step, us."""
    us = 1e6
    calls, step = calls * us, step * us
    rows = _call_rows(calls, {k: np.array(v) * us for k, v in clock.times.items()})
    print(f"\n2. one instrumented run: {step.sum() / us:.3f} s of steps, per step median {np.median(step):.0f} us, "
          f"mean {step.mean():.0f} us, p90 {np.percentile(step, 90):.0f} us, max {step.max():.0f} us")
    print(f"\n   {'fmpy call':30s} {'median':>8s} {'mean':>8s}   {'slave Python':>12s} {'(mean)':>8s}   "
          f"{'call overhead':>13s}")
    for label, _, _, c, mine, over in rows:
        print(f"   {label:30s} {np.median(c):7.1f}  {c.mean():7.1f}   {np.median(mine):11.1f} "
              f"{mine.mean():8.1f}   {np.median(over):12.1f}")
    master = step - calls.sum(axis=1)
    print(f"   {'master (copies, rows)':30s} {np.median(master):7.1f}  {master.mean():7.1f}")
    print("\n   per-step median of each FMU's doStep (the whole fmpy call):")
    for label, fmu, meth, c, mine, over in rows:
        if meth == "do_step":
            print(f"     {SHORT[fmu]:10s} {np.median(c):6.1f} us   (slave's do_step {np.median(mine):5.1f} us, "
                  f"fmpy + C wrapper {np.median(over):4.1f} us)")
    # where the time goes (means: they add up to the wall time)
    total = step.mean()
    step_of = lambda k: [r for r in rows if r[2] == "do_step" and r[1] == FMU_NAMES[k]]   # noqa: E731
    # whole calls: behind the loader's fast lanes the compiled steps run inside them, without Python
    groups = [("DK doStep, whole call (the tracker's compiled step inside)", step_of(0), 3),
              ("controller doStep, whole call (the compiled law inside)", step_of(1), 3),
              ("plant doStep, whole call (the compiled RK4 inside)", step_of(2), 3),
              ("8 get/set calls, whole calls", [r for r in rows if r[2] != "do_step"], 3)]
    print("\n   where the time goes (mean per 1 ms step; wall budget for 10x real time: 100 us)")
    print(f"   | {'part':55s} | {'us/step':>7s} | {'share':>6s} |")
    print(f"   |{'-' * 57}|{'-' * 9}|{'-' * 8}|")
    parts = [(name, float(sum(r[col].mean() for r in sel))) for name, sel, col in groups]
    parts.append(("master: input copies, kept rows, bookkeeping", float(master.mean())))
    for name, v in parts:
        print(f"   | {name:55s} | {v:7.1f} | {100 * v / total:5.1f}% |")
    acc = sum(v for _, v in parts)
    print(f"   | {'total (instrumented; clocks add ~2 us)':55s} | {total:7.1f} | {100 * acc / total:5.1f}% |")
    python = float(sum(r[4].mean() for r in rows))
    print(f"   of which the slaves' Python inside the calls: {python:.1f} us a step (0 when the fast lanes "
          "answer every call)")
    return parts, total


def _report(sc, med, metrics, parts, total, args, ref):
    """The closed loop's timings and where a step's time goes into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    loop = []
    for key, label in (("flags", "with the DK's Integer/Boolean outputs (11 FMI calls)"),
                       ("no flags", "without them (9 FMI calls, `flags=False`)"),
                       ("fmpy calls", "with the flags, every call by fmpy's methods (`calls=\"fmpy\"`, the path "
                                      "before the master's direct calls)"),
                       ("no lanes", "with the flags, the loader's fast lanes off (`RRR_DK_FAST_LANE=0`)")):
        for clock in ("wall", "cpu"):
            v, trk = med[key, clock], med["tracker", clock]
            loop.append((f"{label}, {clock} time", f"{1e6 * v:.1f} us", f"{v / trk:.2f}x", f"{sc.h / v:.1f}x",
                         f"{1e6 * v / ref['us']:.1f}x"))
    loop.append(("reference: the same loop compiled without FMI (plant RK4, computed torque, Newton DK; "
                 "`bench/reference_loop.py`), wall time", f"{ref['us']:.2f} us", f"{1e-6 * ref['us'] / med['tracker', 'wall']:.2f}x",
                 f"{ref['real_time']:.0f}x", "1x"))
    body = (table(["closed loop per step", "time", "/ one in-process tracker step", "real time",
                   "/ the compiled reference loop"], loop)
            + f"\n\nLast run: RMS joint error after 0.5 s {metrics['rms_joint_error_after_0.5s']:.3e} rad, "
            f"max |DK pose - true pose| {metrics['max_dk_vs_true']:.1e}.\n\nWhere a step's time goes (one "
            "instrumented run, mean per step):\n\n"
            + table(["part", "us/step", "share"], [(n, f"{v:.1f}", f"{100 * v / total:.0f} %") for n, v in parts]))
    wall, trk = med["flags", "wall"], med["tracker", "wall"]
    publish("cosim", body, note=f"Default scenario, {sc.t_end:g} s at h = {sc.h * 1e3:g} ms, {sc.order}, "
            f"{args.repeat} runs alternating with the in-process tracker on each run's joints; medians.",
            headline=[("closed loop through FMI at 1 ms: wall per step / one in-process tracker step; real time",
                       f"{1e6 * wall:.0f} us = {wall / trk:.2f}x; {sc.h / wall:.1f}x real time",
                       ">= 30x real time"),
                      ("the same loop compiled without FMI (Newton DK): real time; the FMI loop / it",
                       f"{ref['real_time']:.0f}x; {1e6 * wall / ref['us']:.1f}x", "")])


if __name__ == "__main__":
    main()
