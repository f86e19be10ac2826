"""The FMUs in hosts other than the project's: declared requirements, and the reason a host without
them gets (fmu_src.requirements, cosim.fmus.packaging).

The bare host is a virtual environment with fmpy only, made once under ``build/bare-host-venv``
(reused while its fmpy version matches this one's); it runs ``fmpy.simulate_fmu`` with default
arguments.  libcosim runs in the project's environment an FMU whose requirements list a package
that does not exist.
"""
import json
import os
import subprocess
import sys
import zipfile
from importlib.metadata import version
from pathlib import Path

import pytest

from fmu_src import requirements as req
from cosim.fmus.packaging import BuildError, declared_requirements, project_dependencies
from host_support import REPO, run_python, session_fmus

BARE = REPO / "build" / "bare-host-venv"
FMPY = version("fmpy")
#: what each FMU's code imports beyond the standard library, fmu_src, solver, dynamics and pythonfmu
# llvmlite: the step budget's clock (solver/_kernels/clock.py, in every bundle of the solver's kernels);
# scipy: numba's BLAS and LAPACK for ``@`` in compiled code (solver/_kernels/tube_chain.py), loaded at run time
IMPORTS = {"RRRDirectKinematics": {"llvmlite", "numba", "numpy", "scipy"},
           "ComputedTorqueController": {"control", "llvmlite", "numba", "numpy", "scipy"},
           "RRRPlant": {"control", "llvmlite", "numba", "numpy", "scipy"}}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


def _bare_python() -> Path:
    return BARE / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


@pytest.fixture(scope="module")
def bare_host():
    """A Python environment with fmpy (and what fmpy depends on) only."""
    marker = BARE / "fmpy-version.txt"
    if not (marker.is_file() and marker.read_text() == FMPY and _bare_python().is_file()):
        import shutil

        shutil.rmtree(BARE, ignore_errors=True)
        subprocess.run([sys.executable, "-m", "venv", str(BARE)], check=True, capture_output=True)
        proc = subprocess.run([str(_bare_python()), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                               f"fmpy=={FMPY}"], capture_output=True, text=True)
        assert proc.returncode == 0, f"pip install fmpy=={FMPY} into {BARE} failed:\n{proc.stderr[-3000:]}"
        marker.write_text(FMPY)
    return _bare_python()


# ---------------------------------------------------------------------- declared requirements
def test_each_fmu_declares_what_its_code_imports(fmus):
    deps = project_dependencies()
    for name, path in fmus.items():
        with zipfile.ZipFile(path) as z:
            text = z.read(f"resources/{req.FILE}").decode()       # where `pythonfmu deploy` looks
        declared = req.parse_requirements(text)
        assert {r.module for r in declared} == IMPORTS[name], name
        for r in declared:                                        # the ranges of pyproject.toml
            assert r.specifiers == deps[r.dist].specifiers and r.specifiers, (name, r)
        assert f"pythonfmu deploy -f {name}.fmu" in text


