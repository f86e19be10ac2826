"""The README and the docs pages: every ```python block runs as written, links resolve, the README
stays a landing page (at most 300 lines, with the docs index), its DK FMU interface table is the one
generated from the slave's variable table.

The blocks of one markdown file run in order in one namespace, in a temporary working directory (so an
output file lands there; maps go to the project's map cache, as for a user); a block whose first line is ``# not run`` is skipped.  A
failing block is reported with its file and line: the block is compiled with the markdown file as its
file name and its own line numbers, so the traceback points into the markdown.
"""
from __future__ import annotations

import re
import traceback
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
NOT_RUN = "# not run"
MAX_README_LINES = 300


def markdown_files() -> list[Path]:
    """README.md and every page under docs/, in a fixed order."""
    return [README, *sorted(DOCS.rglob("*.md"))]


def python_blocks(text: str) -> list[tuple[int, str]]:
    """The ```python blocks of a markdown text: (line number of the block's first code line, 1-based;
    code).  Blocks whose first line is ``# not run`` are left out.  An unclosed block is an error."""
    blocks, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].strip() == "```python":
            start, j = i + 1, i + 1
            while j < len(lines) and lines[j].strip() != "```":
                j += 1
            if j == len(lines):
                raise ValueError(f"line {i + 1}: ```python block is not closed")
            code = "\n".join(lines[start:j])
            if not code.lstrip().startswith(NOT_RUN):
                blocks.append((start + 1, code))
            i = j
        i += 1
    return blocks


def run_blocks(path: Path, blocks) -> None:
    """Run ``blocks`` of ``path`` in order in one namespace; raise AssertionError naming file and line."""
    namespace = {"__name__": "__docs__"}
    rel = path.relative_to(ROOT)
    for k, (line, code) in enumerate(blocks, 1):
        try:
            exec(compile("\n" * (line - 1) + code, str(rel), "exec"), namespace)
        except Exception as exc:            # noqa: BLE001 - any failure of a snippet is the finding
            tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__, limit=-3))
            raise AssertionError(f"{rel}:{line}: python block {k} of {len(blocks)} fails: "
                                 f"{type(exc).__name__}: {exc}\n{tb}") from None


def _with_blocks():
    return [p for p in markdown_files() if python_blocks(p.read_text())]


@pytest.mark.parametrize("path", _with_blocks(), ids=lambda p: str(p.relative_to(ROOT)))
def test_python_blocks_run(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    run_blocks(path, python_blocks(path.read_text()))


def test_block_collection_and_failure_report(tmp_path):
    text = ("# t\n\n```python\nx = 1\n```\n\n```python\n# not run\nraise SystemExit\n```\n\n"
            "```bash\nfalse\n```\n\n```python\ny = x + 1\nassert y == 3, 'y is 2'\n```\n")
    blocks = python_blocks(text)
    assert [line for line, _ in blocks] == [4, 17]
    page = ROOT / "docs" / "_probe.md"         # a path under ROOT, never written
    with pytest.raises(AssertionError, match=r"docs/_probe\.md:17: python block 2 of 2 fails: AssertionError: y is 2"):
        run_blocks(page, blocks)
    with pytest.raises(ValueError, match="line 1: ```python block is not closed"):
        python_blocks("```python\nx = 1\n")


def test_readme_is_a_landing_page():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines (at most {MAX_README_LINES})"
    assert "docs/index.md" in README.read_text(), "README.md does not link the docs index"
    index = (DOCS / "index.md").read_text()
    missing = [p.name for p in sorted(DOCS.glob("*.md")) if p.name != "index.md" and f"({p.name})" not in index]
    assert not missing, f"docs/index.md does not list {missing}"


_LINK = re.compile(r"\]\(([^)\s]+)\)")


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    bad = []
    for target in _LINK.findall(path.read_text()):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        file = target.split("#", 1)[0]
        if not (path.parent / file).exists():
            bad.append(target)
    assert not bad, f"{path.relative_to(ROOT)}: links to missing files {bad}"


def test_readme_interface_table_is_generated():
    from cosim.fmus.interface_table import interface_table, slave_class

    text = README.read_text()
    start, end = "<!-- interface:RRRDirectKinematics -->", "<!-- /interface:RRRDirectKinematics -->"
    assert start in text and end in text, "README.md lacks the interface table markers"
    found = text.split(start, 1)[1].split(end, 1)[0].strip()
    assert found == interface_table(slave_class("RRRDirectKinematics")), \
        "README.md's DK FMU interface table is stale: run python -m cosim.fmus.interface_table"


def test_interface_table_lists_every_variable_in_value_reference_order():
    from cosim.fmus.interface_table import InterfaceTableError, interface_table, replace_table, slave_class

    cls = slave_class("RRRDirectKinematics")
    lines = interface_table(cls).splitlines()[2:]
    assert [line.split(" | ")[1].strip("`") for line in lines] == [v.name for v in cls.VARIABLES]
    assert [int(line.split(" | ")[0].lstrip("| ")) for line in lines] == [cls.VR[v.name] for v in cls.VARIABLES]
    assert replace_table("a\n<!-- interface:X -->\nold\n<!-- /interface:X -->\nb", "X", "T") == \
        "a\n<!-- interface:X -->\nT\n<!-- /interface:X -->\nb"
    with pytest.raises(InterfaceTableError, match="interface:X"):
        replace_table("no markers", "X", "T")
    with pytest.raises(InterfaceTableError, match="name: expected one of"):
        slave_class("NoSuchFMU")


def _report_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_report", ROOT / "bench" / "report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_report_replaces_only_its_section(tmp_path, monkeypatch):
    report = _report_module()
    monkeypatch.delenv("RRR_DK_NO_REPORT", raising=False)
    page, store, readme = tmp_path / "b.md", tmp_path / "h.json", tmp_path / "R.md"
    page.write_text("# B\n\nintro\n\n<!-- bench:a -->\nold a\n<!-- /bench:a -->\n\ntail\n")
    readme.write_text("x\n<!-- headline -->\n<!-- /headline -->\ny\n")
    body = report.table(["k", "v"], [("n", 1)])
    report.publish("a", body, command="python bench/a.py", headline=[("n", "1", ">= 1")], page=page, store=store,
                   readme=readme)
    report.publish("b", "new b", command="python bench/b.py", page=page, store=store, readme=readme)
    text = page.read_text()
    assert text.startswith("# B\n\nintro\n\n<!-- bench:a -->") and "old a" not in text and "tail" in text
    assert "| n | 1 |" in text and "`python bench/a.py`" in text and text.rstrip().endswith("<!-- /bench:b -->")
    assert re.search(r"\| n \| 1 \| >= 1 \| \[a\]\(docs/benchmarks.md#a\), load [0-9.]+ \|", readme.read_text())
    monkeypatch.setenv("RRR_DK_NO_REPORT", "1")
    assert report.publish("a", "changed", page=page, store=store, readme=readme) is None
    assert page.read_text() == text
    with pytest.raises(report.ReportError, match=r"rows\[0\]: expected 2 cells"):
        report.table(["k", "v"], [(1,)])
    with pytest.raises(report.ReportError, match="one marker without the other"):
        report.replace_section("<!-- bench:a -->", "a", "x")
