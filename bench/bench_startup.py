"""Cold start: ``python -m cosim`` from process start to exit, where its time goes, the
first run of a batch worker, and the FMUs' own compiled kernels in a host without our packages.

    python bench/bench_startup.py [--build-dir build] [--repeat 5] [--skip-compile] [--only-cold]

The FMUs are built into ``--build-dir`` first if missing.  Every measurement runs in fresh
processes (``sys.executable``, the environment of this one, so ``PYTHONPATH=<another tree>``
measures that tree); each figure is the median over ``--repeat`` processes.  Prints:

1. the whole command, ``python -m cosim --build-dir ... --out <tmp>`` (the default 2.5 s
   scenario, CSV and plots; and with ``--no-plots``): wall time from process start to exit and its
   ratio to the 2.5 s it simulates (target: faster than real time, ratio < 1);
2. the cold-start split of that command, measured inside one such process: interpreter start,
   imports (the command's own imports), FMU load (extraction, instantiation and initialization of
   the three FMUs, without the kernel loads inside), kernel load (numba's cached machine code,
   loaded at the first call of each kernel: numba's ``Cache.load_overload``, wherever it
   happens), kernel compilation (0 when every cache is warm), the simulation loop, the CSV and the
   plots;
3. a batch worker's warm-up: a fresh process imports :mod:`cosim.batch.worker` and runs two
   short tasks (:func:`cosim.batch.run_task`, 0.05 s simulated): imports, FMU load (the first
   task's ``load_seconds``), the first-run warm-up (its ``init_seconds`` minus the second task's,
   as ``bench/bench_batch.py`` counts it; target: a few tenths of a second) and the whole
   start-up;
4. (unless ``--skip-compile``; ``--only-cold`` runs just this) the cold start of each FMU (the three
   of the loop, the 3-RPR's DK and the FMI 3.0 DK FMU, built first if missing) in a host that has
   not imported ``solver`` (fmpy's ``FMU2Slave``/``FMU3Slave`` in a fresh process: extract into a new
   folder, instantiate, initialize, 10 steps of 1 ms, timed inside): *cold* with empty caches
   (``NUMBA_CACHE_DIR`` and ``RRR_DK_CACHE`` = new empty folders: a machine that never ran it; the
   kernels come from the FMU's ``resources/kernels/``, :mod:`fmu_src.kernel_cache`), then *warm*
   (a second process with those caches); with the kernels compiled here (index files written to
   the caches: 0 when the FMU's own served every call) and whether the FMU announced a compile.
   Target: cold within 5 s for each;
5. (unless ``--skip-hosts``) each FMU's instantiate + initialize (setup, enter/exit initialization),
   timed inside fresh host processes that have not imported ``solver``: fmpy (``FMU2Slave``, Python
   in the process) and the C host of ``tests/test_c_host.py`` (no Python in the process: the FMU's
   loader starts it, :mod:`cosim.fmus.native`), first with an empty kernel cache (``NUMBA_CACHE_DIR`` = a
   new folder: the first process ever), then in a second process.  ``--only-hosts`` runs just this.

Numbers, no assertions.  The machine is shared: the load average is printed.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIMULATED = 2.5          # s, the default scenario
#: the children's working folder: not a source tree (``python -m``/``-c`` put it first on sys.path,
#: before PYTHONPATH), so the packages come from PYTHONPATH or the installed project
_NEUTRAL = tempfile.gettempdir()

#: the cold-start probe: the steps of ``python -m cosim`` with clocks (argv: build dir, out dir)
PROBE = r"""
import sys, time
T = {"start": time.perf_counter()}
import numba.core.caching as _caching, numba.core.dispatcher as _dispatcher
T["numba"] = time.perf_counter()
K = {"load": 0.0, "compile": 0.0}
_load = _caching.Cache.load_overload
def load_overload(self, *a, **k):
    t0 = time.perf_counter()
    try:
        return _load(self, *a, **k)
    finally:
        K["load"] += time.perf_counter() - t0
