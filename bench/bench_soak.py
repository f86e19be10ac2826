"""Soak benchmark: the closed loop through FMI for a million steps, then 100 new instances of each FMU.

    python bench/bench_soak.py [--build-dir build] [--steps 1000000] [--budget 1200] [--cycles 100]
                               [--fmi2-reset N]

Part 1, the loop.  :class:`cosim.ClosedLoop` builds and initializes the three FMUs (default
scenario, Gauss-Seidel, h = 1 ms); the loop makes the same FMI calls per step as
``ClosedLoop.run`` (its ``step_function``: set, doStep, get per instance) but keeps no rows, so that the process's memory
is the FMUs' own.  It runs ``--steps`` steps (the circle repeats every 2 s) or until ``--budget``
seconds have passed, and prints: the steps run (and the wall time of a million, extrapolated if
fewer), the wall time per step over the first and the last 10,000 steps, the peak RSS and the
RSS after 10,000 steps and at the end, and the largest |DK pose - true pose| (x, y, phi) at any step.

Part 2, instances.  ``--cycles`` times: free and instantiate again (``FMUUnit.reset``, what the
master does between runs) each of the three FMUs and run 10 steps; RSS before and after.  Then,
separately, ``--fmi2-reset`` calls of fmi2Reset on one DK instance, each followed by a legal run
(default 0; docs/reliability.md, known issues: three or more in a process have aborted it at exit).

The process exits through :func:`cosim.unit.exit_process` (os._exit once FMUs were loaded).
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WINDOW = 10_000


def rss_mb() -> float:
    """Current resident set size, MB (from /proc; the peak from getrusage)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return float("nan")


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def soak(fmus: dict, steps: int, budget: float) -> dict:
    """Part 1 (module docstring); returns the figures."""
    from cosim import ClosedLoop, Scenario
    from cosim.loop.calls import check
    from cosim.loop.master import INSTANCES

    loop = ClosedLoop(fmus)
    sc = Scenario()
    loop.initialize(sc, 0.0)
    ports = [loop.ports[inst] for inst in INSTANCES]
    by = {p.instance: p for p in ports}
    for p in ports:                                           # the outputs at initialization
        check(p.read_calls(False)[0][1](), p.instance, "fmi2GetReal")
    advance = loop.step_function(sc.order)
    dk_buf, pl_buf = by["dk"].buffers["Real"], by["plant"].buffers["Real"]
    dk_idx = [by["dk"].where[f"dk.{n}"][1] for n in ("x", "y", "phi")]
    pl_idx = [by["plant"].where[f"plant.{n}_true"][1] for n in ("x", "y", "phi")]
    (dx, dy, dp), (px, py, pp) = dk_idx, pl_idx
    h = sc.h
    drift = 0.0
    times, rss_after_window = [], None
    start = time.perf_counter()
    mark = start
    k = 0
    while k < steps:
        t = k * h
        xt, yt, pt = pl_buf[px], pl_buf[py], pl_buf[pp]       # the plant at t_k
        advance(t, h)
        e = max(abs(dk_buf[dx] - xt), abs(dk_buf[dy] - yt), abs(dk_buf[dp] - pt))
        if e > drift:
            drift = e
        k += 1
        if k % WINDOW == 0:
            now = time.perf_counter()
            times.append((now - mark) / WINDOW)
            mark = now
            if rss_after_window is None:
                rss_after_window = rss_mb()
            if now - start > budget:
                break
    wall = time.perf_counter() - start
    loop.close()
    return {"steps": k, "wall": wall, "first": times[0] if times else float("nan"),
            "last": times[-1] if times else float("nan"), "rss_start": rss_after_window, "rss_end": rss_mb(),
            "peak": peak_rss_mb(), "drift": drift}


def instances(fmus: dict, cycles: int, fmi2_reset: int) -> dict:
    """Part 2 (module docstring)."""
    from cosim.unit import FMUUnit

    units = {name: FMUUnit(path, f"cycle-{name}") for name, path in fmus.items()}
    out = {"rss_before": rss_mb()}
    start = time.perf_counter()
    for c in range(cycles):
        for unit in units.values():
            unit.reset()
            unit.initialize(0.0, {})
            for k in range(10):
                unit.fmu.doStep(k * 1e-3, 1e-3)
    out["wall"] = time.perf_counter() - start
    out["rss_after"] = rss_mb()
    dk = units["RRRDirectKinematics"]
    for r in range(fmi2_reset):
        dk.fmu.reset()
        dk.initialize(0.0, {})
        for k in range(10):
            dk.fmu.doStep(k * 1e-3, 1e-3)
    out["rss_after_reset"] = rss_mb()
    for unit in units.values():
        unit.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build-dir", default=str(ROOT / "build"))
    ap.add_argument("--steps", type=int, default=1_000_000)
    ap.add_argument("--budget", type=float, default=1200.0, help="seconds for the loop (part 1)")
    ap.add_argument("--cycles", type=int, default=100)
    ap.add_argument("--fmi2-reset", type=int, default=0, help="fmi2Reset calls on one DK instance (part 2)")
    args = ap.parse_args(argv)

    from cosim.fmus.fmu_set import build_fmus

    print(f"machine: {os.uname().machine}, {os.cpu_count()} cores, python {sys.version.split()[0]}, "
          f"load average {os.getloadavg()[0]:.2f}")
    fmus = build_fmus(Path(args.build_dir), progress=False)
    print(f"RSS after loading: {rss_mb():.1f} MB")
    s = soak(fmus, args.steps, args.budget)
    per_million = s["wall"] / max(s["steps"], 1) * 1e6
    print(f"closed loop, Gauss-Seidel, h = 1 ms: {s['steps']:,} steps in {s['wall']:.1f} s "
          f"({per_million:.0f} s per million{'' if s['steps'] >= 1_000_000 else ', extrapolated'})")
    print(f"  wall per step: first {WINDOW:,} steps {s['first'] * 1e6:.1f} us, last {WINDOW:,} "
          f"{s['last'] * 1e6:.1f} us (ratio {s['last'] / s['first']:.3f})")
    growth = (s["rss_end"] - s["rss_start"]) / s["rss_start"] * 100
    print(f"  RSS after {WINDOW:,} steps {s['rss_start']:.1f} MB, at the end {s['rss_end']:.1f} MB "
          f"({growth:+.2f} %); peak RSS {s['peak']:.1f} MB")
    print(f"  max |DK pose - true pose| over all steps: {s['drift']:.3g}")
    i = instances(fmus, args.cycles, args.fmi2_reset)
    print(f"{args.cycles} x (free + instantiate + initialize + 10 steps) of each of the three FMUs: "
          f"{i['wall']:.1f} s; RSS {i['rss_before']:.1f} -> {i['rss_after']:.1f} MB "
          f"({(i['rss_after'] - i['rss_before']) / i['rss_before'] * 100:+.2f} %)")
    if args.fmi2_reset:
        print(f"{args.fmi2_reset} x fmi2Reset of one DK instance (+ initialize + 10 steps): done; RSS "
              f"{i['rss_after_reset']:.1f} MB")
    sys.stdout.flush()
    from cosim.unit import exit_process
    exit_process(0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
