"""What an FMU build reads of its sources (cosim.fmus.imports) and compiles once per process (the loader)."""
import textwrap

import pytest

from cosim.fmus import native
from cosim.fmus.imports import bundled_files, third_party_modules


def _package(tmp_path, files: dict):
    root = tmp_path / "pkg"
    root.mkdir()
    for name, text in files.items():
        (root / name).write_text(textwrap.dedent(text))
    return root


def test_the_imports_follow_the_package_and_an_edit_is_read_again(tmp_path):
    """The script's imports are followed through the package (relative imports, imports inside functions);
    the third-party ones are named, with scipy for a numba module that uses ``@``; and an edited module
    (the same process, the same path) is read again, not taken from the memo of its old text."""
    pkg = _package(tmp_path, {"__init__.py": "", "a.py": "from . import b\n",
                              "b.py": "def f():\n    import numpy\n", "c.py": "import numba\nx = y @ z\n"})
    script = tmp_path / "script.py"
    script.write_text("import pkg.a\nimport json\n")
    packages = {"pkg": pkg}
    assert list(bundled_files(script, packages)) == ["pkg/__init__.py", "pkg/a.py", "pkg/b.py"]
    files = [script, *bundled_files(script, packages).values()]
    assert third_party_modules(files, {"pkg"}) == {"numpy": ["b.py"]}
    (pkg / "b.py").write_text("from . import c\n")                     # b now reaches c, numba and scipy
    bundled = bundled_files(script, packages)
    assert list(bundled) == ["pkg/__init__.py", "pkg/a.py", "pkg/b.py", "pkg/c.py"]
    assert third_party_modules([script, *bundled.values()], {"pkg"}) == {"numba": ["c.py"], "scipy": ["c.py"]}


def test_the_loader_is_compiled_once_per_process_and_sources(tmp_path):
    """Every build of a process gets the same loader bytes from one compile; other sources compile anew."""
    if native.compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the loader cannot be built")
    first = native.compile_loader()
    before = native._compiled.cache_info()
    assert native.compile_loader() == first
    after = native._compiled.cache_info()
    assert (after.hits, after.misses) == (before.hits + 1, before.misses)
    changed = []
    for source in native.LOADER_FILES:
        copy = tmp_path / source.name
        copy.write_bytes(source.read_bytes() + (b"\n/* another build */\n" if source.suffix == ".c" else b""))
        changed.append(copy)
    assert native.compile_loader(files=tuple(changed)) == first       # a comment: the same machine code
    assert native._compiled.cache_info().misses == before.misses + 1
