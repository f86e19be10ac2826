"""The cost of the FMI 3.0 loader: the FMI 3.0 DK FMU's step with and without it, beside the FMI 2.0 DK FMU's.

    python bench/fmu3_loader.py [--n 1000] [--passes 15] [--work DIR]

Builds (into ``--work``, a temporary folder by default; the coarse map of the tests, 40 mm / 6 deg,
from the map cache) the FMI 2.0 DK FMU and the FMI 3.0 one, whose binary is the project's FMI 3.0
loader (``fmu_src/loader/fmi3_loader.c``) in front of pythonfmu3's wrapper; the FMU *without* the
loader is the same archive with pythonfmu3's wrapper back as the binary (what the build makes without
a C compiler).  Per communication step over the paper's circle (h = 1 ms), raw calls with buffers made
once (:class:`bench.fmu3_step._Dk3`, bench_fmu's FMI 2.0 pass): ``fmi3SetFloat64(q[3]) + fmi3DoStep +
fmi3GetFloat64(pose[3])`` through fmpy's ``FMU3Slave`` for both FMI 3.0 FMUs, ``fmi2SetReal + fmi2DoStep
+ fmi2GetReal`` for the FMI 2.0 one; each pass times the three in turn (the order rotating), medians;
the poses must be the FMI 2.0 FMU's bit for bit.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def without_loader(fmu: Path, out: Path) -> Path:
    """``fmu`` with pythonfmu3's wrapper as its binary again (no loader, no runtime record)."""
    from cosim.fmus.fmi3_build import DK3_NAME, PLATFORM
    from cosim.fmus.native import RUNTIME_FILE, WRAPPER3_NAME

    binary, wrapper = f"binaries/{PLATFORM}/{DK3_NAME}.so", f"binaries/{PLATFORM}/{WRAPPER3_NAME}"
    with zipfile.ZipFile(fmu) as z:
        entries = {i.filename: z.read(i) for i in z.infolist()}
    entries[binary] = entries.pop(wrapper)
    entries.pop(f"resources/{RUNTIME_FILE}")
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in entries.items():
            z.writestr(name, data)
    return out


def main(argv=None) -> None:
    import fmu3_step
    import numpy as np
    from bench_fmu import _fmu_pass, _io

    import solver
    from cosim.fmus import builds, fmi3_build, references
    from cosim.unit import FMUUnit
    from solver import Manipulator, circle_path

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="points of the circle")
    ap.add_argument("--passes", type=int, default=15, help="passes; each times the three FMUs in turn")
    ap.add_argument("--work", default=None, help="build folder (default: a temporary one)")
    args = ap.parse_args(argv)
    X = circle_path(args.n)
    Q = solver.ik(Manipulator.paper(), X, 1)
    rows = [tuple(map(float, q)) for q in Q]
    start = {"x0": X[0][0], "y0": X[0][1], "phi0": X[0][2], "q1": Q[0][0], "q2": Q[0][1], "q3": Q[0][2]}
    with tempfile.TemporaryDirectory(prefix="fmu3_loader_") as tmp:
        work = Path(args.work or tmp)
        kw = dict(postures=(1,), resolution=references.REFERENCE["resolution"], cache_dir=work / "maps",
                  log=lambda m: None)
        fmu2 = builds.build_dk(work / "fmi2", **kw).fmu
        loader = fmi3_build.build_dk3(work / "fmi3", **kw).fmu
        bare = without_loader(loader, work / "RRRDirectKinematics-no-loader.fmu")
        unit = FMUUnit(fmu2, "bench2")
        dk3 = {"with the loader": fmu3_step._Dk3(loader, X[0], Q[0]),
               "without the loader": fmu3_step._Dk3(bare, X[0], Q[0])}
        times = {label: [] for label in (*dk3, "FMI 2.0")}
        poses = {label: np.empty((args.n, 3)) for label in times}
        io = _io(unit)
        try:
            for k in range(args.passes):                 # the order turns each pass
                for label in list(times)[k % 3:] + list(times)[:k % 3]:
                    if label == "FMI 2.0":
                        unit.reset()
                        unit.initialize(0.0, start)
                        _fmu_pass(unit.fmu, unit.fmu.component, rows, io, times[label], poses[label],
                                  everything=False)
                    else:
                        dk3[label].fresh()
                        dk3[label].run(rows, times[label], poses[label])
        finally:
            for dk in dk3.values():
                dk.close()
            unit.close()
        med = {label: float(np.median(t) * 1e6) for label, t in times.items()}
        print(f"load average {os.getloadavg()[0]:.2f}; {args.n} steps x {args.passes} passes, medians per step:")
        for label in dk3:
            print(f"  FMI 3.0 {label:<19} {med[label]:6.1f} us  = {med[label] / med['FMI 2.0']:.3f} x FMI 2.0's "
                  f"{med['FMI 2.0']:.1f} us; poses identical to FMI 2.0: "
                  f"{bool(np.array_equal(poses[label], poses['FMI 2.0']))}")
        print(f"  the loader's cost: {med['with the loader'] / med['without the loader']:.3f} x")


if __name__ == "__main__":
    main()
