"""The DK FMU and the closed loop's SSP in OMSimulator's command line (OpenModelica's SSP host).

OMSimulator 3.0's command line takes a system's type only from its own vendor annotation
(``ssc:Annotation type="org.openmodelica"`` with ``oms:SimulationInformation``): the SSD carries it
(:mod:`cosim.hosts.ssp`).  The checks of that annotation run everywhere.  The runs need the
``OMSimulator`` executable (on PATH, or named by ``$OMSIMULATOR``); without it they are skipped
with that reason (docs/fmus.md, section OMSimulator, says how to build it from source).

OMSimulator's fixed-step master (``oms-ma``) sets the inputs along the connections in the data-flow
order (reading the DK's pose after setting its joints: direct feedthrough) and then steps every FMU:
the controller gets the current pose, the plant the torque of the previous step.  The project's
master runs that order as ``order="omsimulator"``, the reference for OMSimulator's joints.
OMSimulator writes its CSV with 12 significant digits, so 1e-9 is far above its rounding.
"""
import csv
import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest

from cosim import INSTANCES, ClosedLoop, Scenario
from cosim.hosts import ssp
from cosim.hosts.system_files import write_closed_loop_ssp
from host_support import session_fmus
from solver import wrap_angle

SC = Scenario()                                     # the default scenario: 2.5 s at 1 ms
OMSIMULATOR = os.environ.get("OMSIMULATOR") or shutil.which("OMSimulator")
NOT_HERE = ("OMSimulator is not on PATH and $OMSIMULATOR is not set: the runs of the DK FMU and of the "
            "closed loop's SSP in OMSimulator's command line were NOT checked (docs/fmus.md, section "
            "OMSimulator, says how to build it from source)")
needs_omsimulator = pytest.mark.skipif(OMSIMULATOR is None, reason=NOT_HERE)
TOL = 1e-9


def _q(prefix, tag):
    return f"{{{ssp._PREFIXES[prefix]}}}{tag}"


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def package(fmus):
    return write_closed_loop_ssp(next(iter(fmus.values())).parent, SC)


def _fixed_step_master(ssd: bytes):
    """OMSimulator's reading of an SSD: the first ``ssc:Annotation`` of the system, if it is of type
    org.openmodelica, and its ``oms:FixedStepMaster`` (None where OMSimulator would find none)."""
    system = ET.fromstring(ssd).find(_q("ssd", "System"))
    first = system.find(f"{_q('ssd', 'Annotations')}/{_q('ssc', 'Annotation')}")
    if first is None or first.get("type") != "org.openmodelica":
        return None
    return first.find(f"{_q('oms', 'Annotations')}/{_q('oms', 'SimulationInformation')}/{_q('oms', 'FixedStepMaster')}")


def test_ssd_has_omsimulator_annotation(package):
    """The package's SSD: OMSimulator's fixed-step master at the scenario's step, the scenario's
    stop time in the default experiment, still SSP 1.0 schema-valid."""
    data = ssp.read_system_structure(package)
    master = _fixed_step_master(data)
    assert master is not None, "no org.openmodelica oms:FixedStepMaster as the system's first annotation"
    assert master.get("description") == "oms-ma"
    assert float(master.get("stepSize")) == SC.h
    root = ET.fromstring(data)
    assert float(root.find(_q("ssd", "DefaultExperiment")).get("stopTime")) == SC.t_end
    assert root.find(_q("ssd", "System"))[-1].tag == _q("ssd", "Annotations")   # the schema's place
    assert b'xmlns:oms="' in data and b"<oms:FixedStepMaster " in data           # OMSimulator reads "oms:"
    try:
        assert ssp.schema_problems(data) == []
    except ssp.SchemaUnavailable as exc:
        pytest.fail(f"the SSP 1.0 schemas are a test dependency: {exc}")


def test_annotation_follows_the_step(fmus):
    """The annotation carries the step it is given, and there is none without a step."""
    by_instance = {inst: fmus[name] for inst, name in INSTANCES.items()}
    master = _fixed_step_master(ssp.system_structure(by_instance, step_size=2.5e-3))
    assert float(master.get("stepSize")) == 2.5e-3
    assert _fixed_step_master(ssp.system_structure(by_instance)) is None


