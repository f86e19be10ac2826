"""The fast paths of issue 12: slaves without pickling or copies on the step path, the master's
fewest FMI calls, kernels of FMU bundles cached by content, designed gains cached.

Every fast path must give what the slow one gave, bit for bit, and refuse what it refused.
"""
from __future__ import annotations

import functools
import importlib.util
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

import dynamics  # noqa: F401  (before any FMU: the FMUs then use the host's packages)
from cosim import Scenario
from cosim.loop.results import COLUMNS, FLAG_COLUMNS
from fmu_src import kernel_cache, kernel_locator, slave_state
from fmu_src.fmi_states import STEP_COMPLETE, STEP_FAILED
from fmu_src.table_slave import StepRefused, TableSlave, Var

from cosim_support import fmus, loop  # noqa: F401 (fixtures)

ROOT = Path(__file__).resolve().parents[1]


def _slave(cls, **values):
    """An initialized instance of a slave class, run in process (no FMU)."""
    inst = cls(instance_name="test", resources=str(ROOT), fmi_strict=True)   # the FMI state table, as in an FMU
    inst.setup_experiment(0.0)
    inst.enter_initialization_mode()
    for k, v in values.items():
        setattr(inst, k, v)
    inst.exit_initialization_mode()
    assert inst._init_error is None
    return inst


def _resume(inst):
    """After a refused step (state stepFailed): back to stepComplete, as fmi2SetFMUstate of a state
    taken at the start of the step would do (the rollback already restored everything else)."""
    assert inst._fmi_state == STEP_FAILED
    inst._enter_state(STEP_COMPLETE)


class Replacing(TableSlave):
    """A slave whose state is replaced at every step (IMMUTABLE_STATE), with direct feedthrough."""

    VARIABLES = (Var("u", "Real", "input", start=0.0), Var("n", "Integer", "parameter", start=1, min=1, max=5),
                 Var("on", "Boolean", "input", start=True),
                 Var("y", "Real", "output", depends_on=("u",)), Var("s", "Real", "output", depends_on=()),
                 Var("k", "Integer", "output", depends_on=()))
    STATE = ("_acc", "_hist")
    IMMUTABLE_STATE = True
    evaluations = 0

    def setup(self):
        self._acc, self._hist = 0.0, ()

    def step(self, t, dt):
        self._acc = self._acc + self.u * dt          # replaced, never changed in place
        self._hist = self._hist + (self.u,)
        self.s, self.k = self._acc, len(self._hist)
        if self.u > 10:
            raise StepRefused("u too large")
        if self.u < -10:
            self.s = math.inf                       # a non-finite output: refused by the base class

    def evaluate(self):
        type(self).evaluations += 1
        self.y = 2.0 * self.u + self._acc


# ---------------------------------------------------------------------- slave: set/get fast paths
def test_set_and_get_by_value_reference_match_pythonfmu():
    s = _slave(Replacing)
    vr = Replacing.VR
    s.set_real([vr["u"]], [1.5])
    assert s.u == 1.5 and s._dirty                 # an input of a feedthrough output: outputs stale
    assert s.get_real([vr["y"], vr["s"]]) == [3.0, 0.0] and not s._dirty     # refreshed by evaluate()
    s.set_integer([vr["n"]], [3])                 # a fixed parameter: FMI forbids it after initialization
    assert s.n == 1 and "variable(s) 'n' not settable in this state" in s.last_call_refusal
    s.n = 3
    s.set_boolean([vr["on"]], [False])
    assert (s.n, s.on) == (3, False)
    assert s.get_integer([vr["n"], vr["k"]]) == [3, 0] and s.get_boolean([vr["on"]]) == [False]
    assert s.get_real([]) == []
    # what the fast path does not take is refused with a message, never raised (that is fmi2Fatal)
    s.set_real([vr["n"], vr["u"]], [1.0, 2.0])
    assert (s.n, s.u) == (3, 1.5) and "not of type Real" in s.last_call_refusal
    assert s.get_integer([vr["u"], vr["k"]]) == [0, 0] and "no Integer variable" in s.last_call_refusal
    assert math.isnan(s.get_real([999])[0])
    s.set_real([vr["u"]], ["not a number"])
    assert s.u == 1.5 and "does not convert" in s.last_call_refusal


