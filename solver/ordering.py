"""The numbering of the six DK solutions (paper eq. 15): the ordering rules.

A label border of the map tensor appears wherever the number of the true solution changes,
whether or not it is a basic-region border, so the rule that numbers the solutions decides
how many borders there are (docs/maptensor.md: the rule table).  The rules are compiled in
:mod:`solver._kernels.ordering`; :func:`solver.dk_all` numbers its output with them and
:func:`solver.order_solutions` renumbers given solution sets.
"""
from __future__ import annotations

from ._kernels import layout
from .checks import SolverInputError

__all__ = ["ORDERING_RULES", "DEFAULT_RULE", "RULE_CODES", "rule_code"]

#: The ordering rules that number the six solutions 1..6 (paper eq. 15).
ORDERING_RULES = {
    "real-phi": "real solutions first, by phi ascending in (-pi, pi]; then the complex ones "
                "by (Re phi, Im phi) ascending",
    "real-x": "real solutions first, by x ascending; then the complex ones by (Re phi, Im phi)",
    "real-y": "real solutions first, by y ascending; then the complex ones by (Re phi, Im phi)",
    "aspect": "real solutions with det J >= 0 in slots 1-3 and with det J < 0 in slots 4-6, each "
              "by phi ascending; complex solutions by (Re phi, Im phi) fill the free slots, first "
              "class first (det J keeps its sign inside a basic region; each class holds at most "
              "three real solutions)",
    "literal": "all six by (Re phi, Im phi) ascending, Re phi wrapped to (-pi, pi], real and "
               "complex alike (the paper's 'arrange all imaginary and real solutions in an "
               "arbitrary order (e.g. increasing)')",
}
#: The rule used when none is given (chosen by the border-volume measurement, docs/maptensor.md).
DEFAULT_RULE = "aspect"
#: The kernels' code of each rule.
RULE_CODES = {"real-phi": layout.RULE_REAL_PHI, "literal": layout.RULE_LITERAL, "real-x": layout.RULE_REAL_X,
              "real-y": layout.RULE_REAL_Y, "aspect": layout.RULE_ASPECT}


def rule_code(rule) -> int:
    """The kernels' code of ``rule``, or :class:`SolverInputError` naming the known rules."""
    code = RULE_CODES.get(rule) if isinstance(rule, str) else None
    if code is None:
        raise SolverInputError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
    return code