def test_master_omsimulator_order(fmus):
    """``order="omsimulator"``: per step, the inputs set in the data-flow order with the DK's pose
    read for the new joints before the controller's inputs, then every instance steps; its joints
    differ from both other orders (the torque reaches the plant one step late, the pose does not)."""
    calls = []
    with ClosedLoop(fmus) as loop:
        loop.initialize(SC, 0.0)
        for inst, port in loop.ports.items():          # each call answers its FMI status: 0, fmi2OK
            port.set_inputs = lambda inst=inst: calls.append(f"{inst}.set") or 0
            port.step_call = lambda inst=inst: lambda t, h, flag: calls.append(f"{inst}.step") or 0
            port.read_calls = lambda flags=True, inst=inst: (("Real", lambda: calls.append(f"{inst}.get") or 0),)
        loop.step_function("omsimulator")(0.0, SC.h)
    assert calls == ["dk.set", "dk.get", "controller.set", "controller.get", "plant.set",
                     "dk.step", "controller.step", "plant.step", "dk.get", "controller.get", "plant.get"]
    short = replace(SC, t_end=0.2)
    with ClosedLoop(fmus) as loop:
        q = {order: np.column_stack([loop.run(replace(short, order=order))[f"q{i}"] for i in (1, 2, 3)])
             for order in ("omsimulator", "jacobi", "gauss-seidel")}
    for other in ("jacobi", "gauss-seidel"):
        assert np.abs(q["omsimulator"] - q[other]).max() > 1e-9, other
    with pytest.raises(ValueError, match="order"):
        Scenario(order="oms")


def _run(*args, cwd):
    proc = subprocess.run([OMSIMULATOR, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=900)
    assert proc.returncode == 0, (f"OMSimulator {' '.join(map(str, args))}: exit {proc.returncode}\n"
                                  f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def _result(path) -> tuple[np.ndarray, dict]:
    """OMSimulator's CSV: the last row of each communication point (it may write a point twice,
    before and after moving the outputs along the connections), {variable: column}."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        head = next(reader)
        rows = np.array([[float(v) for v in row] for row in reader])
    k = np.rint(rows[:, 0] / SC.h).astype(int)
    last = np.flatnonzero(np.append(k[1:] != k[:-1], True))
    names = [h.split(".", 2)[-1] if h.count(".") >= 2 else h for h in head]   # model.system.instance.var
    return rows[last], {name: i for i, name in enumerate(names)}


def _pose_error(a, b):
    d = np.abs(a - b)
    d[:, 2] = np.abs(wrap_angle(a[:, 2] - b[:, 2]))
    return d.max()


@needs_omsimulator
def test_dk_fmu_in_omsimulator(fmus, tmp_path):
    """The DK FMU alone: exit 0; its inputs stay at the start joints, so every row holds the start
    pose (its start values), certain."""
    from fmpy import read_model_description

    fmu = fmus["RRRDirectKinematics"]
    _run(fmu, "--stopTime=0.1", "--resultFile=dk.csv", cwd=tmp_path)
    rows, col = _result(tmp_path / "dk.csv")
    start = {v.name: float(v.start) for v in read_model_description(str(fmu)).modelVariables
             if v.name in ("x0", "y0", "phi0")}
    assert rows[-1, 0] == pytest.approx(0.1) and len(rows) == 101
    pose = rows[:, [col["x"], col["y"], col["phi"]]]
    assert _pose_error(pose, np.array([[start["x0"], start["y0"], start["phi0"]]] * len(rows))) <= TOL
    assert (rows[:, col["certain"]] == 1).all()


@needs_omsimulator
def test_closed_loop_ssp_in_omsimulator(fmus, package, tmp_path):
    """``OMSimulator RRRClosedLoop.ssp --stopTime=2.5``: exit 0; the DK pose is the plant's true pose;
    the joints are the project's master's in OMSimulator's order (and not in the Gauss-Seidel one)."""
    _run(package, f"--stopTime={SC.t_end}", "--resultFile=loop.csv", cwd=tmp_path)
    rows, col = _result(tmp_path / "loop.csv")
    assert rows[-1, 0] == pytest.approx(SC.t_end) and len(rows) == SC.n_steps + 1
    pick = lambda *names: rows[:, [col[n] for n in names]]            # noqa: E731
    assert _pose_error(pick("dk.x", "dk.y", "dk.phi"), pick("plant.x_true", "plant.y_true", "plant.phi_true")) <= TOL
    oq = pick("plant.q1", "plant.q2", "plant.q3")[:SC.n_steps]       # our row k is t_k
    with ClosedLoop(fmus) as loop:
        q = {order: np.column_stack([loop.run(replace(SC, order=order))[f"q{i}"] for i in (1, 2, 3)])
             for order in ("omsimulator", "gauss-seidel")}
    assert np.abs(wrap_angle(q["omsimulator"] - oq)).max() <= TOL
    assert np.abs(wrap_angle(q["gauss-seidel"] - oq)).max() > 1e3 * TOL