_caching.Cache.load_overload = load_overload
_compile = _dispatcher.Dispatcher.compile
def compile(self, sig):
    t0, l0 = time.perf_counter(), K["load"]
    try:
        return _compile(self, sig)
    finally:
        K["compile"] += time.perf_counter() - t0 - (K["load"] - l0)
_dispatcher.Dispatcher.compile = compile
def mark(name):
    T[name] = time.perf_counter()
    K[name] = (K["load"], K["compile"])
from cosim.__main__ import main          # the command's imports
from cosim import ClosedLoop, Scenario, build_fmus
from cosim.loop.results import plot_closed_loop, write_csv
mark("imports")
paths = build_fmus(sys.argv[1], progress=False)
loop = ClosedLoop(paths)                           # extract and instantiate
mark("fmu")
res = loop.run(Scenario())                         # initialize, then the loop (res.wall_seconds)
mark("run")
write_csv(res, sys.argv[2] + "/closed_loop.csv")
mark("csv")
plot_closed_loop(res, sys.argv[2] + "/figures")
mark("plots")
import json
out = {"total": T["plots"] - T["start"], "numba": T["numba"] - T["start"]}
prev, (l0, c0) = "numba", (0.0, 0.0)
for name in ("imports", "fmu", "run", "csv", "plots"):
    l1, c1 = K[name]
    out[name] = T[name] - T[prev] - (l1 - l0) - (c1 - c0)
    out[name + "_kernels"], out[name + "_compile"] = l1 - l0, c1 - c0
    prev, (l0, c0) = name, (l1, c1)
out["loop"] = res.wall_seconds
out["fmu"] += out["run"] - res.wall_seconds        # the run's initialization is FMU load
out["run"] = res.wall_seconds
print("PROBE " + json.dumps(out))
from cosim.unit import exit_process
exit_process(0)
"""

#: a batch worker's first tasks (argv: build dir)
WORKER = r"""
import sys, time, json
t0 = time.perf_counter()
from cosim.batch.worker import run_task
from cosim.batch.fmu_files import fmu_spec
from cosim import build_fmus
t_import = time.perf_counter() - t0
spec = fmu_spec(build_fmus(sys.argv[1], progress=False))
rows = [run_task(i, {"t_end": 0.05}, spec) for i in range(2)]
assert all(r["status"] == "ok" for r in rows), rows
print("WORKER " + json.dumps({"imports": t_import, "load": rows[0]["load_seconds"], "init1": rows[0]["init_seconds"],
                              "init2": rows[1]["init_seconds"], "sim": rows[1]["sim_seconds"]}))
from cosim.unit import exit_process
exit_process(0)
"""

#: an FMU's cold start in fmpy: extract, instantiate, initialize, 10 steps (argv: the FMU, extraction folder)
COLD_FMU = r"""
import sys, time, json
t0 = time.perf_counter()
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1], unzipdir=sys.argv[2]),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
fmu.instantiate()
t1 = time.perf_counter()
fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode(); fmu.exitInitializationMode()
t2 = time.perf_counter()
for k in range(10):
    fmu.doStep(k * 1e-3, 1e-3)
t3 = time.perf_counter()
solver = sys.modules.get("solver")
print("COLD " + json.dumps({"instantiate": t1 - t0, "initialize": t2 - t1, "steps": t3 - t2, "total": t3 - t0,
                            "bundled": solver is None or sys.argv[2] in (solver.__file__ or "")}))
