"""Speed of the direct-kinematics FMU through fmpy's FMU2Slave, against the in-process tracker.

    python bench/bench_fmu.py [--fmu build/RRRDirectKinematics.fmu] [--n 1000] [--repeat 5]

Builds the FMU with the default options first if ``--fmu`` does not exist (``fmu_src.builds.build_dk``).
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
import time
from pathlib import Path

import numpy as np

import solver  # noqa: F401  (first: the FMU then uses this copy of the package)
from fmu_src.unit import FMUUnit, exit_process, import_hygiene
from solver import Manipulator, MapTensor, Tracker, circle_path

ROOT = Path(__file__).resolve().parents[1]


def _initialize(unit, X0, q0):
    unit.initialize(0.0, {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "q1": q0[0], "q2": q0[1], "q3": q0[2]})


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fmu", default=str(ROOT / "build" / "RRRDirectKinematics.fmu"))
    ap.add_argument("--n", type=int, default=1000, help="points of the circle")
    ap.add_argument("--repeat", type=int, default=5, help="passes over the circle")
    ap.add_argument("--instances", type=int, default=10, help="instantiations timed")
    args = ap.parse_args(argv)

    from fmpy import extract, read_model_description

    fmu_path = Path(args.fmu)
    if not fmu_path.is_file():
        from fmu_src.builds import build_dk

        print(f"{fmu_path} missing: building it with the default options")
        fmu_path = build_dk(fmu_path.parent).fmu
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
    hygiene = import_hygiene()
    hygiene.__enter__()
    instances = []
    try:
        times = []
        for k in range(args.instances):
            t0 = time.perf_counter()
            unit = FMUUnit(fmu_path, f"bench{k}", unzip_dir=unzipdir)
            _initialize(unit, X[0], q[0])
            times.append(time.perf_counter() - t0)
            instances.append(unit)
        later = np.array(times[1:]) * 1e3
        print(f"instantiation + initialization: extract {t_extract * 1e3:.1f} ms, first {times[0] * 1e3:.1f} ms "
              f"(imports, map read and check), later median {np.median(later):.1f} ms")
        for unit in instances[1:]:
            unit.close()
        unit = instances[0]
        instances = [unit]
        fmu = unit.fmu

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
            unit.reset()
            _initialize(unit, X[0], q[0])
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
            unit.reset()
            _initialize(unit, X[0], q[0])
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
        for unit in instances:
            unit.close()
        hygiene.__exit__(None, None, None)
        shutil.rmtree(unzipdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    exit_process(main())         # FMUs were loaded: skip the pythonfmu libraries' finalizers
