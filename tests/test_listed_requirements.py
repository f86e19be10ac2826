"""Each FMU in a host that installed exactly what the FMU lists (issue 41): fmpy and the C host.

A user who reads ``resources/requirements.txt`` and installs it, with fmpy, into a fresh virtual
environment must be able to run the FMU on a moving input: the list has to name every package the
bundled code needs at run time, also those it loads without an import statement (numba's ``@`` and
``np.dot`` call scipy's BLAS: without scipy the process aborts at the first step that reaches them).

For each FMU (the DK, plant and controller of the session, and the 3-RPR's DK) a virtual environment
under ``build/listed-host-<digest of the list>`` holds fmpy (this environment's version) and the
FMU's list, nothing of the project (made once, reused while the list's requirements and fmpy are the
same: the two DK FMUs share one, the plant and the controller another).  The
C host's call sequence (``tests/c_host/fmi2_host.c``: instantiate, start values, initialization, 100
steps on a moving input, terminate, free) runs through fmpy in that environment and through the C
host with ``$RRR_DK_PYTHON`` pointing at it; both exit 0 and their outputs equal those of this
project's environment (fmpy, a child process) to 1e-12.
"""
from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import zipfile
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from cosim.fmus.rpr_build import RPR_REFERENCE_RESOLUTION, build_rpr_dk
from fmu_src import requirements as req
from host_support import CC, FMPY_HOST, H, REPO, compile_host, host_case, no_python_env, output_table, run_python
from host_support import session_fmus

STEPS = 100
FMPY = version("fmpy")


@pytest.fixture(autouse=True)
def _no_project_path(monkeypatch):
    """The listed host is a process of its own environment: ``$PYTHONPATH`` of the one running the tests
    (a checkout put first on the path, as bench/bench_first_run.py does) must not hand it the project."""
    monkeypatch.delenv("PYTHONPATH", raising=False)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    built = dict(session_fmus(tmp_path_factory))
    built["RPRDirectKinematics"] = build_rpr_dk(tmp_path_factory.mktemp("rpr"), resolution=RPR_REFERENCE_RESOLUTION,
                                                log=lambda *a: None).fmu
    return built


def _listed_python(requirements: list) -> Path:
    """A virtual environment with fmpy and ``requirements`` (:class:`fmu_src.requirements.Requirement`) only,
    made once per set of them: FMUs whose lists differ only in their comments share one."""
    text = "".join(f"{r.spec}\n" for r in requirements)
    digest = hashlib.sha256((text + FMPY).encode()).hexdigest()[:12]
    venv = REPO / "build" / f"listed-host-{digest}"
    python = venv / "bin" / "python"
    marker = venv / "requirements.txt"
    if not (marker.is_file() and marker.read_text() == text and python.is_file()):
        shutil.rmtree(venv, ignore_errors=True)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, capture_output=True)
        listed = venv.parent / f"listed-{digest}.txt"
        listed.write_text(text)
        proc = subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                               f"fmpy=={FMPY}", "-r", str(listed)], capture_output=True, text=True, timeout=1200)
        assert proc.returncode == 0, f"pip install into {venv} failed:\n{proc.stderr[-3000:]}"
        marker.write_text(text)
    return python


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    if CC is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the C host cannot be built")
    return compile_host(tmp_path_factory.mktemp("c_host"))


@pytest.mark.parametrize("name", ["RRRDirectKinematics", "RPRDirectKinematics", "RRRPlant",
                                  "ComputedTorqueController"])
def test_a_host_with_exactly_the_listed_packages_runs_the_fmu(fmus, host, tmp_path, name):
    with zipfile.ZipFile(fmus[name]) as z:
        text = z.read(f"resources/{req.FILE}").decode()
    requirements = req.parse_requirements(text)
    listed = {r.module for r in requirements}
    assert "scipy" in listed, f"{name}: numba's BLAS and LAPACK need scipy at run time, the FMU does not list it"
    python = _listed_python(requirements)
    absent = run_python("import importlib.util as u; print(u.find_spec('solver'), u.find_spec('rrr_dk'))",
                        python=python, cwd=tmp_path)
    assert absent.stdout.split() == ["None", "None"], "the listed host must not see the project"
    folder, guid, inputs, outputs, starts = host_case(name, fmus[name], tmp_path, STEPS)
    args = [folder, name, guid, repr(H), str(STEPS), inputs, outputs, starts]
    ours = run_python(FMPY_HOST, *args, cwd=tmp_path)
    assert ours.returncode == 0 and "end" in ours.stdout, ours.stderr[-3000:]
    theirs = run_python(FMPY_HOST, *args, python=python, cwd=tmp_path, timeout=1200)
    assert theirs.returncode == 0 and "end" in theirs.stdout, \
        f"fmpy in {python.parent.parent}: status {theirs.returncode}\n{theirs.stderr[-3000:]}"
    env = no_python_env(RRR_DK_PYTHON=str(python))
    c = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=1200, env=env, cwd=str(tmp_path))
    assert c.returncode == 0 and c.stdout.rstrip().endswith("end"), \
        f"C host with $RRR_DK_PYTHON={python}: status {c.returncode}\n{c.stdout[-1500:]}\n{c.stderr[-3000:]}"
    assert "not usable before it" not in c.stderr, c.stderr[-2000:]
    a, b, c_out = output_table(ours.stdout), output_table(theirs.stdout), output_table(c.stdout)
    assert a.shape == b.shape == c_out.shape and a.shape[0] == STEPS and np.isfinite(a).all()
    assert np.ptp(a[:, 1], axis=0) > 0, f"{name}: the input did not move the output"
    diff = max(float(np.max(np.abs(a - b))), float(np.max(np.abs(a - c_out))))
    print(f"{name}: listed-requirements host (fmpy, C host) vs the project's, max |difference| {diff:.1e}")
    assert diff <= 1e-12
