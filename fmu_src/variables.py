"""The variable table of a slave: :class:`Var` rows and the FMI 2.0 rules they must keep.

Part of the FMU runtime (bundled into every FMU): it imports nothing but the standard library.
:func:`check_table` validates a table and makes every default explicit; :class:`TableError`
names the variable and the rule it breaks.
"""
from __future__ import annotations

import keyword
import math
import re
from dataclasses import dataclass, replace

__all__ = ["Var", "TableError", "check_table", "attr_name", "TYPES", "CAUSALITIES", "VARIABILITIES", "INITIALS",
           "LEGAL_INITIAL"]

TYPES = ("Real", "Integer", "Boolean")
CAUSALITIES = ("parameter", "calculatedParameter", "input", "output", "local")
VARIABILITIES = ("constant", "fixed", "tunable", "discrete", "continuous")
INITIALS = ("exact", "approx", "calculated")

# FMI 2.0 (section 2.2.7, table of causality x variability): legal 'initial' values per
# (causality, variability); the first entry is the default.  None means "initial is not allowed".
LEGAL_INITIAL: dict[tuple[str, str], tuple[str | None, ...]] = {
    ("parameter", "fixed"): ("exact",),
    ("parameter", "tunable"): ("exact",),
    ("calculatedParameter", "fixed"): ("calculated", "approx"),
    ("calculatedParameter", "tunable"): ("calculated", "approx"),
    ("input", "discrete"): (None,),
    ("input", "continuous"): (None,),
    ("output", "constant"): ("exact",),
    ("output", "discrete"): ("calculated", "exact", "approx"),
    ("output", "continuous"): ("calculated", "exact", "approx"),
    ("local", "constant"): ("exact",),
    ("local", "fixed"): ("calculated", "approx"),
    ("local", "tunable"): ("calculated", "approx"),
    ("local", "discrete"): ("calculated", "exact", "approx"),
    ("local", "continuous"): ("calculated", "exact", "approx"),
}


class TableError(ValueError):
    """The variable table of a slave breaks a rule of FMI 2.0 or of this base class."""


@dataclass(frozen=True)
class Var:
    """One row of a slave's variable table.

    ``variability`` defaults to ``fixed`` for parameters, ``continuous`` for Real and ``discrete``
    for Integer/Boolean variables; ``initial`` defaults to FMI's default for the combination.
    ``depends_on`` is required for outputs: the names of the inputs the output depends on directly
    (``()`` for none); it becomes ModelStructure/Outputs/Unknown/@dependencies.
    """

    name: str
    type: str
    causality: str
    variability: str | None = None
    initial: str | None = None
    start: float | int | bool | None = None
    unit: str | None = None
    description: str = ""
    depends_on: tuple[str, ...] | None = None
    min: float | int | None = None
    max: float | int | None = None
    attr: str | None = None

    @property
    def is_output(self) -> bool:
        return self.causality == "output"


def attr_name(name: str) -> str:
    """The instance attribute of an FMI variable name (``Var.attr`` when not given)."""
    attr = re.sub(r"\W", "_", name)
    if not attr or attr[0].isdigit():
        attr = "v_" + attr
    return attr


def _check_start(v: Var, where: str, initial: str):
    """The start value of ``v`` converted to its type; raises on a missing, illegal or bad start."""
    needs_start = v.causality == "input" or initial in ("exact", "approx")
    start = v.start
    if needs_start and start is None:
        raise TableError(f"{where}: a start value is required ({v.causality}, initial={initial})")
    if initial == "calculated" and start is not None:
        raise TableError(f"{where}: initial='calculated' must not have a start value")
    if start is None:
        return None
    if v.type == "Boolean":
        if not isinstance(start, bool):
            raise TableError(f"{where}: Boolean start must be True or False")
    elif v.type == "Integer":
        if isinstance(start, bool) or int(start) != start:
            raise TableError(f"{where}: Integer start must be an integer")
        start = int(start)
    else:
        start = float(start)
        if not math.isfinite(start):
            raise TableError(f"{where}: start must be finite")
    return start


