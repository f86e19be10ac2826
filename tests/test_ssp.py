"""The closed loop as an SSP 1.0 package (cosim.hosts.ssp, cosim.hosts.system_files), run by Ecos and libcosim.

Ecos (ecospy) and libcosim each run in a child process from ``RRRClosedLoop.ssp`` alone: the
FMUs, connections and start values come from the package.  Both masters are Jacobi: every FMU
steps from the inputs of the previous communication point, then the outputs move along the
connections; the project's master with ``order="jacobi"`` is the reference.  Their rows are
sampled after each step (row k is time (k + 1) h), ours before it (row k is t_k).
"""
import json
import zipfile

import numpy as np
import pytest

from cosim import CONNECTIONS, INSTANCES, ClosedLoop, Scenario, start_values
from cosim.hosts.system_files import SSP_NAME, write_closed_loop_ssp
from cosim.hosts import ssp
from host_support import run_python, session_fmus
from solver import wrap_angle

SC = Scenario()                                     # the default scenario: 2.5 s at 1 ms
POSE = ("x", "y", "phi")
PLANT = ("q1", "q2", "q3", "dq1", "dq2", "dq3", "x_true", "y_true", "phi_true")
CONTROLLER = ("tau1", "tau2", "tau3")
#: the DK FMU's warning when its inputs at initialization are not the joints of its initial pose
INIT_WARNING = "are not the joints of the initial pose"


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def package(fmus):
    path = write_closed_loop_ssp(next(iter(fmus.values())).parent, SC)
    assert path.name == SSP_NAME
    return path


@pytest.fixture(scope="module")
def master(fmus):
    """The project's own master, Jacobi order, default scenario (this process)."""
    from dataclasses import replace

    with ClosedLoop(fmus) as loop:
        return loop.run(replace(SC, order="jacobi"))


def _ssd(package):
    import xml.etree.ElementTree as ET

    return ET.fromstring(ssp.read_system_structure(package))


def _pose_error(a, b):
    d = np.abs(np.asarray(a) - np.asarray(b))
    d[..., 2] = np.abs(wrap_angle(np.asarray(a)[..., 2] - np.asarray(b)[..., 2]))
    return d.max()


# ---------------------------------------------------------------------- the package
def test_package_holds_the_system_structure_and_the_fmus(package, fmus):
    with zipfile.ZipFile(package) as z:
        names = sorted(z.namelist())
        assert names == sorted(["SystemStructure.ssd", *(f"resources/{n}.fmu" for n in fmus)])
        for name, path in fmus.items():
            assert z.read(f"resources/{name}.fmu") == path.read_bytes()
    before = package.read_bytes()
    assert write_closed_loop_ssp(package.parent, SC).read_bytes() == before      # deterministic


def test_system_structure_passes_the_ssp_1_0_schemas(package):
    assert ssp.schema_problems(package) == []


def test_the_schema_check_finds_errors(package):
    bad = ssp.read_system_structure(package).replace(b'kind="input"', b'kind="sideways"', 1)
    assert any("kind" in p for p in ssp.schema_problems(bad))
    bad = ssp.read_system_structure(package).replace(b'<ssv:Real value=', b'<ssv:Real valeur=', 1)
    assert any("SystemStructureParameterValues.xsd" in p for p in ssp.schema_problems(bad))


def test_components_connections_and_start_values(package):
    S, V = f"{{{ssp.SSD}}}", f"{{{ssp.SSV}}}"
    root = _ssd(package)
    assert root.get("version") == "1.0"
    comps = {c.get("name"): c for c in root.iter(f"{S}Component")}
    assert {k: c.get("source") for k, c in comps.items()} == {i: f"resources/{n}.fmu" for i, n in INSTANCES.items()}
    conns = [(f"{c.get('startElement')}.{c.get('startConnector')}", f"{c.get('endElement')}.{c.get('endConnector')}")
             for c in root.iter(f"{S}Connection")]
    assert conns == list(CONNECTIONS)
    expected = start_values(SC)
    for inst, comp in comps.items():
        (pset,) = comp.iter(f"{V}ParameterSet")
        assert pset.get("name") == ssp.PARAMETER_SET
        got = {p.get("name"): next(iter(p)).get("value") for p in pset.iter(f"{V}Parameter")}
        assert set(got) == set(expected[inst])
        for name, value in expected[inst].items():
            assert float(got[name]) == pytest.approx(float(value), abs=0, rel=0), (inst, name)
    # the DK FMU starts from the plant's initial joints (no inconsistent q at initialization)
    assert all(expected["dk"][f"q{i}"] == expected["controller"][f"q{i}"] for i in (1, 2, 3))


