import numpy as np
import pytest
from hypothesis import settings

from solver import Manipulator

# numba compiles on first use; hypothesis must not count that against a deadline
settings.register_profile("project", deadline=None, max_examples=200, derandomize=True)
settings.load_profile("project")


@pytest.fixture(scope="session")
def model():
    return Manipulator.paper()


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


#: Fixtures that build FMUs (the session's three, :func:`host_support.session_fmus`; the batch's folder of them).
FMU_FIXTURES = ("fmus", "fmu_dir")


def pytest_collection_modifyitems(session, config, items):
    """Run the modules that build the session's FMUs first (each module's tests in their own order).

    The DK FMU's build compiles the tracker's kernels once, for a generic CPU, into the store that this
    process then loads them from (:mod:`solver.shared_kernels`); a tracker test that ran first would
    compile the same kernels for this CPU (minutes on a cold cache, nothing once warm)."""
    def module(item):
        return getattr(getattr(item, "module", None), "__name__", None)

    builds = {module(item) for item in items if any(f in getattr(item, "fixturenames", ()) for f in FMU_FIXTURES)}
    items.sort(key=lambda item: 0 if module(item) in builds - {None} else 1)


_COARSE_MAPS = {}


def coarse_map(model, posture, rule="aspect"):
    """A coarse map of ``posture`` (20 mm, 4 deg) over the default bounds: quick, for tracker tests;
    loaded once per session and posture from the project's map cache (:func:`solver.mapcache.cached_map`,
    which checks the file and builds it there when missing: about 2.3 s a posture)."""
    from solver.mapcache import cached_map

    key = (model.digest(), posture, rule)
    if key not in _COARSE_MAPS:
        _COARSE_MAPS[key] = cached_map(model, posture, rule=rule, step=(0.02, 0.02, np.deg2rad(4.0)),
                                       progress=False, log=lambda text: None)
    return _COARSE_MAPS[key]


@pytest.fixture(scope="session")
def coarse_map1(model):
    """The coarse map of posture 1 (:func:`coarse_map`)."""
    return coarse_map(model, 1)


def track_stream(tracker, q, X0, dt=1e-3):
    """Reset ``tracker`` at ``(X0, q[0])`` and step it through the joints ``q`` (n, 3) with time step
    ``dt``: poses (n, 3) and the step infos (n,; None at the reset)."""
    tracker.reset(X0, q[0])
    X, infos = [tracker.state.X], [None]
    for k in range(1, len(q)):
        x, info = tracker.step(q[k], dt)
        X.append(x)
        infos.append(info)
    return np.array(X), infos


def random_poses(rng, n, model=None):
    """Uniform poses over a box that covers the paper manipulator's tool space."""
    return np.column_stack([rng.uniform(-0.2, 1.2, n), rng.uniform(-0.3, 1.1, n),
                            rng.uniform(-np.pi, np.pi, n)])


def pose_distance(a, b):
    """max(|dx|, |dy|, |wrapped dphi|) between real poses (..., 3)."""
    d = np.abs(np.asarray(a) - np.asarray(b))
    d[..., 2] = np.abs(np.angle(np.exp(1j * (np.asarray(a)[..., 2] - np.asarray(b)[..., 2]))))
    return d.max(axis=-1)


# A process that ran pythonfmu 0.7 FMUs may abort at exit, in the C runtime's finalizers, on a heap
# corrupted earlier (tests/test_exit.py reproduces it with a plain fmpy script; docs/reliability.md, known issues).
# The session's outcome is known and printed by then: a session that loaded FMUs ends with that
# status through cosim.unit.exit_process (no finalizers); one that loaded none exits normally.
_SESSION = {}


def pytest_sessionfinish(session, exitstatus):
    _SESSION["status"] = int(exitstatus)


def pytest_unconfigure(config):
    if "status" in _SESSION:
        from cosim.unit import exit_process, fmus_loaded

        if fmus_loaded():
            exit_process(_SESSION["status"])