def test_immutable_state_rolls_back_by_reference():
    s = _slave(Replacing)
    s.u = 1.0
    assert s.do_step(0.0, 0.1)
    acc, hist = s._acc, s._hist
    before = s._table_values(s)
    for bad in (11.0, -11.0):                        # StepRefused; a non-finite output
        s.u = bad
        assert not s.do_step(0.1, 0.1)
        assert s._acc is acc and s._hist is hist and s._time == pytest.approx(0.1)
        assert s._table_values(s)[3:] == before[3:]  # outputs back (the input is the master's)
        _resume(s)
    assert s.refused_steps == 2
    s.u, s.n = 0.5, 7                                # a parameter out of range, named
    assert not s.do_step(0.1, 0.1) and "'n' = 7 outside [1, 5]" in s.last_refusal
    _resume(s)
    s.n, s.u = 1, float("nan")                       # a non-finite input, named
    assert not s.do_step(0.1, 0.1) and "'u' = nan" in s.last_refusal
    _resume(s)
    s.u = 0.5
    assert not s.do_step(0.1, -1.0) and "invalid communication step size" in s.last_refusal
    _resume(s)
    assert s.do_step(0.1, 0.1) and s._acc == 0.1 + 0.05 and s._hist == (1.0, 0.5)


def test_step_path_never_pickles(monkeypatch):
    """The rollback of IMMUTABLE_STATE slaves keeps references: no pickle on the step path."""
    def forbidden(*a, **k):
        raise AssertionError("pickled on the step path")

    s = _slave(Replacing)
    monkeypatch.setattr(slave_state.pickle, "dumps", forbidden)
    monkeypatch.setattr(slave_state.pickle, "loads", forbidden)
    s.u = 20.0
    assert not s.do_step(0.0, 0.1)                   # refused and rolled back without a pickle
    _resume(s)
    s.u = 1.0
    assert s.do_step(0.0, 0.1)
    monkeypatch.undo()
    state = s._get_fmu_state()                       # the FMU state still is a pickle
    s.u = 2.0
    assert s.do_step(0.1, 0.1)
    s._set_fmu_state(state)
    assert s._acc == 0.1 and s._hist == (1.0,)


