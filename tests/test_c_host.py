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

Interpreter discovery (the loader's ``python_runtime.c``): ``$RRR_DK_PYTHON`` first, a wrong one
named in a warning; the issue's moved environment (the recorded interpreter gone, its libpython
still there) runs with a ``python3`` on ``PATH`` that has the FMU's requirements, or, with none,
fails instantiation with every candidate and its reason, the missing interpreter and
``$RRR_DK_PYTHON`` named.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import CC, H, OUTPUTS, compile_host, host_case, no_python_env, output_table  # noqa: E402
from host_support import FMPY_HOST, run_python, session_fmus  # noqa: E402

STEPS = 100
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (cc or gcc) on PATH: the C host cannot be built")

@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    return compile_host(tmp_path_factory.mktemp("c_host"))


def _case(name: str, fmu: Path, work: Path):
    return host_case(name, fmu, work, STEPS)


@pytest.mark.parametrize("name", list(OUTPUTS))
def test_c_host_runs_the_fmu_without_python_as_fmpy_does(fmus, host, tmp_path, name):
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    args = [folder, name, guid, repr(H), str(STEPS), inputs, outputs, starts]
    py = run_python(FMPY_HOST, *args, timeout=600)
    assert py.returncode == 0 and "end" in py.stdout, py.stderr[-3000:]
    c = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=600, env=no_python_env(),
                       cwd=str(tmp_path))
    assert c.returncode == 0 and c.stdout.rstrip().endswith("end"), \
        f"status {c.returncode}\n{c.stdout[-1500:]}\n{c.stderr[-3000:]}"
    assert "python_before 0" in c.stdout, "the C host had Python before the FMU was loaded"
    assert "python_after 1" in c.stdout, "the FMU's loader did not bring in Python"
    a, b = output_table(c.stdout), output_table(py.stdout)
    assert a.shape == b.shape == (STEPS, 1 + len(OUTPUTS[name]))
    assert np.isfinite(a).all()
    diff = float(np.max(np.abs(a - b)))
    print(f"{name}: C host vs fmpy, {STEPS} steps, max |difference| {diff:.1e}")
    assert diff <= 1e-12
    if name == "RRRDirectKinematics":      # and the pose is the circle's: row k of the joints gives X[k]
        from solver import circle_path

        assert np.max(np.abs(a[:, 1:4] - circle_path(STEPS))) <= 1e-9


@pytest.mark.parametrize("name", list(OUTPUTS))
def test_c_host_fast_lane_gives_the_python_paths_rows(fmus, host, tmp_path, name):
    """In a host without Python of its own (the loader started it), the loader's fast lane answers the
    steps on the slave's arrays, calling into Python only at the border with the GIL it takes itself:
    the same rows, bit for bit, as with the lane off (every call through the slave's Python)."""
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    args = [str(host), folder, name, guid, repr(H), str(STEPS), inputs, outputs, starts]
    runs = {lane: subprocess.run(args, capture_output=True, text=True, timeout=600, cwd=str(tmp_path),
                                 env=no_python_env(RRR_DK_FAST_LANE=lane)) for lane in ("report", "0")}
    for lane, run in runs.items():
        assert run.returncode == 0 and run.stdout.rstrip().endswith("end"), (lane, run.stderr[-3000:])
        assert "fast lane dropped" not in run.stderr and "no fast lane" not in run.stderr, run.stderr[-2000:]
    assert np.array_equal(output_table(runs["report"].stdout), output_table(runs["0"].stdout))
    # the lane answered the steps (the slave's count at fmi2Terminate); none without it
    import re

    counts = re.findall(r"the fast lane answered (\d+) doSteps", runs["report"].stderr)
    assert len(counts) == 1 and int(counts[0]) >= STEPS - 3, runs["report"].stderr[-2000:]
    assert "the fast lane answered" not in runs["0"].stderr


