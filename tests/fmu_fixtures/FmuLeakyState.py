"""A deliberately broken slave: ``step`` keeps state in an attribute it never declares.

The build cannot see it (the attribute appears only after the first step); ``smoke_check`` must.
"""
from fmu_src.wrapper_refs import hold_globals
from fmu_src.table_slave import TableSlave, Var

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation


class FmuLeakyState(TableSlave):
    VARIABLES = (
        Var("u", "Real", "input", start=1.0, unit="1"),
        Var("y", "Real", "output", unit="1", depends_on=()),
    )

    def step(self, t, dt):
        self._calls = getattr(self, "_calls", 0) + 1  # undeclared: not in STATE, not rolled back
        self.y = self._calls * self.u
