"""numba's cache of the project's kernels is stamped with the content of the whole kernel folder.

numba alone stamps a cached kernel with its own file: a kernel that reads a constant from another
module kept its old machine code after that module changed (a CI cache kept between runs failed
with "cannot assign slice of shape (0,) from input of shape (3,)").  A small kernel package in a
temporary folder, run in fresh processes, shows the stamp at work.
"""
import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import dynamics._kernels
import solver._kernels
from solver._kernels import cache_stamp

ROOT = Path(__file__).resolve().parents[1]

KERNEL = textwrap.dedent("""
    import numpy as np
    from numba import njit

    from .consts import N


    @njit(cache=True)
    def size():
        return np.zeros(N).size
""")
INIT = textwrap.dedent("""
    import os
    from solver._kernels.cache_stamp import stamp_by_content

    stamp_by_content(os.path.dirname(os.path.abspath(__file__)))
""")


def _package(tmp_path: Path, n: int) -> Path:
    pkg = tmp_path / "pkg" / "_k"
    pkg.mkdir(parents=True, exist_ok=True)
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text(INIT)
    (pkg / "fill.py").write_text(KERNEL)
    (pkg / "consts.py").write_text(f"N = {n}\n")
    return pkg


def _run(tmp_path: Path, cache: str | None) -> tuple[int, str]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]), NUMBA_DEBUG_CACHE="1")
    env.pop("NUMBA_CACHE_DIR", None)
    if cache:
        env["NUMBA_CACHE_DIR"] = cache
    out = subprocess.run([sys.executable, "-c", "from pkg._k.fill import size; print('size', size())"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    line = [s for s in out.stdout.splitlines() if s.startswith("size ")][-1]
    return int(line.split()[1]), out.stdout


@pytest.mark.parametrize("where", ["pycache", "NUMBA_CACHE_DIR"])
def test_a_constant_changed_in_another_module_recompiles_the_kernel(tmp_path, where):
    cache = str(tmp_path / "numba-cache") if where == "NUMBA_CACHE_DIR" else None
    pkg = _package(tmp_path, 3)
    assert _run(tmp_path, cache)[0] == 3
    size, log = _run(tmp_path, cache)
    assert size == 3 and "data loaded" in log                  # the cache serves an unchanged tree
    place = Path(cache) if cache else pkg / "__pycache__"
    assert list(place.rglob("fill.size-*.nbi"))               # where numba would have put it
    (pkg / "consts.py").write_text("N = 5\n")                  # fill.py itself is unchanged
    assert _run(tmp_path, cache)[0] == 5


def test_the_key_covers_every_module_of_the_folder_and_its_dependencies(tmp_path):
    pkg = _package(tmp_path, 3)
    key = cache_stamp.content_key([str(pkg)])
    assert cache_stamp.content_key([str(pkg)]) == key
    (pkg / "consts.py").write_text("N = 4\n")
    assert cache_stamp.content_key([str(pkg)]) != key
    # the same tree elsewhere has the same key
    other = _package(tmp_path / "elsewhere", 4)
    assert cache_stamp.content_key([str(other)]) == cache_stamp.content_key([str(pkg)])
    # the project's folders: dynamics' kernels depend on the solver's
    here = os.path.join(os.path.dirname(solver._kernels.__file__), "")
    there = os.path.join(os.path.dirname(dynamics._kernels.__file__), "")
    assert cache_stamp._FOLDERS[here] == (here,)
    assert cache_stamp._FOLDERS[there] == (there, here)


#: what a kernel folder may import of the project: itself and the kernel folders before it (solver's before dynamics')
KERNEL_FOLDERS = {"solver": ("solver._kernels",), "dynamics": ("dynamics._kernels", "solver._kernels")}
PROJECT = ("solver", "dynamics", "fmu_src", "cosim", "experiments")


def test_kernel_modules_import_only_the_kernel_folders_their_keys_cover():
    """Both caches of compiled kernels key a kernel on the bytes of its ``_kernels`` folder and of the kernel
    folders before it (``cache_stamp``'s ``depends_on``; ``fmu_src.kernel_cache``'s per-folder keys, which let an
    FMU load another FMU's shipped kernels): a kernel module that imported a constant from elsewhere in the
    project would bake it into machine code those keys do not cover."""
    wrong = []
    for package, allowed in KERNEL_FOLDERS.items():
        for path in sorted((ROOT / package / "_kernels").glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.level == 1:
                    continue                                   # the same folder
                names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else
                         [a.name for a in node.names] if isinstance(node, ast.Import) else
                         [f"{'.' * node.level}{node.module or ''}"] if isinstance(node, ast.ImportFrom) else [])
                for name in names:
                    if name.startswith(".") or (name.split(".")[0] in PROJECT
                                                and not any(name == a or name.startswith(a + ".") for a in allowed)):
                        wrong.append(f"{path.relative_to(ROOT)}:{node.lineno}: {name}")
    assert not wrong, wrong