def _check_row(v, names: set[str], attrs: set[str], reserved) -> Var:
    """One row checked (not its dependencies) and completed with its defaults."""
    if not isinstance(v, Var):
        raise TableError(f"VARIABLES entries must be Var, got {v!r}")
    where = f"variable {v.name!r}"
    if not v.name or v.name != v.name.strip() or any(c in v.name for c in "\r\n\t"):
        raise TableError(f"{where}: illegal name")
    if v.name in names:
        raise TableError(f"{where}: duplicate name")
    names.add(v.name)
    if v.type not in TYPES:
        raise TableError(f"{where}: type must be one of {TYPES}, not {v.type!r}")
    if v.causality not in CAUSALITIES:
        raise TableError(f"{where}: causality must be one of {CAUSALITIES}, not {v.causality!r}")
    variability = v.variability
    if variability is None:
        if v.causality in ("parameter", "calculatedParameter"):
            variability = "fixed"
        else:
            variability = "continuous" if v.type == "Real" else "discrete"
    if variability not in VARIABILITIES:
        raise TableError(f"{where}: variability must be one of {VARIABILITIES}, not {variability!r}")
    if variability == "continuous" and v.type != "Real":
        raise TableError(f"{where}: only Real variables may be continuous ({v.type} must be discrete)")
    legal = LEGAL_INITIAL.get((v.causality, variability))
    if legal is None:
        raise TableError(f"{where}: causality={v.causality!r} with variability={variability!r} "
                         "is not allowed by FMI 2.0")
    initial = v.initial if v.initial is not None else legal[0]
    if initial not in legal:
        allowed = "no initial attribute" if legal == (None,) else f"initial in {legal}"
        raise TableError(f"{where}: {v.causality}/{variability} requires {allowed}, not {v.initial!r}")
    start = _check_start(v, where, initial)
    if v.unit is not None and v.type != "Real":
        raise TableError(f"{where}: only Real variables carry a unit")
    if (v.min is not None or v.max is not None) and v.type == "Boolean":
        raise TableError(f"{where}: Boolean variables have no min/max")
    lo = -math.inf if v.min is None else v.min
    hi = math.inf if v.max is None else v.max
    if lo > hi:
        raise TableError(f"{where}: min > max")
    if start is not None and v.type != "Boolean" and not lo <= start <= hi:
        raise TableError(f"{where}: start {start!r} outside [min, max]")
    attr = v.attr or attr_name(v.name)
    if not attr.isidentifier() or keyword.iskeyword(attr) or attr.startswith("_"):
        raise TableError(f"{where}: attribute name {attr!r} is not a public Python identifier")
    if attr in reserved:
        raise TableError(f"{where}: attribute name {attr!r} collides with a TableSlave attribute; "
                         "pass Var(attr=...)")
    if attr in attrs:
        raise TableError(f"{where}: attribute name {attr!r} used twice")
    attrs.add(attr)
    return replace(v, variability=variability, initial=None if v.causality == "input" else initial,
                   start=start, attr=attr, depends_on=tuple(v.depends_on) if v.depends_on is not None else None)


def check_table(variables, reserved: set[str] = frozenset()) -> tuple[Var, ...]:
    """Validate a variable table and return it with every default made explicit.

    Raises :class:`TableError` naming the variable and the rule it breaks.
    """
    if not isinstance(variables, (tuple, list)) or not variables:
        raise TableError("VARIABLES must be a non-empty tuple of Var")
    names: set[str] = set()
    attrs: set[str] = set()
    out = [_check_row(v, names, attrs, reserved) for v in variables]
    inputs = {v.name for v in out if v.causality == "input"}
    for v in out:
        where = f"variable {v.name!r}"
        if v.is_output:
            if v.depends_on is None:
                raise TableError(f"{where}: outputs must declare depends_on (the inputs they depend on "
                                 "directly; () for none)")
            if len(set(v.depends_on)) != len(v.depends_on):
                raise TableError(f"{where}: depends_on lists a name twice")
            bad = [d for d in v.depends_on if d not in inputs]
            if bad:
                raise TableError(f"{where}: depends_on must name inputs of this table, not {bad}")
        elif v.depends_on is not None:
            raise TableError(f"{where}: only outputs have depends_on")
    return tuple(out)