def test_c_host_with_another_python_or_none(fmus, host, tmp_path):
    """$RRR_DK_PYTHON comes first (here the test's own interpreter); a wrong one is tried, named in a
    warning with why it failed, and the recorded interpreter runs the FMU instead."""
    name = "ComputedTorqueController"
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    args = [str(host), folder, name, guid, repr(H), "5", inputs, outputs, starts]
    good = subprocess.run(args, capture_output=True, text=True, timeout=600,
                          env=no_python_env(RRR_DK_PYTHON=sys.executable))
    assert good.returncode == 0 and good.stdout.rstrip().endswith("end"), good.stderr[-3000:]
    assert "not usable before it" not in good.stderr, good.stderr[-2000:]
    wrong = tmp_path / "no-such-python"
    bad = subprocess.run(args, capture_output=True, text=True, timeout=600, env=no_python_env(RRR_DK_PYTHON=str(wrong)))
    assert bad.returncode == 0 and bad.stdout.rstrip().endswith("end"), bad.stderr[-3000:]
    assert f"$RRR_DK_PYTHON {wrong}: missing" in bad.stderr and "using the interpreter recorded" in bad.stderr, \
        bad.stderr[-2000:]


def _moved(name: str, fmus, tmp_path: Path):
    """The issue's moved environment: the FMU's recorded interpreter no longer exists (its libpython does)."""
    folder, guid, inputs, outputs, starts = _case(name, fmus[name], tmp_path)
    record = Path(folder) / "resources" / "python_runtime.txt"
    gone = tmp_path / "moved-venv" / "bin" / "python"
    record.write_text("".join(f"python={gone}\n" if line.startswith("python=") else line + "\n"
                              for line in record.read_text().splitlines()))
    return [folder, name, guid, repr(H), "5", inputs, outputs, starts], gone


def test_moved_environment_runs_with_a_python3_on_path(fmus, host, tmp_path):
    """The recorded interpreter is gone, $RRR_DK_PYTHON unset: a python3 on PATH with the FMU's
    requirements (this test's interpreter's folder) runs the FMU, and a warning says which and why."""
    args, gone = _moved("RRRPlant", fmus, tmp_path)
    run = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=600,
                         env=no_python_env(PATH=str(Path(sys.executable).parent)))
    assert run.returncode == 0 and run.stdout.rstrip().endswith("end"), run.stderr[-3000:]
    assert "using python3 on PATH" in run.stderr and f"{gone}: missing" in run.stderr, run.stderr[-2000:]
    assert np.isfinite(output_table(run.stdout)).all()


def test_moved_environment_without_any_python_names_each_one_tried(fmus, host, tmp_path):
    """Nothing fits: fmi2Instantiate returns NULL (no crash) and the host's logger gets every candidate
    with why it failed, the missing recorded interpreter among them, and the fix ($RRR_DK_PYTHON)."""
    args, gone = _moved("RRRPlant", fmus, tmp_path)
    empty = tmp_path / "empty-bin"
    empty.mkdir()
    run = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=600,
                         env=no_python_env(PATH=str(empty)))
    err = run.stderr
    assert run.returncode == 1 and "fmi2Instantiate returned NULL" in err, (run.returncode, err[-2000:])
    logged = [line for line in err.splitlines() if line.startswith("[c_host 3 logStatusError]")]
    assert logged and "no Python interpreter fits the FMU RRRPlant" in logged[0], err[-2000:]
    for part in ("$RRR_DK_PYTHON: not set", f"(resources/python_runtime.txt) {gone}: missing",
                 "python3 on PATH: none found", "Fix: set $RRR_DK_PYTHON"):
        assert part in err, (part, err[-2000:])


@pytest.mark.parametrize("files", ["LOADER_FILES", "LOADER3_FILES"])
def test_the_loader_compiles_without_warnings(tmp_path, files):
    """The loaders' C files (cosim.fmus.native.LOADER_FILES: FMI 2.0, LOADER3_FILES: FMI 3.0) under
    -Wall -Wextra -Werror."""
    from cosim.fmus import native

    sources = [str(p) for p in getattr(native, files) if p.suffix == ".c"]
    proc = subprocess.run([CC, "-std=c11", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror",
                           "-Wno-format-truncation", "-o", str(tmp_path / "loader.so"), *sources, "-ldl", "-lpthread"],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