def test_bad_systems_are_refused(fmus, tmp_path):
    one = {"plant": fmus["RRRPlant"]}
    with pytest.raises(ssp.SSPError, match="plant.tau1"):
        ssp.system_structure(one, connections=[("plant.tau1", "plant.q1")])
    with pytest.raises(ssp.SSPError, match=r"'q1'.*output"):
        ssp.system_structure(one, parameter_values={"plant": {"q1": 0.0}})
    with pytest.raises(ssp.SSPError, match="expected an Integer"):
        ssp.system_structure(one, parameter_values={"plant": {"posture": 1.5}})
    with pytest.raises(ssp.SSPError, match="unknown instances"):
        ssp.system_structure(one, parameter_values={"dk": {"x0": 0.5}})
    with pytest.raises(ssp.SSPError, match=r"\.ssp"):
        ssp.write_ssp(tmp_path / "x.zip", one)


# ---------------------------------------------------------------------- Ecos
ECOS_RUN = """
    import json, sys
    import numpy as np
    import solver, dynamics  # noqa: F401  (the FMUs use these copies: no numba compilation in the child)
    from ecospy import EcosSimulation

    ssp_path, h, n, pset, names, out = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), sys.argv[4], \\
        json.loads(sys.argv[5]), sys.argv[6]
    sim = EcosSimulation(ssp_path=ssp_path, step_size=h)
    sim.init(parameter_set=pset)
    init = [sim.get_real(v) for v in names]
    rows = []
    for _ in range(n):
        t = sim.step()
        rows.append([t] + [sim.get_real(v) for v in names])
    sim.terminate()
    sim.free()
    np.savez(out, rows=np.array(rows), init=np.array(init))
    print("ecos done", flush=True)
"""


@pytest.fixture(scope="module")
def ecos(package, tmp_path_factory):
    probe = run_python("import ecospy")          # in a child: this process loads no Ecos library
    if probe.returncode != 0:                     # ImportError, or OSError: no libtbb.so.12 (package libtbb12)
        pytest.skip("Ecos unavailable (pip install ecospy; apt-get install libtbb12): "
                    + probe.stderr.strip().splitlines()[-1])
    names = [f"dk::{v}" for v in POSE] + [f"plant::{v}" for v in PLANT] + [f"controller::{v}" for v in CONTROLLER]
    out = tmp_path_factory.mktemp("ecos") / "ecos.npz"
    proc = run_python(ECOS_RUN, package, SC.h, SC.n_steps, ssp.PARAMETER_SET, json.dumps(names), out,
                      tmpdir=out.parent)                      # (Ecos's extracted SSP stays in pytest's folder)
    assert "ecos done" in proc.stdout, proc.stderr[-3000:]
    data = np.load(out)
    cols = {name.split("::")[1]: data["rows"][:, i + 1] for i, name in enumerate(names)}
    init = {name.split("::")[1]: data["init"][i] for i, name in enumerate(names)}
    return proc, data["rows"][:, 0], cols, init


def test_ecos_runs_the_package_with_its_start_values(ecos):
    proc, t, cols, init = ecos
    assert proc.returncode == 0, proc.stderr[-3000:]
    np.testing.assert_allclose(t, SC.h * np.arange(1, SC.n_steps + 1), rtol=0, atol=1e-9)
    X0 = SC.start_pose
    # the DK's honest start: the DK solution of the plant's joints near X0, X0 within rounding
    assert _pose_error([init["x"], init["y"], init["phi"]], X0) < 1e-12
    assert _pose_error([init["x_true"], init["y_true"], init["phi_true"]], X0) == 0.0


