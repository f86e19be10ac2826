"""Write a bench script's results into ``docs/benchmarks.md``, between markers, with its provenance.

Each bench script that prints a headline table ends with a call to :func:`publish`::

    from report import publish, table        # bench/ is on sys.path when a script there runs
    publish("dk", table(["what", "measured", "target"], rows), note="...")

A script may also pass ``headline=[(what, measured, target), ...]``: those rows are kept in
``docs/headline.json`` (per section) and the README's headline table, between ``<!-- headline -->``
and ``<!-- /headline -->``, is rewritten from it, each row linking the section it comes from.

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
import json
import os
import platform
import re
import sys
from pathlib import Path

__all__ = ["PAGE", "README", "HEADLINE", "SECTIONS", "table", "provenance", "render_section", "replace_section",
           "headline_table", "publish", "target", "ReportError"]

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "benchmarks.md"
README = ROOT / "README.md"
HEADLINE = ROOT / "docs" / "headline.json"
#: The order of the sections in the README's headline table (others follow, by name).
SECTIONS = ("first_run", "dk", "maptensor", "tracker", "step", "sensors", "rpr", "fmu", "c_host", "cosim", "master", "batch", "dynamics", "rules")
_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*$")


def target(text: str, met: bool) -> str:
    """A headline row's target column: ``text``, and " (not met)" after it when the measurement misses it."""
    return text if met else text + " (not met)"


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


def _settings(args: list[str]) -> list[str]:
    """The arguments without ``--out DIR`` / ``--out=DIR``: where a run writes is not how it ran (and a
    scratch folder's path means nothing to a reader)."""
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
        elif a == "--out":
            skip = True
        elif not a.startswith("--out="):
            out.append(a)
    return out


def provenance(command: str | None = None, when: datetime.datetime | None = None) -> str:
    """One line: the command, the UTC date and the machine it ran on (with its load average)."""
    if command is None:
        script = Path(sys.argv[0])
        rel = f"bench/{script.name}" if script.parent.name == "bench" else script.name
        command = " ".join(["python", rel, *_settings(sys.argv[1:])])
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


def headline_table(sections: dict, link: str = "docs/benchmarks.md") -> str:
    """The README's headline table from ``{section: {"rows": [(what, measured, target), ...], "load": float}}``
    (the load average of the machine when the section was written, shown next to the link)."""
    order = sorted(sections, key=lambda n: (SECTIONS.index(n) if n in SECTIONS else len(SECTIONS), n))
    rows = [(what, measured, target, f"[{name}]({link}#{name}), load {sections[name]['load']:.1f}")
            for name in order for what, measured, target in sections[name]["rows"]]
    return table(["what", "measured", "target", "details"], rows)


def _replace_marked(text: str, start: str, end: str, body: str) -> str:
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        raise ReportError(f"expected the markers {start!r} ... {end!r} in this order (found at {i} and {j})")
    return text[:i + len(start)] + "\n" + body + "\n" + text[j:]


def _write_headline(name: str, rows, store: Path, readme: Path) -> None:
    """Keep ``rows`` as section ``name``'s headline rows and rewrite the README's headline table."""
    data = json.loads(store.read_text()) if store.is_file() else {}
    rows = [[str(c) for c in row] for row in rows]
    for i, row in enumerate(rows):
        if len(row) != 3:
            raise ReportError(f"headline[{i}]: expected (what, measured, target), got {row!r}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    data[name] = {"rows": rows, "load": round(load, 2)}
    store.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    if readme.is_file():
        text = readme.read_text()
        readme.write_text(_replace_marked(text, "<!-- headline -->", "<!-- /headline -->", headline_table(data)))


def publish(name: str, body: str, note: str = "", command: str | None = None, headline=None,
            page: Path | str = PAGE, store: Path | str = HEADLINE, readme: Path | str = README) -> Path | None:
    """Write ``body`` (markdown) as section ``name`` of the benchmarks page; returns the page's path.

    ``headline``: rows ``(what, measured, target)`` for the README's headline table (see the module
    doc).  Nothing is written when ``RRR_DK_NO_REPORT`` is set to a non-empty value other than ``0``
    (returns None).  The page is created with a title if it does not exist.
    """
    if os.environ.get("RRR_DK_NO_REPORT", "0") not in ("", "0"):
        return None
    page = Path(page)
    text = page.read_text() if page.is_file() else "# Benchmarks\n"
    page.write_text(replace_section(text, name, render_section(name, body, command, note)))
    print(f"wrote section {name!r} of {page}")
    if headline is not None:
        _write_headline(name, headline, Path(store), Path(readme))
    return page
