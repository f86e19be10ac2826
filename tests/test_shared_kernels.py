"""Kernels compiled once (solver.shared_kernels): a process that runs its own ``solver`` loads the
generic-CPU kernels an FMU build compiled (the generic store, cosim.fmus.kernels) instead of compiling
them again for its own CPU, while its files are the ones the FMU bundled."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

from cosim.fmus.kernels import generic_root
from cosim_support import fmus  # noqa: F401 (fixture)
from solver.shared_kernels import FILES

ROOT = Path(__file__).resolve().parents[1]

#: the children's one step: a tracker on the map (argv[1]), its honest start on the paper circle, one step
_STEP_ONE = r"""
model = Manipulator.paper()
X = circle_path(50)
q = ik(model, X, 1)
tracker = Tracker(model, MapTensor.load(sys.argv[1]), start_tolerance=(1e-9, 1e-9, 1e-9))
tracker.reset(X[0], q[0], warn=False)
pose, info = tracker.step(q[1])
"""

#: a fresh process with an empty numba cache of its own: the DK slave's in-process path (a tracker on a
#: map, its honest start, steps through the C entry point), then what it loaded from where
_CHILD = r"""
import json, sys
import numpy as np
from solver import Manipulator, MapTensor, Tracker, circle_path, ik, shared_kernels
from solver._kernels.c_entry import entry
""" + _STEP_ONE + r"""
for k in range(2, 6):
    pose, info = tracker.step(q[k])
print(json.dumps({"entry_hits": entry().cache_hits, "served": shared_kernels.served(),
                  "error": float(np.abs(pose - X[5]).max()), "certain": bool(info.certain)}))