import os
os._exit(0)
"""

#: the same for an FMI 3.0 FMU (fmpy's FMU3Slave)
COLD_FMU3 = COLD_FMU.replace("from fmpy.fmi2 import FMU2Slave", "from fmpy.fmi3 import FMU3Slave").replace(
    "FMU2Slave(guid=md.guid", "FMU3Slave(guid=md.guid").replace(
    "fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode()", "fmu.enterInitializationMode()")
#: the FMUs of the cold start (4.): name, file under the build folder, probe
COLD_FMUS = (("RRRDirectKinematics", "RRRDirectKinematics.fmu", COLD_FMU),
             ("RRRPlant", "RRRPlant.fmu", COLD_FMU),
             ("ComputedTorqueController", "ComputedTorqueController.fmu", COLD_FMU),
             ("RPRDirectKinematics", "RPRDirectKinematics.fmu", COLD_FMU),
             ("RRRDirectKinematics3 (FMI 3.0)", "fmi3/RRRDirectKinematics.fmu", COLD_FMU3))


#: an FMU's instantiate + initialize in fmpy, timed inside (argv: the FMU)
FMPY_START = r"""
import sys, time, json
t0 = time.perf_counter()
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="bench")
t1 = time.perf_counter()
fmu.instantiate()
t2 = time.perf_counter()
fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode(); fmu.exitInitializationMode()
t3 = time.perf_counter()
print("START " + json.dumps({"load": t1 - t0, "instantiate": t2 - t1, "initialize": t3 - t2}))
import os
os._exit(0)
"""


def _host_starts(build: Path, tmp: Path, env: dict) -> None:
    """5.: instantiate + initialize of each FMU in fresh fmpy and C host processes, empty cache then warm."""
    from fmpy import extract, read_model_description

    cc = shutil.which("cc") or shutil.which("gcc")
    host = tmp / "fmi2_host"
    if cc:
        subprocess.run([cc, "-std=c11", "-O1", "-o", str(host), str(ROOT / "tests/c_host/fmi2_host.c"), "-ldl"],
                       check=True)
    print("\n5. instantiate + initialize in a fresh host process without `solver` (timed inside the process; "
          "the C host has no Python until the FMU's loader starts it):")
    c_env = {k: v for k, v in env.items() if not k.startswith("PYTHON") and k != "VIRTUAL_ENV"}
    for name in ("RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"):
        fmu = build / f"{name}.fmu"
        md = read_model_description(str(fmu))
        folder = extract(str(fmu), unzipdir=str(tmp / f"{name}-c"))
        for host_name in ("fmpy", "C host"):
            if host_name == "C host" and not cc:
                print(f"   {name:25s} C host: skipped (no C compiler)")
                continue
            run_env = {**(env if host_name == "fmpy" else c_env), "NUMBA_CACHE_DIR": str(tmp / f"cache-{name}-{host_name}")}
            figures = []
            for _ in range(2):                 # empty kernel cache, then the second process
                t0 = time.perf_counter()
                if host_name == "fmpy":
                    r, wall = _python(FMPY_START, str(fmu), env=run_env, marker="START")
                else:
                    proc = subprocess.run([str(host), folder, name, md.guid, "1e-3", "0", "-", "0", "-"],
                                          capture_output=True, text=True, env=run_env, cwd=_NEUTRAL)
                    wall = time.perf_counter() - t0
                    if proc.returncode:
                        raise RuntimeError(f"C host failed ({proc.returncode}): {proc.stderr[-2000:]}")
                    r = dict(line.split() for line in proc.stdout.splitlines() if line.startswith("seconds_"))
                    r = {"instantiate": float(r["seconds_instantiate"]), "initialize": float(r["seconds_initialize"])}
                figures.append(f"{r['instantiate'] + r['initialize']:6.2f} s (instantiate {r['instantiate']:.2f} + "
                               f"initialize {r['initialize']:.2f}; process {wall:.2f} s)")
            print(f"   {name:25s} {host_name:6s}: first ever {figures[0]}; second process {figures[1]}")


def _python(code: str, *args, env=None, marker: str) -> tuple[dict, float]:
    """Run ``code`` in a fresh interpreter; its ``marker`` JSON line and the process's wall time."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env,
                          cwd=_NEUTRAL)
    wall = time.perf_counter() - t0
    for line in proc.stdout.splitlines():
        if line.startswith(marker + " "):
            return json.loads(line[len(marker) + 1:]), wall
    raise RuntimeError(f"{marker} probe failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")


