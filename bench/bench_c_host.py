"""The DK FMU's step from a C host (no Python in the host) against the tracker's compiled kernel.

    python bench/bench_c_host.py [--build-dir build] [--n 1000] [--runs 3]

The C host is ``tests/c_host/fmi2_host.c`` (compiled here with the system compiler): it dlopens the
FMU's loader, which starts Python itself, and per step sets q1..q3, calls fmi2DoStep and reads x, y,
phi; it prints the median of those steps.  The FMU is the one ``build_fmus`` puts in ``--build-dir``
(built if missing).  Runs alternate with the loader's fast lane on and off (``RRR_DK_FAST_LANE=0``:
every call through pythonfmu's wrapper into the slave's Python), and the in-process kernel is timed
in this process over the same joints (``Tracker.track``: the CPU's cycle counter around each step inside
compiled code).  Prints the medians and the ratio the compiled-step issue sets a target for (C host
step at most 1.1x the compiled kernel).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from cosim.fmus.fmu_set import build_fmus
from report import publish, table            # bench/ is on sys.path when a script there runs
from solver import Manipulator, MapTensor, Tracker, circle_path, ik

ROOT = Path(__file__).resolve().parents[1]
HOST = ROOT / "tests" / "c_host" / "fmi2_host.c"
H = 1e-3


def compile_host(folder: Path) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        sys.exit("bench_c_host: no C compiler (cc or gcc) on PATH")
    exe = folder / "fmi2_host"
    subprocess.run([cc, "-std=c11", "-O2", "-o", str(exe), str(HOST), "-ldl"], check=True)
    return exe


def host_run(exe: Path, folder: str, guid: str, vr: dict, q: np.ndarray, X0, work: Path, lane: bool) -> float:
    """The C host's median step (s) over the joints ``q`` (n + 1, 3)."""
    inputs = work / "inputs.txt"
    inputs.write_text(" ".join(str(vr[n]) for n in ("q1", "q2", "q3")) + "\n"
                      + "\n".join(" ".join(repr(float(v)) for v in row) for row in q) + "\n")
    starts = ",".join(f"{vr[n]}={float(v)!r}" for n, v in zip(("x0", "y0", "phi0"), X0))
    outputs = ",".join(str(vr[n]) for n in ("x", "y", "phi"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "VIRTUAL_ENV"}
    env["RRR_DK_FAST_LANE"] = "1" if lane else "0"
    proc = subprocess.run([str(exe), folder, "RRRDirectKinematics", guid, repr(H), str(len(q) - 1), str(inputs),
                           outputs, starts], capture_output=True, text=True, env=env)
    if proc.returncode:
        sys.exit(f"bench_c_host: the C host failed ({proc.returncode}): {proc.stderr[-2000:]}")
    line = next(s for s in proc.stdout.splitlines() if s.startswith("seconds_step_median"))
    return float(line.split()[1])


def kernel_median(map_path: Path, q: np.ndarray, X0) -> float:
    """The compiled kernel's median step (s) over ``q``, timed inside the compiled loop of ``track``."""
    tracker = Tracker(Manipulator.paper(), MapTensor.load(map_path))
    return float(np.median(tracker.track(q, X0).seconds[1:]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default=str(ROOT / "build"))
    ap.add_argument("--n", type=int, default=1000, help="points of the paper circle")
    ap.add_argument("--runs", type=int, default=3, help="C host runs per lane setting (alternating)")
    args = ap.parse_args(argv)
    from fmpy import extract, read_model_description

    fmu = build_fmus(args.build_dir)["RRRDirectKinematics"]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    X = circle_path(args.n)
    q = ik(Manipulator.paper(), np.vstack([X, X[:1]]), 1)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        folder = extract(str(fmu), unzipdir=str(work / "fmu"))
        exe = compile_host(work)
        host_run(exe, folder, md.guid, vr, q[:50], X[0], work, True)          # the first run loads the kernels
        kernel_median(Path(folder) / "resources" / "maps" / "posture1.npz", q[:50], X[0])
        lane, python, kernel = [], [], []
        for _ in range(args.runs):
            lane.append(host_run(exe, folder, md.guid, vr, q, X[0], work, True))
            python.append(host_run(exe, folder, md.guid, vr, q, X[0], work, False))
            kernel.append(kernel_median(Path(folder) / "resources" / "maps" / "posture1.npz", q, X[0]))
    k, f, p = (1e6 * float(np.median(v)) for v in (kernel, lane, python))
    verdict = "meets" if f <= 1.1 * k else "MISSES"
    rows = [("compiled kernel (in process, inside `track`'s loop)", f"{k:.2f} us", ""),
            ("C host: set q1..q3 + fmi2DoStep + get x, y, phi, fast lane", f"{f:.2f} us = {f / k:.2f}x", "<= 1.1x"),
            ("C host, the same without the fast lane (`RRR_DK_FAST_LANE=0`)", f"{p:.2f} us = {p / k:.2f}x", "")]
    body = table(["what (median step over the paper circle)", "measured", "target"], rows)
    print(f"DK FMU {fmu}, paper circle {args.n} points, h = {H} s, {args.runs} runs each (alternating)")
    print(body)
    print(f"C host with the fast lane / kernel: {f / k:.2f}x (target <= 1.1: {verdict})")
    publish("c_host", body, note=f"The C host of tests/c_host (no Python in its process) on the DK FMU built by "
            f"build_fmus, over the paper circle ({args.n} points, h = 1 ms); medians of {args.runs} runs per "
            "setting, alternating; the kernel timed in process inside the compiled loop of `track`.",
            command=" ".join(["python bench/bench_c_host.py", *(argv or sys.argv[1:])]),
            headline=[("DK FMU step from a C host (no Python in the host) / the compiled kernel", f"{f / k:.2f}x",
                       "<= 1.1x")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