def _import_module_from(name):
    """The slave script ``fmu_src/<name>.py`` as a module of another name (no FMU)."""
    spec = importlib.util.spec_from_file_location(f"_speed_{name}", ROOT / "fmu_src" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_project_slaves_roll_back_by_reference():
    for name in ("RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"):
        cls = getattr(_import_module_from(name), name)
        assert cls.IMMUTABLE_STATE, name
    assert not _import_module_from("RRRDirectKinematics").RRRDirectKinematics.EVALUATE_AFTER_STEP


def test_plant_refusal_keeps_its_state_and_the_next_step_is_exact():
    """The plant's result buffers alternate: a refused step leaves the state it started from."""
    plant_cls = _import_module_from("RRRPlant").RRRPlant
    a = _slave(plant_cls, tau1=0.3, tau2=-0.2, tau3=0.1)
    b = _slave(plant_cls, tau1=0.3, tau2=-0.2, tau3=0.1)
    assert a.do_step(0.0, 1e-3) and b.do_step(0.0, 1e-3)
    x = a._x
    saved = x.copy()
    a.tau1 = 1e9                                     # throws the platform out of the tool space
    assert not a.do_step(1e-3, 1e-3) and "left the tool space" in a.last_refusal
    assert a._x is x and np.array_equal(a._x, saved)
    _resume(a)
    a.tau1 = 0.3
    for k in range(1, 4):
        assert a.do_step(k * 1e-3, 1e-3) and b.do_step(k * 1e-3, 1e-3)
    assert np.array_equal(a._x, b._x) and a._table_values(a) == b._table_values(b)


# ---------------------------------------------------------------------- master


def test_one_set_step_get_per_fmu_and_step(loop, monkeypatch):
    """Per step and FMU: one fmi2SetReal, fmi2DoStep, fmi2GetReal; the DK's Integer and Boolean
    outputs only when asked (flags).  Counted in the slaves' Python, with the loader's fast lanes off
    (which answer every one of them without Python: none reach it with the lanes on)."""
    calls = {}
    for meth in ("set_real", "do_step", "get_real", "get_integer", "get_boolean"):
        orig = getattr(TableSlave, meth)

        def counted(self, *args, _orig=orig, _meth=meth):
            calls[type(self).__name__, _meth] = calls.get((type(self).__name__, _meth), 0) + 1
            return _orig(self, *args)
        monkeypatch.setattr(TableSlave, meth, counted)
    def per_step(flags):
        """Calls per step: the difference between a run of 2n and of n steps (initialization apart)."""
        counts = []
        for t_end in (0.01, 0.02):
            calls.clear()
            loop.run(Scenario(t_end=t_end), flags=flags)
            counts.append(dict(calls))
        return {k: (counts[1].get(k, 0) - counts[0].get(k, 0)) / 10 for k in set(counts[0]) | set(counts[1])}

    lanes = per_step(True)
    assert sum(lanes.values()) == 0, lanes                # the fast lanes: no Python in a step
    monkeypatch.setenv("RRR_DK_FAST_LANE", "0")
    for flags in (True, False):
        c = per_step(flags)
        for name in ("RRRDirectKinematics", "ComputedTorqueController", "RRRPlant"):
            for meth in ("set_real", "do_step", "get_real"):
                assert c[name, meth] == 1, (name, meth)
        assert c.get(("RRRDirectKinematics", "get_integer"), 0) == c.get(("RRRDirectKinematics", "get_boolean"), 0) \
            == (1 if flags else 0)
        assert sum(c.values()) == (11 if flags else 9)


def test_inputs_from_one_buffer_are_passed_without_a_copy(loop):
    loop.run(Scenario(t_end=0.01))
    assert isinstance(loop.ports["dk"].set_inputs, functools.partial)        # q from the plant's buffer
    assert isinstance(loop.ports["plant"].set_inputs, functools.partial)     # tau from the controller's
    assert not isinstance(loop.ports["controller"].set_inputs, functools.partial)   # two sources: copied


def test_runs_without_flags_give_the_same_columns(loop):
    for sc in (Scenario(t_end=0.6), Scenario(t_end=0.6, order="jacobi")):
        a = loop.run(sc)
        b = loop.run(sc, flags=False)
        assert tuple(a.columns) == COLUMNS
        assert tuple(b.columns) == tuple(c for c in COLUMNS if c not in FLAG_COLUMNS)
        for key in b.columns:
            assert b[key].dtype == np.float64
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
        assert b.metrics()["dk_status_nonzero"] is None and a.metrics()["dk_status_nonzero"] == 0


# ---------------------------------------------------------------------- the master's direct FMI calls
def test_each_order_makes_its_calls_in_sequence_and_stops_at_a_failed_one():
    from fmpy.fmi1 import FMICallException

    from cosim.loop.calls import ORDERS, step_sequence

    made, fail_at = [], [None]

    def fake(inst, what):
        def call(*args):
            made.append((inst, what, args))
            return 3 if (inst, what) == fail_at[0] else (1 if what == "get" else 0)   # fmi2Warning passes
        return call
    calls = {(i, w): fake(i, w) for i in ("dk", "controller", "plant") for w in ("set", "step", "get")}
    for order, expected in ORDERS.items():
        made.clear()
        fail_at[0] = None
        step_sequence(calls, order)(0.25, 1e-3)
        assert [(i, w) for i, w, _ in made] == list(expected), order
        assert all(args == ((0.25, 1e-3, 1) if w == "step" else ()) for _, w, args in made)
        made.clear()
        fail_at[0] = ("controller", "step")
        with pytest.raises(FMICallException, match="controller: fmi2DoStep"):
            step_sequence(calls, order)(0.25, 1e-3)
        assert made[-1][:2] == ("controller", "step")                  # nothing called after it
    with pytest.raises(ValueError, match="order: expected one of .* got 'seidel'"):
        step_sequence(calls, "seidel")


def test_direct_calls_give_the_runs_of_fmpy_calls(fmus, loop):
    from cosim import ClosedLoop
    from cosim.loop.calls import hot_call

    sc = Scenario(t_end=0.3)
    a = loop.run(sc)
    assert loop.ports["dk"].calls == "direct"
    with ClosedLoop(fmus, calls="fmpy") as other:
        b = other.run(sc)
        fmu = other.ports["dk"].unit.fmu
        assert hot_call(fmu, "fmi2DoStep", fmu.component).func is not fmu._functions["fmi2DoStep"]
        fmu.fmiCallLogger = lambda message: None                    # a logger: fmpy's method, which logs
        try:
            assert hot_call(fmu, "fmi2DoStep", fmu.component).func == fmu.fmi2DoStep
        finally:
            fmu.fmiCallLogger = None
    assert tuple(a.columns) == tuple(b.columns)
    for key in a.columns:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    with pytest.raises(ValueError, match="calls: expected one of .* got 'ctypes'"):
        ClosedLoop(fmus, calls="ctypes")


def test_a_step_function_never_steps_freed_instances(fmus):
    """Its calls are bound to the instances of one initialize: after the next (fresh instances, the old
    ones freed) or after close, it refuses to step instead of calling freed memory (a crash of the host)."""
    from cosim import ClosedLoop

    def start():                                                        # as run: initialize, read the outputs
        loop.initialize(sc, 0.0)
        for port in loop.ports.values():
            assert all(call() == 0 for _, call in port.read_calls(False))

    sc = Scenario(t_end=0.01)
    loop = ClosedLoop(fmus)
    with pytest.raises(RuntimeError, match="call initialize"):
        loop.step_function()
    start()
    old = loop.step_function()
    old(0.0, sc.h)
    pose = list(loop.ports["dk"].buffers["Real"])
    start()                                                             # the instances old was made for: freed
    with pytest.raises(RuntimeError, match="initialized again or closed"):
        old(sc.h, sc.h)
    new = loop.step_function()
    new(0.0, sc.h)
    assert list(loop.ports["dk"].buffers["Real"]) == pose               # the same first step again
    loop.close()
    with pytest.raises(RuntimeError, match="initialized again or closed"):
        new(sc.h, sc.h)
    with pytest.raises(RuntimeError, match="closed"):
        loop.run(sc)
    with pytest.raises(RuntimeError, match="closed"):
        loop.step_function()


def test_hot_calls_are_the_fmus_c_functions_by_their_declared_types(loop):
    """A hot call is a cffi pointer of the C type fmpy declared (pointers as addresses); it reads what
    fmpy's method reads and answers its status; a function of a type it does not know stays ctypes."""
    import ctypes

    from cosim.loop.calls import c_declaration, hot_call

    loop.run(Scenario(t_end=0.01))                                      # instances in step mode
    fmu = loop.ports["plant"].unit.fmu
    functions = fmu._functions
    assert c_declaration(functions["fmi2GetReal"]) == "int (*)(void *, void *, size_t, void *)"
    assert c_declaration(functions["fmi2DoStep"]) == "int (*)(void *, double, double, int)"
    vr = loop.ports["plant"].unit.vr_array("x_true", "y_true", "phi_true")
    mine, theirs = (ctypes.c_double * 3)(), (ctypes.c_double * 3)()
    call = hot_call(fmu, "fmi2GetReal", fmu.component, vr, 3, mine)
    assert type(call.func).__module__ == "_cffi_backend" and call() == 0
    fmu.fmi2GetReal(fmu.component, vr, 3, theirs)
    assert list(mine) == list(theirs) and np.all(np.isfinite(list(mine)))
    assert c_declaration(ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_char_p)(lambda c, s: 0)) == \
        "int (*)(void *, void *)"                                           # a string is an address
    assert c_declaration(ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_float)(lambda x: 0)) is None    # a float
    assert c_declaration(ctypes.CFUNCTYPE(None, ctypes.c_void_p)(lambda c: None)) is None       # returns void
    # a pointer left for the call (an array, or None, there): fmpy's ctypes function, which takes them
    left = hot_call(fmu, "fmi2GetReal", fmu.component)
    assert left.func is functions["fmi2GetReal"] and left(vr, 3, theirs) == 0