def _command(build_dir, out_dir, plots: bool) -> float:
    args = [sys.executable, "-m", "cosim", "--build-dir", str(build_dir), "--out", str(out_dir)]
    if not plots:
        args.append("--no-plots")
    t0 = time.perf_counter()
    proc = subprocess.run(args, capture_output=True, text=True, cwd=_NEUTRAL)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return wall


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default=str(ROOT / "build"), help="folder of the FMUs (built there if stale)")
    ap.add_argument("--repeat", type=int, default=5, help="fresh processes per measurement")
    ap.add_argument("--skip-compile", action="store_true", help="skip the cold kernel compilation (4.)")
    ap.add_argument("--skip-hosts", action="store_true", help="skip the fmpy and C host start-up (5.)")
    ap.add_argument("--only-hosts", action="store_true", help="only the fmpy and C host start-up (5.)")
    ap.add_argument("--only-cold", action="store_true", help="only each FMU's cold start (4.)")
    args = ap.parse_args(argv)
    build = Path(args.build_dir).resolve()
    proc = subprocess.run([sys.executable, "-c", "import sys; from cosim import build_fmus; "
                           "build_fmus(sys.argv[1]); from cosim.unit import exit_process; exit_process(0)",
                           str(build)], cwd=_NEUTRAL)
    if proc.returncode:
        return proc.returncode
    for file, flags in (("RPRDirectKinematics.fmu", ["--manipulator", "3rpr"]),
                        ("fmi3/RRRDirectKinematics.fmu", ["--fmi", "3"])):        # --fmi 3 writes <out>/fmi3/
        if not (args.only_hosts or args.skip_compile) and not (build / file).is_file():
            subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), *flags, "--out", str(build), "--no-reference"],
                           check=True)
    print(f"python {platform.python_version()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; "
          f"FMUs in {build}; {args.repeat} fresh processes per figure (medians)")
    tmp = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    if args.only_cold:
        _cold_fmus(build, tmp)
    elif not args.only_hosts:
        _command_walls(build, tmp, args.repeat)
        _cold_split(build, tmp, args.repeat)
        _worker_start(build, args.repeat)
        if not args.skip_compile:
            _cold_fmus(build, tmp)
    if not args.only_cold and (args.only_hosts or not args.skip_hosts):
        _host_starts(build, tmp, dict(os.environ))
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


def _command_walls(build: Path, tmp: Path, repeat: int) -> None:
    """1. ``python -m cosim``, process start to exit (alternating with and without plots)."""
    walls = {"with plots": [], "--no-plots": []}
    for _ in range(repeat):
        walls["with plots"].append(_command(build, tmp / "a", True))
        walls["--no-plots"].append(_command(build, tmp / "b", False))
    print(f"\n1. `python -m cosim` ({SIMULATED:g} s simulated), process start to exit:")
    for key, v in walls.items():
        med = float(np.median(v))
        print(f"   {key:10s}: {med:5.2f} s wall = {med / SIMULATED:.2f}x the simulated time "
              f"[target < 1: {'meets' if med < SIMULATED else 'MISSES'}]  (runs: {', '.join(f'{w:.2f}' for w in v)})")