"""


def _child(script: str, *args, numba_cache: Path, **env_extra) -> dict:
    """Run ``script`` with ``args`` in a fresh process with the numba cache ``numba_cache``; its last line, JSON."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
    env.update(NUMBA_CACHE_DIR=str(numba_cache), PYTHONPATH=str(ROOT), **env_extra)
    proc = subprocess.run([sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _dk_map(fmus, folder: Path) -> Path:
    """The map file the session's DK FMU embeds, written into ``folder``."""
    with zipfile.ZipFile(Path(fmus["RRRDirectKinematics"])) as z:
        name = next(n for n in z.namelist() if n.startswith("resources/") and n.endswith(".npz"))
        map_file = folder / Path(name).name
        map_file.write_bytes(z.read(name))
    return map_file


def test_a_fresh_process_steps_with_the_kernels_the_fmu_build_compiled(fmus, tmp_path):  # noqa: F811
    """After the FMU build, a process whose numba cache is empty runs the tracker's step from the generic
    store: the C entry point is a cache hit (no compile), the poses are right; the store folder says
    which files it was compiled from."""
    map_file = _dk_map(fmus, tmp_path)
    records = list((generic_root() / "RRRDirectKinematics").glob(f"*/{FILES}"))
    assert records, "the DK FMU build wrote no record of its bundled files"
    files = json.loads(max(records, key=lambda p: p.stat().st_mtime).read_text())
    assert "solver/_kernels/c_entry.py" in files and not any(n.startswith("fmu_src/") for n in files)
    got = _child(_CHILD, map_file, numba_cache=tmp_path / "numba")
    assert got["entry_hits"] == 1, got
    assert any(s.startswith("c_entry._step-") for s in got["served"]), got
    assert got["error"] < 1e-9 and got["certain"]


#: a process that compiles a kernel before any FMU build filled the store (its first miss finds no store),
#: then finds the store filled (an FMU build that ran meanwhile) and steps the tracker
_LATE = r"""
import json, shutil, sys
from pathlib import Path
import numpy as np
from solver import Manipulator, MapTensor, Tracker, cache_dir, circle_path, ik, shared_kernels
from solver._kernels.c_entry import entry
from solver._kernels.linalg import wrap

store = cache_dir("fmu-kernels-generic")
assert not store.exists()
wrap(7.0)                                                   # a miss with no store: compiled here
before = shared_kernels.served()
# the build that ran meanwhile (not the files another test process writes into it now: xdist)
shutil.copytree(sys.argv[2], store, ignore=shutil.ignore_patterns("*.tmp*", "*.lock", "*.seed-*"))
""" + _STEP_ONE + r"""
print(json.dumps({"before": before, "entry_hits": entry().cache_hits, "served": shared_kernels.served(),
                  "error": float(np.abs(pose - X[1]).max())}))
"""


def test_a_store_filled_after_the_first_miss_serves_the_later_ones(fmus, tmp_path):  # noqa: F811
    """The store is looked up at every miss, not once per process: a process whose first kernel compiled
    before the FMU build filled the store (the test session, ``python -m cosim`` checking a robot first)
    loads the C entry point from it afterwards instead of compiling it for its own CPU."""
    got = _child(_LATE, _dk_map(fmus, tmp_path), generic_root(), numba_cache=tmp_path / "numba",
                 RRR_DK_CACHE=str(tmp_path / "cache"))
    assert got["before"] == [] and got["entry_hits"] == 1, got
    assert any(s.startswith("c_entry._step-") for s in got["served"]) and got["error"] < 1e-9, got


#: a process with no generic store at all (a batch worker on another machine) that extracts the DK FMU through
#: the project's host (cosim.unit) and then steps its own tracker
_FROM_FMU = r"""
import json, sys
import numpy as np
from solver import Manipulator, MapTensor, Tracker, cache_dir, circle_path, ik, shared_kernels
from solver._kernels.c_entry import entry
from cosim.unit import extracted

folder, _ = extracted(sys.argv[2])
assert not cache_dir("fmu-kernels-generic").exists()
""" + _STEP_ONE + r"""
print(json.dumps({"entry_hits": entry().cache_hits, "served": shared_kernels.served(),
                  "error": float(np.abs(pose - X[1]).max()), "not_an_fmu": shared_kernels.serve_from_fmu(sys.argv[3])}))
"""


def test_the_kernels_an_fmu_ships_serve_a_process_without_the_store(fmus, tmp_path):  # noqa: F811
    """A process with neither the store nor a numba cache (a batch worker that received the FMU files) loads
    its solver's kernels from the FMUs it extracted (solver.shared_kernels.serve_from_fmu), not compiling."""
    got = _child(_FROM_FMU, _dk_map(fmus, tmp_path), fmus["RRRDirectKinematics"], tmp_path,
                 numba_cache=tmp_path / "numba", RRR_DK_CACHE=str(tmp_path / "cache"))
    assert got["entry_hits"] == 1, got
    assert any(s.startswith("c_entry._step-") for s in got["served"]) and got["error"] < 1e-9, got
    assert got["not_an_fmu"] is False


def test_the_fmu_runtimes_names_are_the_solvers():
    """solver.shared_kernels reads the FMU's layout without importing the FMU runtime (the math never imports
    FMI code): its copies of the runtime's names must be the runtime's."""
    from fmu_src import kernel_cache
    from solver import shared_kernels

    assert (shared_kernels._SHIPPED, shared_kernels._MANIFEST, shared_kernels._NO_KERNELS, shared_kernels.GENERIC_CPU) \
        == (kernel_cache.SHIPPED, kernel_cache.MANIFEST, kernel_cache.NO_KERNELS, kernel_cache.GENERIC_CPU)


def test_an_fmu_whose_sources_are_not_its_keys_serves_nothing(fmus, tmp_path, monkeypatch):  # noqa: F811
    """serve_from_fmu takes an FMU's kernels only while its bundled sources give its manifest's key: sources
    edited after the build (a re-zipped FMU) would pair kernels of one code with the sources of another."""
    from solver import shared_kernels

    monkeypatch.setattr(shared_kernels, "_fmu_sources", {})
    for name in ("as-built", "edited"):
        with zipfile.ZipFile(Path(fmus["RRRDirectKinematics"])) as z:
            z.extractall(tmp_path / name)
    edited = tmp_path / "edited" / "resources" / "solver" / "angles.py"
    edited.write_text(edited.read_text() + "\n# edited after the build\n")
    assert shared_kernels.serve_from_fmu(tmp_path / "as-built" / "resources") is True
    assert shared_kernels.serve_from_fmu(tmp_path / "edited" / "resources") is False
    assert list(shared_kernels._fmu_sources) == [str(tmp_path / "as-built" / "resources")]
