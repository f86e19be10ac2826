"""The FMUs in a C host with no Python in its process (issue 18), against fmpy's run of the same input.

``tests/c_host/fmi2_host.c`` (compiled here with the system compiler ``cc``, linked against libc
and libdl only) dlopens ``binaries/linux64/<modelIdentifier>.so`` of an extracted FMU and runs
fmi2Instantiate, the start values, fmi2SetupExperiment, enter/exit initialization, 100 fmi2DoStep
with inputs, fmi2GetReal after each, fmi2Terminate and fmi2FreeInstance.  The FMU's binary is the
loader of :mod:`cosim.fmus.native`: it opens libpython and starts the interpreter recorded at build
time.  The same call sequence runs in fmpy (``FMU2Slave``, a child Python process: a host that has
Python in-process, where the loader must not start a second interpreter), and the outputs must agree
to 1e-12; the C host must exit with status 0 (the exit crash of pythonfmu's wrapper, fixed in the
loader).  Inputs: the DK gets the joints of a circle (``solver.ik`` of ``solver.circle_path``),
the plant the reference torques, the controller its start values.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import run_python, session_fmus  # noqa: E402

HOST_SOURCE = Path(__file__).resolve().parent / "c_host" / "fmi2_host.c"
STEPS = 100
H = 1e-3
#: outputs compared per FMU
OUTPUTS = {"RRRDirectKinematics": ("x", "y", "phi", "cond", "uncertain_since"),
           "RRRPlant": ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true", "energy"),
           "ComputedTorqueController": ("tau1", "tau2", "tau3", "x_ref", "y_ref", "q1_ref")}
CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (cc or gcc) on PATH: the C host cannot be built")

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


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    """The C host, compiled with the system compiler; it links neither libpython nor anything else of Python."""
    exe = tmp_path_factory.mktemp("c_host") / "fmi2_host"
    proc = subprocess.run([CC, "-std=c11", "-O1", "-Wall", "-o", str(exe), str(HOST_SOURCE), "-ldl"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert b"libpython" not in exe.read_bytes(), "the C host must not link libpython"
    return exe


def _case(name: str, fmu: Path, work: Path):
    """(extracted folder, guid, inputs file or "-", output vrs, start values) of one FMU's run."""
    from fmpy import extract, read_model_description

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(str(fmu), unzipdir=str(work / f"{name}-unzipped"))
    starts, inputs = "-", "-"
    rows, names = None, ()
    if name == "RRRDirectKinematics":
        from solver import Manipulator, circle_path, ik

        X = circle_path(STEPS)
        q = ik(Manipulator.paper(), np.vstack([X, X[:1]]), 1)          # once round, back to the start
        rows, names = q, ("q1", "q2", "q3")
        starts = ",".join(f"{vr[n]}={v!r}" for n, v in zip(("x0", "y0", "phi0"), map(float, X[0])))
    elif name == "RRRPlant":
        t = np.arange(STEPS + 1) * H
        rows, names = np.column_stack([0.05 * np.sin(3 * t), -0.04 * np.cos(2 * t), 0.03 * np.sin(5 * t)]), \
            ("tau1", "tau2", "tau3")
    if rows is not None:
        inputs = work / f"{name}-inputs.txt"
        inputs.write_text(" ".join(str(vr[n]) for n in names) + "\n"
                          + "\n".join(" ".join(repr(float(v)) for v in row) for row in rows) + "\n")
    outputs = ",".join(str(vr[n]) for n in OUTPUTS[name])
    return folder, md.guid, str(inputs), outputs, starts


def _no_python_env() -> dict:
    """This process's environment without anything that would point an interpreter elsewhere."""
    return {k: v for k, v in os.environ.items()
            if not k.startswith("PYTHON") and k not in ("RRR_DK_PYTHON", "VIRTUAL_ENV")}


def _table(stdout: str) -> np.ndarray:
    lines = [line for line in stdout.splitlines() if line and line[0].isdigit()]
    return np.array([[float(v) for v in line.split()] for line in lines])


@pytest.mark.parametrize("name", list(OUTPUTS))
def test_c_host_runs_the_fmu_without_python_as_fmpy_does(fmus, host, tmp_path, name):
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    args = [folder, name, guid, repr(H), str(STEPS), inputs, outputs, starts]
    py = run_python(FMPY_HOST, *args, timeout=600)
    assert py.returncode == 0 and "end" in py.stdout, py.stderr[-3000:]
    c = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=600, env=_no_python_env(),
                       cwd=str(tmp_path))
    assert c.returncode == 0 and c.stdout.rstrip().endswith("end"), \
        f"status {c.returncode}\n{c.stdout[-1500:]}\n{c.stderr[-3000:]}"
    assert "python_before 0" in c.stdout, "the C host had Python before the FMU was loaded"
    assert "python_after 1" in c.stdout, "the FMU's loader did not bring in Python"
    a, b = _table(c.stdout), _table(py.stdout)
    assert a.shape == b.shape == (STEPS, 1 + len(OUTPUTS[name]))
    assert np.isfinite(a).all()
    diff = float(np.max(np.abs(a - b)))
    print(f"{name}: C host vs fmpy, {STEPS} steps, max |difference| {diff:.1e}")
    assert diff <= 1e-12
    if name == "RRRDirectKinematics":      # and the pose is the circle's: row k of the joints gives X[k]
        from solver import circle_path

        assert np.max(np.abs(a[:, 1:4] - circle_path(STEPS))) <= 1e-9


def test_c_host_with_another_python_or_none(fmus, host, tmp_path):
    """$RRR_DK_PYTHON picks the interpreter (here the test's own); a wrong one is refused with a message
    that names the variable, and the host gets NULL from fmi2Instantiate, not a crash."""
    name = "ComputedTorqueController"
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    args = [str(host), folder, name, guid, repr(H), "5", inputs, outputs, starts]
    good = subprocess.run(args, capture_output=True, text=True, timeout=600,
                          env={**_no_python_env(), "RRR_DK_PYTHON": sys.executable})
    assert good.returncode == 0 and good.stdout.rstrip().endswith("end"), good.stderr[-3000:]
    bad = subprocess.run(args, capture_output=True, text=True, timeout=600,
                         env={**_no_python_env(), "RRR_DK_PYTHON": str(tmp_path / "no-such-python")})
    assert bad.returncode == 1, (bad.returncode, bad.stderr[-2000:])
    assert "RRR_DK_PYTHON" in bad.stderr and "fmi2Instantiate returned NULL" in bad.stderr, bad.stderr[-2000:]