def _cold_split(build: Path, tmp: Path, repeat: int) -> None:
    """2. Where that command's time goes, one fresh process each."""
    probes = [_python(PROBE, str(build), str(tmp / "p"), marker="PROBE") for _ in range(repeat)]
    split = {k: float(np.median([p[k] for p, _ in probes])) for k in probes[0][0]}
    whole = float(np.median([w for _, w in probes]))
    print(f"\n2. cold-start split of that command (one process each, median of {repeat}; whole process "
          f"{whole:.2f} s):")
    phases = ("imports", "fmu", "run", "csv", "plots")
    rows = [("interpreter start and exit (python, site, os._exit)", whole - split["total"]),
            ("import numba", split["numba"]),
            ("the command's imports (dynamics, solver, fmu_src, fmpy)", split["imports"]),
            ("FMU load: extract, instantiate, initialize (3 FMUs)", split["fmu"]),
            ("kernel load: numba cache, all kernels of the process", sum(split[k + "_kernels"] for k in phases)),
            ("kernel compilation (0: every cache warm)", sum(split[k + "_compile"] for k in phases)),
            ("simulation: the loop of 2500 steps (wall_seconds)", split["run"]),
            ("CSV", split["csv"]),
            ("plots (matplotlib import + 3 figures)", split["plots"])]
    for label, v in rows:
        print(f"   {label:58s} {v:6.3f} s")
    print(f"   (of the kernel load: during the FMU load {split['fmu_kernels']:.3f} s, during the run's "
          f"initialization and loop {split['run_kernels']:.3f} s)")


def _worker_start(build: Path, repeat: int) -> None:
    """3. A batch worker's start-up before its first step, fresh processes."""
    workers = [_python(WORKER, str(build), marker="WORKER") for _ in range(repeat)]
    w = {k: float(np.median([p[k] for p, _ in workers])) for k in workers[0][0]}
    print("\n3. batch worker, fresh process (as bench/bench_batch.py splits it):")
    print(f"   imports {w['imports']:.3f} s; FMU load (extract + instantiate, once per process) {w['load']:.3f} s; "
          f"first-run warm-up (first initialization {w['init1'] * 1e3:.0f} ms - a later one "
          f"{w['init2'] * 1e3:.0f} ms) {max(w['init1'] - w['init2'], 0.0) * 1e3:.0f} ms")
    print(f"   the process's start-up before its first step, all in: "
          f"{w['imports'] + w['load'] + w['init1']:.2f} s (+ interpreter start)")


def _cold_fmus(build: Path, tmp: Path) -> None:
    """4. Each FMU's instantiate + initialize + 10 steps in fmpy, empty caches (cold), then warm."""
    print("\n4. cold start of each FMU in fmpy, host without `solver` (extract + instantiate + initialize + "
          "10 steps, timed inside a fresh process; cold: NUMBA_CACHE_DIR and RRR_DK_CACHE new empty folders):")
    for name, file, probe in COLD_FMUS:
        caches = tmp / f"cold-{file.replace('/', '-')}"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(caches / "numba"), RRR_DK_CACHE=str(caches / "rrr-dk"))
        env.pop("PYTHONPATH", None)                  # the FMU's own packages, as in a host without ours
        row = []
        for run, what in enumerate(("cold", "warm")):
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", probe, str(build / file),
                                   str(caches / f"x{run}")], capture_output=True, text=True, env=env, cwd=_NEUTRAL)
            wall = time.perf_counter() - t0
            line = next((x for x in proc.stdout.splitlines() if x.startswith("COLD ")), None)
            if line is None:
                raise RuntimeError(f"{name}: the cold-start probe failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
            r = json.loads(line[5:])
            compiled = sum(1 for sub in ("numba", "rrr-dk") for _ in (caches / sub).rglob("*.nbi"))
            row.append(f"{what} {r['total']:5.2f} s (instantiate {r['instantiate']:.2f}, initialize "
                       f"{r['initialize']:.2f}, 10 steps {r['steps']:.2f}; process {wall:.2f} s; kernels compiled "
                       f"so far {compiled}{', announced' if 'compiling' in proc.stderr else ''}"
                       f"{'' if r['bundled'] else '; NOT the bundled solver'})")
        cold = float(row[0].split()[1])
        print(f"   {name:25s} {row[0]}\n   {'':25s} {row[1]}  [target cold < 5 s: {'meets' if cold < 5 else 'MISSES'}]")


if __name__ == "__main__":
    sys.exit(main())
