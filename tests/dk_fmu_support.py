"""Shared by the tests of the direct-kinematics FMU (test_fmu_dk.py, test_fmu_dk_stepping.py).

The FMU is built per test module into a temporary folder with a coarse map (40 mm / 6 deg, the
reference configuration of ``cosim.fmus.references.REFERENCE``); a test module imports the fixtures
below by name.
"""
from __future__ import annotations

import pytest
from fmpy import extract, read_model_description

import solver  # noqa: F401  (before any FMU: the FMUs then use this copy, no numba recompilation)
from cosim.fmus import builds, references
from cosim.unit import FMUUnit, import_hygiene
from solver import Manipulator, MapTensor, Tracker, circle_path, ik

H = references.REFERENCE["h"]
N = references.REFERENCE["n"]
RES = references.REFERENCE["resolution"]
OUTPUTS = references.OUTPUTS
#: the outputs of the tracker's certainty (not in the reference CSV)
CERTAINTY = ("certain", "uncertain_since")
#: the pose bound and trust (not in the reference CSV)
BOUND = ("x_bound", "y_bound", "phi_bound", "trust")
#: the step budget's flag (not in the reference CSV)
BUDGET = ("out_of_budget",)
MODEL = Manipulator.paper()
PATH = circle_path(N)
Q = ik(MODEL, PATH, 1)
X0 = PATH[0]


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(autouse=True)
def hygiene():
    """Undo what pythonfmu's C wrapper does to sys.path / sys.modules (see cosim.unit)."""
    with import_hygiene():
        yield


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("dk")


@pytest.fixture(scope="module")
def built(tmp):
    """The reference configuration: posture 1, default mode, 40 mm / 6 deg map."""
    logs = []
    result = builds.build_dk(tmp / "fmu", postures=(1,), resolution=RES, cache_dir=tmp / "maps", log=logs.append)
    assert any("built" in m for m in logs)
    return result


@pytest.fixture(scope="module")
def fmu(built):
    return built.fmu


@pytest.fixture(scope="module")
def map1(built):
    return MapTensor.load(built.maps[1])


@pytest.fixture(scope="module")
def md(fmu):
    return read_model_description(str(fmu))


@pytest.fixture(scope="module")
def unzipdir(fmu, tmp):
    return extract(str(fmu), unzipdir=str(tmp / "unzipped"))


@pytest.fixture(scope="module")
def built_multi(tmp):
    """Postures 2 and 1 embedded, posture 2 and paper mode as start values (--posture 2 1 --mode paper)."""
    return builds.build_dk(tmp / "multi", postures=(2, 1), resolution=RES, mode="paper", cache_dir=tmp / "maps",
                           log=lambda m: None)


@pytest.fixture
def make(fmu, unzipdir):
    made = []

    def factory(name="dk", fmu_=None, dir_=None, **start):
        made.append(Master(fmu_ or fmu, dir_ or unzipdir, name, **start))
        return made[-1]

    yield factory
    for m in made:
        m.close()


class Master(FMUUnit):
    """A minimal master on the shared FMU2Slave driver: value references looked up once, the FMU's log kept."""

    def __init__(self, fmu, unzipdir, name="dk", **start):
        super().__init__(fmu, name, unzip_dir=unzipdir, logging_on=True)
        self.initialize(**start)

    def initialize(self, **start):
        super().initialize(0.0, start)
        self.t = 0.0

    def set(self, **values):
        self.set_values(values)

    def set_q(self, q):
        self.set(q1=q[0], q2=q[1], q3=q[2])

    def step(self, q):
        self.set_q(q)
        self.fmu.doStep(self.t, H)
        self.t += H
        return self.outputs()

    def outputs(self):
        return tuple(self.get_values(OUTPUTS))


def circle_start():
    return {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "q1": Q[0, 0], "q2": Q[0, 1], "q3": Q[0, 2]}


def tracker_rows(mt, stream, X_start=X0, q_start=None, mode="default"):
    """What the FMU must output after each doStep: an in-process Tracker fed the same joints."""
    tr = Tracker(MODEL, mt, mode=mode)
    tr.reset(X_start, stream[0] if q_start is None else q_start)
    rows = []
    for q in stream:
        X, info = tr.step(q)
        rows.append((float(X[0]), float(X[1]), float(X[2]), info.label, info.near_border, info.n_real,
                     info.ambiguous, info.status, info.cond))
    return rows


def result_rows(result):
    return [tuple(r[n].item() for n in OUTPUTS) for r in result]
