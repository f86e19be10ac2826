"""The interface table of an FMU, generated from its slave's variable table: ``python -m cosim.fmus.interface_table``.

A slave's ``VARIABLES`` (``fmu_src.variables.Var`` rows, checked and completed by
``fmu_src.variables.check_table``) is the one definition of its interface: the build writes
modelDescription.xml from it, and this module renders it as a markdown table, one row per variable,
in value-reference order.  The command rewrites the table between the markers
``<!-- interface:NAME -->`` and ``<!-- /interface:NAME -->`` in the README (the DK FMU's interface)
and in every FMU readme ``fmu_src/<NAME>.md`` (each carries the markers), so no interface table is
typed by hand; ``--check`` only reports (exit status 1) the files
whose table differs.
"""
from __future__ import annotations

import argparse
import importlib
import math
import sys
from pathlib import Path

from fmu_src.variables import Var, check_table

from .builds import FMU_NAMES
from .sources import SLAVE_DIR, slave_readme

__all__ = ["HEADER", "slave_class", "interface_rows", "interface_table", "replace_table", "update_file", "main",
           "InterfaceTableError"]

#: The columns of the rendered table.
HEADER = ("vr", "name", "causality", "variability", "type", "unit", "start", "range", "depends on", "description")
#: The FMUs whose slaves this module knows (the closed loop's three and the 3-RPR's DK).
NAMES = (*FMU_NAMES, "RPRDirectKinematics")


class InterfaceTableError(ValueError):
    """An unknown FMU name, or a file whose markers are missing or out of order."""


def slave_class(name: str) -> type:
    """The slave class of FMU ``name`` (``fmu_src.<name>.<name>``)."""
    if name not in NAMES:
        raise InterfaceTableError(f"name: expected one of {NAMES}, got {name!r}")
    return getattr(importlib.import_module(f"fmu_src.{name}"), name)


def _number(value) -> str:
    """A start/min/max value as the table shows it: booleans as in XML, floats with 9 significant digits."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "inf" if math.isinf(value) and value > 0 else "-inf" if math.isinf(value) else f"{value:.9g}"
    return str(value)


def _range(v: Var) -> str:
    if v.min is None and v.max is None:
        return ""
    lo = "" if v.min is None else _number(v.min)
    hi = "" if v.max is None else _number(v.max)
    return f"[{lo}, {hi}]" if lo and hi else f">= {lo}" if lo else f"<= {hi}"


def interface_rows(variables) -> list[tuple[str, ...]]:
    """One row of :data:`HEADER` per variable of the table ``variables`` (Var rows), value reference = row index."""
    rows = []
    for vr, v in enumerate(check_table(tuple(variables))):
        start = "" if v.start is None else _number(v.start)
        if v.initial == "exact" and v.causality == "output":
            start += " (initial exact)"
        description = v.description.replace("|", "\\|").replace("\n", " ")
        deps = "" if not v.is_output else ", ".join(v.depends_on) or "none"
        rows.append((str(vr), f"`{v.name}`", v.causality, v.variability, v.type, v.unit or "", start, _range(v),
                     deps, description))
    return rows


def interface_table(slave) -> str:
    """The markdown table of a slave class's (or a ``Var`` sequence's) interface."""
    variables = slave.VARIABLES if isinstance(slave, type) else slave
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(row) + " |" for row in interface_rows(variables)]
    return "\n".join(lines)


def replace_table(text: str, name: str, table: str) -> str:
    """``text`` with the table between the ``interface:name`` markers replaced by ``table``."""
    start, end = f"<!-- interface:{name} -->", f"<!-- /interface:{name} -->"
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        raise InterfaceTableError(f"expected the markers {start!r} ... {end!r} in this order, found "
                                  f"{start!r} at {i} and {end!r} at {j}")
    return text[:i + len(start)] + "\n" + table + "\n" + text[j:]


def update_file(path: str | Path, names, check: bool = False) -> bool:
    """Rewrite the tables of FMUs ``names`` in ``path`` (only compare when ``check``); True if it differed."""
    path = Path(path)
    text = path.read_text()
    new = text
    for name in names:
        new = replace_table(new, name, interface_table(slave_class(name)))
    if new != text and not check:
        path.write_text(new)
    return new != text


def _targets(readme: Path) -> list[tuple[Path, list[str]]]:
    """The files to update and the FMUs whose tables each holds (those with markers)."""
    out = []
    for path, names in [(readme, NAMES), *((slave_readme(n), (n,)) for n in NAMES)]:
        if path.is_file():
            text = path.read_text()
            found = [n for n in names if f"<!-- interface:{n} -->" in text]
            if found:
                out.append((path, found))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cosim.fmus.interface_table", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--readme", default=str(SLAVE_DIR.parent / "README.md"), metavar="FILE",
                    help="the project README whose marked tables are rewritten (default: the project's)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if a table is out of date")
    ap.add_argument("--print", dest="show", metavar="NAME", choices=NAMES,
                    help="print the table of this FMU and exit")
    args = ap.parse_args(argv)
    if args.show:
        print(interface_table(slave_class(args.show)))
        return 0
    if not Path(args.readme).is_file():
        print(f"error: --readme {args.readme}: no such file", file=sys.stderr)
        return 2
    stale = []
    for path, names in _targets(Path(args.readme)):
        if update_file(path, names, check=args.check):
            stale.append(path)
            print(f"{'out of date' if args.check else 'rewrote'}: {path} ({', '.join(names)})")
    if not stale:
        print("interface tables up to date")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