def test_pythonfmu_deploy_reads_the_requirements(fmus):
    """``pythonfmu deploy`` installs the FMU's requirements with pip (all present here: nothing to do)."""
    proc = subprocess.run([sys.executable, "-m", "pythonfmu", "deploy", "-f", str(fmus["RRRPlant"])],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Requirement already satisfied: numba" in proc.stdout


def test_an_undeclared_import_stops_the_build():
    with pytest.raises(BuildError, match=r"yaml_or_so \(imported by slave.py\).*pyproject.toml"):
        declared_requirements({"yaml_or_so": ["slave.py"]})


def test_requirements_file_round_trip_and_versions():
    reqs = [req.Requirement("numpy", ((">=", "1.26"),), "numpy"),
            req.Requirement("PyYAML", ((">=", "6"), ("<", "7")), "yaml")]
    text = req.format_requirements("M", reqs)
    assert req.parse_requirements(text) == sorted(reqs)
    assert "PyYAML>=6,<7  # import yaml" in text.splitlines()
    with pytest.raises(ValueError, match="line 1"):
        req.parse_requirements("numpy>>1\n")
    for have, op, want, ok in [("1.26.4", ">=", "1.26", True), ("1.25.2", ">=", "1.26", False),
                               ("0.7.0", "<", "0.8", True), ("0.8", "<", "0.8", False),
                               ("2.0.0rc1", ">=", "2.0", True), ("1.4.7", "~=", "1.4.5", True),
                               ("1.5.0", "~=", "1.4.5", False), ("1.26.4", "==", "1.26.*", True),
                               ("1.27", "!=", "1.26.*", True)]:
        assert req._satisfies(have, op, want) is ok, (have, op, want)


def test_require_names_missing_and_old_packages(tmp_path):
    script = tmp_path / "Slave.py"
    script.write_text("")
    req.require(str(script))                                       # no requirements.txt: nothing to check
    (tmp_path / req.FILE).write_text(req.format_requirements("Slave", [
        req.Requirement("numpy", ((">=", "1.0"),), "numpy"),
        req.Requirement("rrr-dk-absent", ((">=", "1"),), "rrr_dk_absent"),
        req.Requirement("numpy", ((">=", "999"),), "numpy")]))
    with pytest.raises(req.MissingRequirements) as info:
        req.require(str(script))
    exc = info.value
    assert isinstance(exc, ModuleNotFoundError) and exc.name == "rrr_dk_absent"
    text = str(exc)
    assert "Slave.fmu cannot run in this Python environment" in text and sys.executable in text
    assert "No module named 'rrr_dk_absent' (the FMU needs rrr-dk-absent>=1)" in text
    assert f"numpy {version('numpy')} is installed (the FMU needs numpy>=999)" in text
    assert f'{sys.executable} -m pip install "numpy>=999" "rrr-dk-absent>=1"' in text
    assert f'{sys.executable} -m pip install -r "{(tmp_path / req.FILE).resolve()}"' in text


def test_an_embedded_interpreter_is_named_by_a_python_that_exists(monkeypatch):
    """A host that started Python under a program name that is no file (pythonfmu's wrappers alone: ``<cwd>/
    PythonFMU``): the fix names the environment's own python, never the made-up path."""
    monkeypatch.setattr(sys, "executable", str(Path.cwd() / "PythonFMU"))
    named = req.interpreter()
    assert named and Path(named).is_file() and Path(named).name.startswith("python")
    assert Path(named).parent.parent in (Path(sys.prefix), Path(sys.base_prefix))
    assert "PythonFMU" not in req.install_command([req.Requirement("numpy", ((">=", "1"),), "numpy")])


# ---------------------------------------------------------------------- a host without the packages
BARE_RUN = """
    import json, sys
    import fmpy

    out = {}
    for path in sys.argv[1:]:
        try:
            fmpy.simulate_fmu(path, stop_time=0.01, step_size=1e-3)       # default arguments
            out[path] = "ran"
        except Exception as exc:
            out[path] = f"{type(exc).__name__}: {exc}"
    print(json.dumps(out))
"""


def test_a_host_without_the_packages_is_told_which_and_how(bare_host, fmus):
    proc = run_python(BARE_RUN, *fmus.values(), python=bare_host)
    assert proc.returncode == 0, proc.stderr[-3000:]               # fails cleanly, exits normally
    outcome = json.loads(proc.stdout.strip().splitlines()[-1])
    missing = run_python("import importlib.util as u, sys; "
                         "print(' '.join(m for m in sys.argv[1:] if u.find_spec(m) is None))",
                         *sorted(set().union(*IMPORTS.values())), python=bare_host).stdout.split()
    assert "numba" in missing
    for name, path in fmus.items():
        assert outcome[str(path)] == "Exception: Failed to instantiate model", name
        part = proc.stderr.split(f"{name}.fmu cannot run in this Python environment ({bare_host}, Python ")[1]
        part = part.split("or everything the FMU lists")[0]
        for module in sorted(IMPORTS[name]):
            assert (f"No module named {module!r}" in part) == (module in missing), (name, module)
        assert f"{bare_host} -m pip install " in part and '"numba>=' in part


# ---------------------------------------------------------------------- libcosim
LIBCOSIM_RUN = """
    import sys
    import fmpy
    from cosim.hosts.libcosim import LibcosimError, run_libcosim

    try:
        fmpy.simulate_fmu(sys.argv[1], stop_time=0.01, step_size=1e-3)
    except Exception as exc:
        print("fmpy:", exc, flush=True)
    try:
        run_libcosim(sys.argv[1], step_size=1e-3, n_steps=3)
    except LibcosimError as exc:
        print("libcosim:", exc, flush=True)
"""


def test_libcosim_and_fmpy_report_a_missing_package(fmus, tmp_path):
    """An FMU that needs a package this environment lacks: the reason reaches the user of
    libcosim (its error and log) and of fmpy (stderr), and neither host crashes."""
    path = tmp_path / "RRRPlant.fmu"
    with zipfile.ZipFile(fmus["RRRPlant"]) as z, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        for info in z.infolist():
            data = z.read(info)
            if info.filename == f"resources/{req.FILE}":
                data += b"rrr-dk-absent>=1.0  # import rrr_dk_absent\n"
            out.writestr(info, data)
    proc = run_python(LIBCOSIM_RUN, path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    reason = "No module named 'rrr_dk_absent' (the FMU needs rrr-dk-absent>=1.0)"
    assert "fmpy: Failed to instantiate model" in proc.stdout
    libcosim = proc.stdout.split("libcosim:", 1)[1]
    assert "could not instantiate" in libcosim and reason in libcosim and '-m pip install "rrr-dk-absent>=1.0"' in libcosim
    # fmpy's user reads it on stderr (Python logging's last resort; run_libcosim collects the slave log)
    assert f"RRRPlant.fmu cannot run in this Python environment ({sys.executable}" in proc.stderr
