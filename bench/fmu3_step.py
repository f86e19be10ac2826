"""The FMI 3.0 DK FMU's step beside the FMI 2.0 DK FMU's, in the same run (``bench/bench_fmu.py`` prints it).

Per communication step over the paper's circle (h = 1 ms), raw calls with value references and
buffers made once: FMI 3.0 ``fmi3SetFloat64(q[3]) + fmi3DoStep + fmi3GetFloat64(pose[3])`` through
fmpy's ``FMU3Slave``, FMI 2.0 ``fmi2SetReal(q1..q3) + fmi2DoStep + fmi2GetReal(x, y, phi)`` through
``FMU2Slave``; the passes alternate, medians.  The FMI 3.0 FMU is built (same map, from the map cache)
into ``<build dir>/fmi3/`` when missing or older than its sources.
"""
from __future__ import annotations

import ctypes
import time
from pathlib import Path

import numpy as np

H = 1e-3

__all__ = ["fmu3_path", "compare"]


def fmu3_path(build_dir) -> Path:
    """``<build_dir>/fmi3/RRRDirectKinematics.fmu``, built first if missing or stale."""
    from cosim.fmus.fmu_set import is_stale
    from cosim.fmus.fmi3_build import DK3_FILE, DK3_NAME, build_dk3
    from cosim.fmus.sources import slave_script

    path = Path(build_dir) / "fmi3" / DK3_FILE
    adapter = slave_script(DK3_NAME).with_name("fmi3_adapter.py")
    if (not path.exists() or is_stale("RRRDirectKinematics", path)
            or path.stat().st_mtime < max(slave_script(DK3_NAME).stat().st_mtime, adapter.stat().st_mtime)):
        result = build_dk3(path.parent, log=lambda m: None)
        if result.problems:
            raise RuntimeError(f"{path}: " + "; ".join(result.problems))
    return path


class _Dk3:
    """The FMI 3.0 FMU through raw fmi3 calls (fmpy's FMU3Slave), reset and initialized per pass."""

    def __init__(self, path: Path, X0, q0):
        from fmpy import extract, read_model_description
        from fmpy.fmi3 import FMU3Slave

        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench3")
        self.fmu.instantiate()
        self.start = ([float(v) for v in X0], [float(v) for v in q0])

    def fresh(self):
        self.fmu.reset()
        self.fmu.setFloat64([self.vr["pose0"]], self.start[0])
        self.fmu.setFloat64([self.vr["q"]], self.start[1])
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def run(self, rows, times: list, poses) -> None:
        f = self.fmu
        c = f.component
        set_f, do_step, get_f = f.fmi3SetFloat64, f.fmi3DoStep, f.fmi3GetFloat64
        q_vr, x_vr = (ctypes.c_uint32 * 1)(self.vr["q"]), (ctypes.c_uint32 * 1)(self.vr["pose"])
        q_buf, x_buf = (ctypes.c_double * 3)(), (ctypes.c_double * 3)()
        event, term, early, last = ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(), ctypes.c_double()
        refs = (ctypes.byref(event), ctypes.byref(term), ctypes.byref(early), ctypes.byref(last))
        pc = time.perf_counter
        for k, q in enumerate(rows):
            t0 = pc()
            q_buf[:] = q
            set_f(c, q_vr, 1, q_buf, 3)
            do_step(c, k * H, H, True, *refs)
            get_f(c, x_vr, 1, x_buf, 3)
            times.append(pc() - t0)
            poses[k] = x_buf

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def compare(unit2, path3: Path, n: int, passes: int, fmu_pass, io) -> dict:
    """Medians (us) of the FMI 3.0 and FMI 2.0 step cycles over the circle, passes alternating, and
    whether their poses are identical.  ``unit2``: the FMI 2.0 DK FMU (:class:`cosim.unit.FMUUnit`);
    ``fmu_pass``/``io``: bench_fmu's raw FMI 2.0 pass and its buffers."""
    import solver
    from solver import Manipulator, circle_path

    X = circle_path(n)
    Q = solver.ik(Manipulator.paper(), X, 1)
    rows = [tuple(map(float, q)) for q in Q]
    start = {"x0": X[0][0], "y0": X[0][1], "phi0": X[0][2], "q1": Q[0][0], "q2": Q[0][1], "q3": Q[0][2]}
    dk3 = _Dk3(path3, X[0], Q[0])
    t2, t3 = [], []
    poses2, poses3 = np.empty((n, 3)), np.empty((n, 3))
    for _ in range(passes):
        unit2.reset()
        unit2.initialize(0.0, start)
        fmu_pass(unit2.fmu, unit2.fmu.component, rows, io, t2, poses2, everything=False)
        dk3.fresh()
        dk3.run(rows, t3, poses3)
    dk3.close()
    return {"fmi3": float(np.median(t3) * 1e6), "fmi2": float(np.median(t2) * 1e6),
            "identical": bool(np.array_equal(poses2, poses3))}
