"""Write a bench script's results into ``docs/benchmarks.md``, between markers, with its provenance.

Each bench script that prints a headline table ends with a call to :func:`publish`::

    from report import publish, table        # bench/ is on sys.path when a script there runs
    publish("dk", table(["what", "measured", "target"], rows), note="...")

The section ``NAME`` of the page is the text between ``<!-- bench:NAME -->`` and
``<!-- /bench:NAME -->``; it is replaced as a whole (or appended at the end of the page when the
markers are missing), so the page holds the numbers the scripts last wrote, never typed ones.
Every section records the command that produced it (the script and its arguments), the date (UTC)
and the machine: CPU, core count, Python and numpy versions, and the load average, which says how
far timings may be off on a shared machine (counts are exact anyway).
``RRR_DK_NO_REPORT=1`` in the environment turns the writing off (a quick look that must not
replace the page's numbers).
"""
from __future__ import annotations

import datetime
import os
import platform
import re
import sys
from pathlib import Path

__all__ = ["PAGE", "table", "provenance", "render_section", "replace_section", "publish", "ReportError"]

PAGE = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*$")


class ReportError(ValueError):
    """A section name, a table or the page is not what the report expects."""


def table(header, rows) -> str:
    """A markdown table: ``header`` (n column titles) and ``rows`` (each n cells, any objects, str()-ed)."""
    header = [str(h) for h in header]
    if not header:
        raise ReportError("header: expected at least one column title, got none")
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for i, row in enumerate(rows):
        cells = [str(c).replace("|", "\\|").replace("\n", " ") for c in row]
        if len(cells) != len(header):
            raise ReportError(f"rows[{i}]: expected {len(header)} cells (one per column), got {len(cells)}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def provenance(command: str | None = None, when: datetime.datetime | None = None) -> str:
    """One line: the command, the UTC date and the machine it ran on (with its load average)."""
    if command is None:
        script = Path(sys.argv[0])
        rel = f"bench/{script.name}" if script.parent.name == "bench" else script.name
        command = " ".join(["python", rel, *sys.argv[1:]])
    when = when or datetime.datetime.now(datetime.timezone.utc)
    try:
        import numpy
        np_version = f", numpy {numpy.__version__}"
    except ImportError:                                   # pragma: no cover - numpy is a dependency
        np_version = ""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    cpu = platform.processor() or platform.machine()
    return (f"`{command}`, {when:%Y-%m-%d %H:%M} UTC; {cpu}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}{np_version}; load average {load:.1f} at the end")


def render_section(name: str, body: str, command: str | None = None, note: str = "") -> str:
    """The marked section ``name``: markers, provenance line, optional note, then ``body``."""
    if not _NAME.match(name):
        raise ReportError(f"name: expected lower-case letters, digits, '-' or '_', got {name!r}")
    parts = [f"<!-- bench:{name} -->", "", f"Written by {provenance(command)}.", ""]
    if note:
        parts += [note.strip(), ""]
    parts += [body.strip(), "", f"<!-- /bench:{name} -->"]
    return "\n".join(parts)


def replace_section(text: str, name: str, section: str) -> str:
    """``text`` with the section ``name`` replaced by ``section`` (appended if it has no such markers)."""
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    i, j = text.find(start), text.find(end)
    if (i < 0) != (j < 0) or (i >= 0 and j < i):
        raise ReportError(f"section {name!r}: the page has one marker without the other, or they are out "
                          f"of order ({start!r} at {i}, {end!r} at {j})")
    if i < 0:
        return text.rstrip("\n") + "\n\n" + section + "\n"
    return text[:i] + section + text[j + len(end):]


def publish(name: str, body: str, note: str = "", command: str | None = None, page: Path | str = PAGE) -> Path | None:
    """Write ``body`` (markdown) as section ``name`` of the benchmarks page; returns the page's path.

    Nothing is written when ``RRR_DK_NO_REPORT`` is set to a non-empty value other than ``0``
    (returns None).  The page is created with a title if it does not exist.
    """
    if os.environ.get("RRR_DK_NO_REPORT", "0") not in ("", "0"):
        return None
    page = Path(page)
    text = page.read_text() if page.is_file() else "# Benchmarks\n"
    page.write_text(replace_section(text, name, render_section(name, body, command, note)))
    print(f"wrote section {name!r} of {page}")
    return page
