"""Shared by the tests of the FMUs in other hosts (test_ssp.py, test_hosts.py, test_exit.py,
test_c_host.py, test_host_life.py).

* :func:`session_fmus`: the three FMUs (DK map 40 mm / 6 deg), built once per test session into the
  session's temporary folder (:func:`cosim.fmus.fmu_set.build_fmus` reuses what is there).
* :func:`run_python`: a script in a child process (an FMU host of its own: the child loads the
  FMUs, not this process), with its exit status, stdout and stderr.
* The C host (``tests/c_host/fmi2_host.c``, no Python in its process): :func:`compile_host`,
  :func:`host_case` (its arguments for one FMU), :func:`no_python_env`, :func:`output_table`.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from cosim.fmus.fmu_set import build_fmus

#: the coarse map of the tests (fast to build; the tracker's answers do not depend on it)
RESOLUTION = (0.04, float(np.deg2rad(6.0)))
REPO = Path(__file__).resolve().parent.parent


def session_fmus(tmp_path_factory) -> dict:
    """{FMU name: path} of the three FMUs, built once per session (``<basetemp>/host-fmus``)."""
    return build_fmus(tmp_path_factory.getbasetemp() / "host-fmus", resolution=RESOLUTION, progress=False)


def run_python(code: str, *args, python: str | Path = sys.executable, cwd: Path | None = None,
               timeout: float = 600, tmpdir: Path | None = None,
               env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``code`` (dedented) as a script with ``args`` in a child ``python``; never raises on its status.
    ``tmpdir``: the child's temporary folder (``TMPDIR``; Ecos extracts every SSP it runs into one there
    and never removes it: 5 MB a run, left in /tmp otherwise); ``env``: variables set in the child besides
    this process's."""
    extra = dict(env or {})
    if tmpdir is not None:
        extra["TMPDIR"] = str(tmpdir)
    env = {**os.environ, **extra} if extra else None
    return subprocess.run([str(python), "-c", textwrap.dedent(code), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, cwd=str(cwd or REPO), env=env)


# ---------------------------------------------------------------------- the C host
HOST_SOURCE = Path(__file__).resolve().parent / "c_host" / "fmi2_host.c"
#: the system C compiler (None: the C host tests are skipped with that reason)
CC = shutil.which("cc") or shutil.which("gcc")
H = 1e-3
#: outputs compared per FMU
OUTPUTS = {"RRRDirectKinematics": ("x", "y", "phi", "cond", "uncertain_since"),
           "RRRPlant": ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true", "energy"),
           "ComputedTorqueController": ("tau1", "tau2", "tau3", "x_ref", "y_ref", "q1_ref")}
#: the outputs compared for the 3-RPR's DK FMU (built apart: :func:`cosim.fmus.rpr_build.build_rpr_dk`)
RPR_OUTPUTS = ("x", "y", "phi", "cond", "uncertain_since")


def compile_host(folder: Path) -> Path:
    """The C host, compiled with the system compiler into ``folder``; it links neither libpython nor
    anything else of Python."""
    exe = folder / "fmi2_host"
    proc = subprocess.run([CC, "-std=c11", "-O1", "-Wall", "-o", str(exe), str(HOST_SOURCE), "-ldl"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert b"libpython" not in exe.read_bytes(), "the C host must not link libpython"
    return exe


def host_case(name: str, fmu: Path, work: Path, steps: int, folder: Path | None = None):
    """(extracted folder, guid, inputs file or "-", output vrs, start values) of one FMU's run of
    ``steps`` steps: the DK gets the joints of a circle (``solver.ik`` of ``solver.circle_path``), the
    plant smooth torques, the controller its start values.  ``folder``: extract there (default
    ``work/<name>-unzipped``)."""
    from fmpy import extract, read_model_description

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(str(fmu), unzipdir=str(folder or work / f"{name}-unzipped"))
    starts, inputs = "-", "-"
    rows, names = None, ()
    if name == "RRRDirectKinematics":
        from solver import Manipulator, circle_path, ik

        X = circle_path(steps)
        q = ik(Manipulator.paper(), np.vstack([X, X[:1]]), 1)          # once round, back to the start
        rows, names = q, ("q1", "q2", "q3")
        starts = ",".join(f"{vr[n]}={v!r}" for n, v in zip(("x0", "y0", "phi0"), map(float, X[0])))
    elif name == "RPRDirectKinematics":                                  # round the loop about cusp 1
        from experiments.rpr_suite import cusp_loop_path
        from solver.rpr import RPRManipulator

        path = cusp_loop_path(RPRManipulator.zein_wenger_chablat(), 1, steps)
        rows, names = path.q, ("rho1", "rho2", "rho3")
        starts = ",".join(f"{vr[n]}={v!r}" for n, v in zip(("x0", "y0", "phi0"), map(float, path.X[0])))
    elif name == "RRRPlant":
        t = np.arange(steps + 1) * H
        rows, names = np.column_stack([0.05 * np.sin(3 * t), -0.04 * np.cos(2 * t), 0.03 * np.sin(5 * t)]), \
            ("tau1", "tau2", "tau3")
    if rows is not None:
        inputs = work / f"{name}-inputs.txt"
        inputs.write_text(" ".join(str(vr[n]) for n in names) + "\n"
                          + "\n".join(" ".join(repr(float(v)) for v in row) for row in rows) + "\n")
    outputs = ",".join(str(vr[n]) for n in OUTPUTS.get(name, RPR_OUTPUTS))
    return folder, md.guid, str(inputs), outputs, starts


#: fmpy's run of the C host's call sequence; same arguments, same output format
FMPY_HOST = """
    import sys
    from fmpy.fmi2 import FMU2Slave

    folder, model, guid, h, steps, inputs, outputs, starts = sys.argv[1:]
    h, steps, out_vr = float(h), int(steps), [int(v) for v in outputs.split(",")]
    in_vr, rows = [], []
    if inputs != "-":
        lines = open(inputs).read().split("\\n")
        in_vr = [int(v) for v in lines[0].split()]
        rows = [[float(v) for v in line.split()] for line in lines[1:] if line.strip()]
    fmu = FMU2Slave(guid=guid, unzipDirectory=folder, modelIdentifier=model, instanceName="fmpy_host")
    fmu.instantiate()
    for item in ([] if starts == "-" else starts.split(",")):
        vr, value = item.split("=")
        fmu.setReal([int(vr)], [float(value)])
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    if in_vr:
        fmu.setReal(in_vr, rows[0])
    fmu.exitInitializationMode()
    for k in range(steps):
        if in_vr:
            fmu.setReal(in_vr, rows[k])
        fmu.doStep(k * h, h)
        print(repr((k + 1) * h), *map(repr, fmu.getReal(out_vr)))
    fmu.terminate()
    fmu.freeInstance()
    print("end", flush=True)
"""


def no_python_env(**extra) -> dict:
    """This process's environment without anything that would point an interpreter elsewhere, plus ``extra``."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("PYTHON") and k not in ("RRR_DK_PYTHON", "VIRTUAL_ENV")}
    return {**env, **extra}


def output_table(stdout: str) -> np.ndarray:
    """The rows "t out..." of the C host's (or its fmpy twin's) stdout."""
    lines = [line for line in stdout.splitlines() if line and line[0].isdigit()]
    return np.array([[float(v) for v in line.split()] for line in lines])