# ---------------------------------------------------------------------- kernels of FMU bundles
KERNEL = textwrap.dedent("""
    from numba import njit

    @njit(cache=True)
    def twice(x):
        return 2.0 * x
""")


def _bundle(folder: Path, text: str = KERNEL) -> Path:
    res = folder / "resources"
    (res / "pkg").mkdir(parents=True)
    (res / "slavemodule.txt").write_text("Model")
    (res / "pkg" / "__init__.py").write_text("")
    (res / "pkg" / "kern.py").write_text(text)
    return res


def _load_kernel(res: Path, tag: str):
    spec = importlib.util.spec_from_file_location(f"_bundle_kern_{tag}", res / "pkg" / "kern.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.twice


def test_bundle_kernels_are_cached_by_content_wherever_extracted(tmp_path, monkeypatch):
    import numba.core.caching as caching

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    kernel_locator.install()
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    assert sum(getattr(c, "_rrr_dk_bundle_locator", False) for c in impl._locator_classes) == 1
    kernel_locator.install()                              # idempotent
    assert sum(getattr(c, "_rrr_dk_bundle_locator", False) for c in impl._locator_classes) == 1

    first, second = _bundle(tmp_path / "a"), _bundle(tmp_path / "b")  # the same content, two folders
    assert kernel_cache.bundle_of(str(first / "pkg" / "kern.py")) == str(first)
    assert kernel_cache.bundle_of(str(tmp_path / "nowhere.py")) is None
    key = kernel_cache.bundle_key(str(first))
    assert key == kernel_cache.bundle_key(str(second))
    f = _load_kernel(first, "a")
    assert f(2.0) == 4.0
    assert any((tmp_path / "cache" / key / "pkg").glob("*.nbi"))
    g = _load_kernel(second, "b")                       # another extraction: loaded, not compiled
    assert g(3.0) == 6.0 and g.stats.cache_hits and not g.stats.cache_misses
    changed = _bundle(tmp_path / "c", KERNEL.replace("2.0 * x", "3.0 * x"))
    assert kernel_cache.bundle_key(str(changed)) != key
    assert _load_kernel(changed, "c")(1.0) == 3.0       # new content, new folder: compiled afresh


# ---------------------------------------------------------------------- designed gains
def test_designed_gains_are_python_controls_bit_for_bit_and_cached(tmp_path, monkeypatch):
    from dynamics import control
    from dynamics.control import ComputedTorqueGains

    monkeypatch.delenv("RRR_DK_CACHE", raising=False)          # the user's shared cache would win over XDG
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    control._designed_gains.cache_clear()
    try:
        for bw, z in ((50.0, 1.0), (40.0, 0.9), (30.0, 1.3)):
            g = ComputedTorqueGains.design(bw, z)
            assert (g.kp[0], g.kd[0]) == ComputedTorqueGains.place(bw, z)
        path = control.gains_cache_file()
        assert path.is_file() and path.parent.parent == tmp_path
        control._designed_gains.cache_clear()
        # a cached entry is used as it is (bit for bit); a corrupted one is placed again
        table = __import__("json").loads(path.read_text())
        key = next(k for k in table if "float 40.0, float 0.9" in k)
        assert ComputedTorqueGains.design(40.0, 0.9).kp[0] == table[key][0]
        table[key] = [1.0, 2.0]
        path.write_text(__import__("json").dumps(table))
        control._designed_gains.cache_clear()
        g = ComputedTorqueGains.design(40.0, 0.9)
        assert (g.kp[0], g.kd[0]) == ComputedTorqueGains.place(40.0, 0.9)
        with pytest.raises(ValueError, match="bandwidth"):
            ComputedTorqueGains.design(-1.0, 1.0)
    finally:
        control._designed_gains.cache_clear()