def test_ecos_dk_pose_equals_the_true_pose_at_every_step(ecos):
    _, _, cols, _ = ecos
    dk = np.column_stack([cols[v] for v in POSE])
    true = np.column_stack([cols[f"{v}_true"] for v in POSE])
    print(f"Ecos, {SC.n_steps} steps: max |DK pose - true pose| = {_pose_error(dk, true):.2e}")
    assert _pose_error(dk, true) <= 1e-9


def test_ecos_is_the_jacobi_master(ecos, master):
    """Ecos's fixed-step algorithm = our order="jacobi": the same trajectory to 1e-9."""
    _, _, cols, _ = ecos
    n = SC.n_steps - 1
    worst = {}
    for name in PLANT + POSE:       # after step k Ecos shows time t_(k+1); the DK pose of the current q
        theirs, ours = cols[name][:n], master[name][1:n + 1]
        err = np.abs(wrap_angle(theirs - ours)) if name.startswith(("q", "phi")) else np.abs(theirs - ours)
        worst[name] = err.max()
    for name in CONTROLLER:         # the torque held over step k
        worst[name] = np.abs(cols[name] - master[name]).max()
    name = max(worst, key=worst.get)
    print(f"Ecos vs the project's Jacobi master, {SC.n_steps} steps: max difference {worst[name]:.2e} ({name})")
    assert worst[name] <= 1e-9, worst


def test_ecos_initializes_the_dk_fmu_without_a_warning(ecos):
    """Ecos passes the plant's outputs to the DK FMU before fmi2ExitInitializationMode: they hold the
    initial state's joints there (RRRPlant.initial_outputs), so the DK starts without a warning."""
    proc, *_ = ecos
    assert INIT_WARNING not in proc.stderr


# ---------------------------------------------------------------------- libcosim
LIBCOSIM_RUN = """
    import json, sys
    import numpy as np
    import solver, dynamics  # noqa: F401
    from cosim.hosts.libcosim import run_osp_system

    ssp_path, n, names, out = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3]), sys.argv[4]
    res = run_osp_system(ssp_path, n_steps=n, observe=names, log_level="warning")   # step: the SSD's
    np.savez(out, time=res.time, **{k: res[k] for k in names})
    print("libcosim done", flush=True)
"""


@pytest.fixture(scope="module")
def libcosim(package, tmp_path_factory):
    pytest.importorskip("libcosimpy")
    names = [f"dk.{v}" for v in POSE] + [f"plant.{v}" for v in PLANT] + [f"controller.{v}" for v in CONTROLLER]
    out = tmp_path_factory.mktemp("libcosim") / "libcosim.npz"
    proc = run_python(LIBCOSIM_RUN, package, SC.n_steps, json.dumps(names), out)
    assert "libcosim done" in proc.stdout, proc.stderr[-3000:]
    data = np.load(out)
    return proc, data["time"], {k.split(".")[1]: data[k] for k in names}


def test_libcosim_runs_the_package_like_the_jacobi_master(libcosim, master):
    """libcosim from the same package and start values: the DK pose is that of the joints the DK
    FMU stepped from (libcosim samples before moving the outputs), the true pose one step later."""
    proc, t, cols = libcosim
    np.testing.assert_allclose(t, SC.h * np.arange(1, SC.n_steps + 1), rtol=0, atol=1e-9)
    n = SC.n_steps - 1
    worst = {name: np.abs(wrap_angle(cols[name][:n] - master[name][1:n + 1])).max() for name in PLANT}
    worst.update({name: np.abs(wrap_angle(cols[name] - master[name])).max() for name in POSE + CONTROLLER})
    name = max(worst, key=worst.get)
    dk = np.column_stack([cols[v][1:] for v in POSE])
    true = np.column_stack([cols[f"{v}_true"][:-1] for v in POSE])
    print(f"libcosim vs the project's Jacobi master, {SC.n_steps} steps: max difference {worst[name]:.2e} "
          f"({name}); max |DK pose - true pose| = {_pose_error(dk, true):.2e}")
    assert worst[name] <= 1e-9, worst
    assert _pose_error(dk, true) <= 1e-9
