"""Speed of the direct-kinematics FMU through fmpy's FMU2Slave, against the in-process tracker.

    python bench/bench_fmu.py [--fmu build/RRRDirectKinematics.fmu] [--n 1000] [--repeat 5]

Builds the FMU with the default options first if ``--fmu`` does not exist (``build_fmu.build``).
Prints:

- the FMU file size;
- instantiation time: extraction (fmpy.extract), the first fmi2Instantiate of the process (imports
  the slave module, reads and checks the embedded map) and the median of later ones, each followed
  by setupExperiment / enterInitializationMode / exitInitializationMode;
- per communication step over the paper's circle (``solver.circle_path(n)`` -> ``solver.ik``
  posture 1), median and 90th percentile of
  ``setReal(q1..q3) + doStep + getReal(x, y, phi, cond) + getInteger(region, n_real, status) +
  getBoolean(near_border, ambiguous)`` (all outputs), and of the minimal cycle
  ``setReal(q1..q3) + doStep + getReal(x, y, phi)`` (target <= 100 us);
- ``Tracker.step`` on the same joints and the same embedded map, measured in the same run, and the
  overhead of the FMU over it.

The host imports ``solver`` before loading the FMU (as any host that runs it repeatedly should), so
the FMU runs this process's compiled kernels.  Numbers, no assertions.
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import time
from ctypes import byref
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import solver  # noqa: E402,F401  (first: the FMU then uses this copy of the package)
from solver import Manipulator, circle_path  # noqa: E402
from solver.maptensor import MapTensor  # noqa: E402
from solver.tracker import Tracker  # noqa: E402


def _instance(md, unzipdir, name):
    import fmpy
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
    from fmpy.logging import addLoggerProxy

    messages = []

    def logger(_c, _n, status, _cat, message):
        messages.append((int(status), message.decode("utf-8", "replace")))

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
    addLoggerProxy(byref(cb))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=name)
    fmu._bench_keep = (cb, logger, messages)     # keep the callbacks alive as long as the instance
    return fmu


def _initialize(fmu, vr, X0, q0):
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr["x0"], vr["y0"], vr["phi0"]], list(map(float, X0)))
    fmu.setReal([vr["q1"], vr["q2"], vr["q3"]], list(map(float, q0)))
    fmu.exitInitializationMode()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fmu", default=str(ROOT / "build" / "RRRDirectKinematics.fmu"))
    ap.add_argument("--n", type=int, default=1000, help="points of the circle")
    ap.add_argument("--repeat", type=int, default=5, help="passes over the circle")
    ap.add_argument("--instances", type=int, default=10, help="instantiations timed")
    args = ap.parse_args(argv)

    from fmpy import extract, read_model_description

    from fmu_src.fmi_build import _fmu_hygiene

    fmu_path = Path(args.fmu)
    if not fmu_path.is_file():
        import build_fmu
        print(f"{fmu_path} missing: building it with the default options")
        fmu_path = build_fmu.build(fmu_path.parent).fmu
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    size = fmu_path.stat().st_size
    print(f"FMU {fmu_path}: {size / 1e6:.3f} MB ({size:,} bytes)")

    model = Manipulator.paper()
    X = circle_path(args.n)
    q = solver.ik(model, X, 1)
    h = 1e-3

    md = read_model_description(str(fmu_path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    t0 = time.perf_counter()
    unzipdir = extract(str(fmu_path))
    t_extract = time.perf_counter() - t0
    hygiene = _fmu_hygiene()
    hygiene.__enter__()
    instances = []
    try:
        times = []
        for k in range(args.instances):
            t0 = time.perf_counter()
            fmu = _instance(md, unzipdir, f"bench{k}")
            fmu.instantiate(loggingOn=False, callbacks=fmu._bench_keep[0])
            _initialize(fmu, vr, X[0], q[0])
            times.append(time.perf_counter() - t0)
            instances.append(fmu)
        later = np.array(times[1:]) * 1e3
        print(f"instantiation + initialization: extract {t_extract * 1e3:.1f} ms, first {times[0] * 1e3:.1f} ms "
              f"(imports, map read and check), later median {np.median(later):.1f} ms")
        for fmu in instances[1:]:
            fmu.terminate()
            fmu.freeInstance()
        fmu = instances[0]
        instances = [fmu]

        q_vr = [vr["q1"], vr["q2"], vr["q3"]]
        pose_vr = [vr["x"], vr["y"], vr["phi"]]
        real_vr = pose_vr + [vr["cond"]]
        int_vr = [vr["region"], vr["n_real"], vr["status"]]
        bool_vr = [vr["near_border"], vr["ambiguous"]]
        rows = [list(map(float, qk)) for qk in q]
        full, minimal, tracker_t = [], [], []
        pc = time.perf_counter
        poses_fmu = np.empty((args.n, 3))
        for rep in range(args.repeat):
            fmu.reset()
            _initialize(fmu, vr, X[0], q[0])
            t = 0.0
            for k, qk in enumerate(rows):
                t0 = pc()
                fmu.setReal(q_vr, qk)
                fmu.doStep(t, h)
                out = fmu.getReal(real_vr)
                fmu.getInteger(int_vr)
                fmu.getBoolean(bool_vr)
                full.append(pc() - t0)
                poses_fmu[k] = out[:3]
                t += h
            fmu.reset()
            _initialize(fmu, vr, X[0], q[0])
            t = 0.0
            for qk in rows:
                t0 = pc()
                fmu.setReal(q_vr, qk)
                fmu.doStep(t, h)
                fmu.getReal(pose_vr)
                minimal.append(pc() - t0)
                t += h
        # the in-process tracker on the same map (read from the extracted FMU) and joints
        mt = MapTensor.load(Path(unzipdir) / "resources" / "maps" / "posture1.npz")
        tr = Tracker(model, mt)
        poses_tr = np.empty((args.n, 3))
        for rep in range(args.repeat):
            tr.reset(X[0], q[0])
            for k in range(args.n):
                qk = q[k]
                t0 = pc()
                Xk, _ = tr.step(qk)
                tracker_t.append(pc() - t0)
                poses_tr[k] = Xk
        same = bool(np.array_equal(poses_fmu, poses_tr))
        full, minimal, tracker_t = (np.array(a) * 1e6 for a in (full, minimal, tracker_t))
        med_t = np.median(tracker_t)
        print(f"per step over the circle ({args.n} points x {args.repeat} passes), median / p90:")
        print(f"  FMU2Slave setReal(q) + doStep + get all 9 outputs: {np.median(full):6.1f} / "
              f"{np.percentile(full, 90):6.1f} us  (overhead over Tracker.step {np.median(full) - med_t:.1f} us, "
              f"x{np.median(full) / med_t:.1f})")
        print(f"  FMU2Slave setReal(q) + doStep + getReal(x, y, phi): {np.median(minimal):6.1f} / "
              f"{np.percentile(minimal, 90):6.1f} us  (target <= 100 us; overhead {np.median(minimal) - med_t:.1f} us)")
        print(f"  in-process Tracker.step (same map, same joints):   {med_t:6.1f} / {np.percentile(tracker_t, 90):6.1f} us")
        print(f"  FMU poses identical to the in-process tracker's: {same}")
    finally:
        for fmu in instances:
            try:
                fmu.terminate()
                fmu.freeInstance()
            except Exception:
                pass
        hygiene.__exit__(None, None, None)
        shutil.rmtree(unzipdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
