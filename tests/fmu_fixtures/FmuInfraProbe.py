"""Test slave of tests/test_fmu_infra.py: small, but with every feature the real slaves use.

- Real inputs with units, a tunable and fixed parameters (one with a min), an Integer test hook;
- ``angle``: trapezoidal integral of ``k*omega`` (state; depends on no input directly);
- ``force = torque / lever``: direct feedthrough (depends on ``torque`` only, via ``evaluate``);
- ``steps`` (Integer) and ``saturated`` (Boolean) outputs, ``elapsed`` time;
- hidden state ``_prev_omega`` (the previous input), which a rollback must restore;
- ``fail_at_step``: step number at which ``step`` corrupts ``angle`` and raises, so the tests can
  check that an internal exception is refused, not fatal, and that the state is rolled back.
"""
from pythonfmu import DefaultExperiment

from fmu_src.wrapper_refs import hold_globals
from fmu_src.table_slave import TableSlave, Var

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation


class FmuInfraProbe(TableSlave):
    description = "Trapezoidal integrator with a feedthrough gain, a counter and a saturation flag"
    author = "rrr-dk tests"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=0.01)

    VARIABLES = (
        Var("omega", "Real", "input", start=0.0, unit="rad/s", description="rate integrated into angle"),
        Var("torque", "Real", "input", start=0.0, unit="N.m", description="torque converted to force"),
        Var("k", "Real", "parameter", "tunable", start=1.0, unit="1", description="integrator gain"),
        Var("lever", "Real", "parameter", "fixed", start=0.5, unit="m", min=1e-3, description="lever arm"),
        Var("angle_limit", "Real", "parameter", "fixed", start=1.0, unit="rad", min=0.0,
            description="saturated = |angle| > angle_limit"),
        Var("fail_at_step", "Integer", "parameter", "tunable", start=-1,
            description="test hook: step() raises when the step count would reach this value"),
        Var("angle", "Real", "output", unit="rad", depends_on=(), description="integral of k*omega"),
        Var("force", "Real", "output", unit="N", depends_on=("torque",), description="torque / lever"),
        Var("steps", "Integer", "output", depends_on=(), description="accepted steps"),
        Var("saturated", "Boolean", "output", depends_on=(), description="|angle| > angle_limit"),
        Var("elapsed", "Real", "output", unit="s", depends_on=(), description="integrated time"),
    )
    STATE = ("_prev_omega",)

    def setup(self):
        self._prev_omega = None  # the first step uses the rectangle rule

    def step(self, t, dt):
        if self.steps + 1 == self.fail_at_step:
            self.angle += 12345.0  # corrupt the state first: the base class must roll it back
            self._prev_omega = -1.0
            raise RuntimeError(f"test failure at step {self.steps + 1} (100% reproducible, not %s)")
        prev = self.omega if self._prev_omega is None else self._prev_omega
        self.angle += self.k * 0.5 * (prev + self.omega) * dt
        self._prev_omega = self.omega
        self.steps += 1
        self.elapsed += dt
        self.saturated = abs(self.angle) > self.angle_limit

    def evaluate(self):
        self.force = self.torque / self.lever
