"""The DK's C entry point compiled beside the map (cosim.fmus.early_compile): what it stages and when it
begins, and that a failed child never fails a build.  The real compile (about 2 minutes) runs in every
first DK build, the session's included; these tests replace the child's script by a quick one."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from cosim.fmus import early_compile, kernels
from cosim.fmus.builds import DK_NAME, DK_STORES, _stage_script, project_packages, warm_up_scenario
from cosim.fmus.kernels import BESIDE, Run, Scenario, fmu_key
from cosim_support import fmus  # noqa: F401 (fixture)
from fmu_src.kernel_cache import GENERIC_CPU, kernel_files, key_of

#: the quick child: writes what it saw (the bundle's files, the CPU and cache it compiles for, pythonfmu's mark)
#: to $LOOK_OUT, then says it is done with the key of the bundle there, as the real child does
_LOOK = r"""
import json, os, pathlib, sys
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
files = sorted(p.relative_to(sys.argv[1]).as_posix() for p in pathlib.Path(sys.argv[1]).rglob("*.py"))
pathlib.Path(os.environ["LOOK_OUT"]).write_text(json.dumps({
    "files": files, "cpu": os.environ["NUMBA_CPU_NAME"], "cache": os.environ["NUMBA_CACHE_DIR"],
    "mark": os.path.isfile(os.path.join(sys.argv[1], cache.BUNDLE_MARK))}))
print("ENTRY " + cache.bundle_key(sys.argv[1]) + " 0.5")
"""


@pytest.fixture
def dk_script(tmp_path):
    return _stage_script(tmp_path, 1, "default", None)


def _scenario():
    return warm_up_scenario(DK_NAME, 1, "default")


def test_it_compiles_the_fmus_own_kernel_packages_for_the_generic_cpu(dk_script, tmp_path, monkeypatch,
                                                                     fmus):  # noqa: F811
    """The staged files give the key of the session's DK FMU (its kernel packages, byte for byte), the
    child sees them as an FMU bundle (pythonfmu's mark) and compiles for the generic CPU into the model's
    store folder; its compile seconds join the warm-up's record; the staging is removed after."""
    out = tmp_path / "seen.json"
    monkeypatch.setattr(early_compile, "_CHILD", _LOOK)
    monkeypatch.setenv("LOOK_OUT", str(out))
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=tmp_path / "store")
    assert early is not None and early.model == DK_NAME
    work = early._work
    assert early.finish()                                    # the child printed the key begin() computed
    assert not work.exists()
    seen = json.loads(out.read_text())
    assert seen["cpu"] == GENERIC_CPU and seen["mark"]
    assert Path(seen["cache"]) == tmp_path / "store" / DK_NAME
    assert early_compile.ENTRY in seen["files"]
    root = Path(__file__).resolve().parents[1]
    pairs = [(rel, (root / rel).read_bytes()) for rel in seen["files"]]
    assert kernel_files(pairs) and key_of(pairs) == early.key == fmu_key(fmus[DK_NAME])
    record = json.loads((tmp_path / "store" / DK_NAME / early.key / "warm-up.json").read_text())
    assert record["seconds"] == {f"{early_compile.ENTRY_KERNEL} {BESIDE}": 0.5} and record["warmed"] == []


#: a child that compiles for a while (3 s) and then succeeds
_SLOW = r"""
import sys, time
time.sleep(3)
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
print("ENTRY " + cache.bundle_key(sys.argv[1]) + " 3.0")
"""


def test_nothing_begins_without_an_entry_point_or_when_warmed_and_a_second_build_waits_for_the_first(
        dk_script, tmp_path, monkeypatch):
    monkeypatch.setattr(early_compile, "_CHILD", _SLOW)
    store = tmp_path / "store"
    # a bundle without the C entry point (a slave that does not import the solver)
    plain = tmp_path / "Plain.py"
    plain.write_text("import math\n")
    assert early_compile.begin(plain, project_packages(), Scenario([]), root=store) is None
    # another build warms this key up now: this one begins nothing (its warm-up waits for that one)
    key = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
    assert isinstance(key, early_compile.EarlyCompile)
    key.stop()
    (store / DK_NAME / key.key).mkdir(parents=True, exist_ok=True)
    with kernels._locked(store / DK_NAME / key.key / ".lock"):
        assert early_compile.begin(dk_script, project_packages(), _scenario(), root=store) is None
    # another process compiles this model's entry point: this build waits for that one
    first = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
    assert isinstance(first, early_compile.EarlyCompile)
    try:
        second = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
        assert isinstance(second, early_compile.Waiting)
        assert second.finish() and first._proc.wait(timeout=10) == 0   # it returned as the first child ended
    finally:
        first.stop()
    # the store holds this key warmed up along this scenario: a build starts no child, nor does this
    folder = store / DK_NAME / first.key
    folder.mkdir(parents=True, exist_ok=True)
    (folder / kernels._KEPT).write_text(json.dumps({"seconds": {"x": 1.0}, "warmed": [kernels._warmed(_scenario())]}))
    assert kernels.is_warmed(folder, _scenario())
    assert early_compile.begin(dk_script, project_packages(), _scenario(), root=store) is None
    # along another scenario it begins again
    other = Scenario([Run(3, 1e-3)])
    assert not kernels.is_warmed(folder, other)
    again = early_compile.begin(dk_script, project_packages(), other, root=store)
    assert again is not None
    again.stop()


def test_a_failed_child_says_so_and_fails_nothing(dk_script, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(early_compile, "_CHILD", "import sys\nprint('numba broke here')\nsys.exit(3)\n")
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=tmp_path / "store")
    assert early is not None
    assert early.finish() is False
    err = capsys.readouterr().err
    assert "failed (exit 3)" in err and "numba broke here" in err and "the warm-up compiles it instead" in err
    early.stop()                                             # idempotent


def test_stop_kills_a_running_child_and_frees_the_model_for_the_next_build(dk_script, tmp_path, monkeypatch):
    monkeypatch.setattr(early_compile, "_CHILD", "import time\ntime.sleep(60)\n")
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=tmp_path / "store")
    assert early is not None
    proc = early._proc
    early.stop()
    assert proc.poll() is not None and not early._work.exists()
    # the lock went with the child: the next build begins its own
    nxt = early_compile.begin(dk_script, project_packages(), _scenario(), root=tmp_path / "store")
    assert isinstance(nxt, early_compile.EarlyCompile)
    nxt.stop()


def _fake_kernels(folder: Path, seconds: dict, warmed=()) -> None:
    """A store folder with two index/data files and a warm-up record (what a warm-up leaves)."""
    (folder / "solver" / "_kernels").mkdir(parents=True, exist_ok=True)
    for name in ("c_entry._step-1.py311.nbi", "c_entry._step-1.py311.1.nbc"):
        (folder / "solver" / "_kernels" / name).write_bytes(name.encode())
    (folder / kernels._KEPT).write_text(json.dumps({"seconds": seconds, "warmed": list(warmed)}))


def test_a_new_store_folder_is_seeded_from_another_dk_of_the_same_code(dk_script, tmp_path, monkeypatch, capsys):
    """One DK FMU's compile serves the others: the early compile and the warm-up of a model whose store folder
    of this key is empty copy the kernels (and their compile seconds) of another model's folder of the key;
    a folder that holds kernels, a model of another key and a folder being written are left alone."""
    monkeypatch.setattr(early_compile, "_CHILD", "print('no compile here')\n")
    store = tmp_path / "store"
    key = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
    key.stop()
    rpr = store / "RPRDirectKinematics" / key.key
    _fake_kernels(rpr, {"solver._kernels.c_entry._publish": 72.7}, warmed=["x"])
    _fake_kernels(store / "RRRDirectKinematics3" / "other-key", {"y": 1.0})
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=store, seeds=DK_STORES)
    early.stop()
    mine = store / DK_NAME / key.key
    assert sorted(p.name for p in mine.rglob("*.nb*")) == sorted(p.name for p in rpr.rglob("*.nb*"))
    assert kernels._readable_record(mine) == {"seconds": {"solver._kernels.c_entry._publish": 72.7}, "warmed": [],
                                              "seeded_from": "RPRDirectKinematics"}
    assert not list(mine.rglob("*.seed-*"))                  # written under temporary names, renamed
    # a folder with kernels of its own is not seeded again
    (rpr / "solver" / "_kernels" / "extra-9.py311.nbi").write_bytes(b"x")
    kernels.seed(mine, [rpr])
    assert not (mine / "solver" / "_kernels" / "extra-9.py311.nbi").exists()
    # a source whose warm-up holds its lock is skipped (not waited for: no deadlock between two builds)
    fresh = store / "RRRDirectKinematics3" / key.key
    fresh.mkdir(parents=True)
    with kernels._locked(rpr / ".lock"):
        kernels.seed(fresh, [rpr])
    assert not any(fresh.rglob("*.nb*"))
    assert kernels.seed(fresh, [fresh, store / "nothing" / key.key, rpr]) == "RPRDirectKinematics"
    assert (fresh / "solver" / "_kernels" / "extra-9.py311.nbi").is_file()
    # a seed that cannot be written fails nothing: it says so, and the warm-up compiles
    (tmp_path / "a-file").write_text("")
    assert kernels.seed(tmp_path / "a-file" / key.key, [rpr]) is None
    assert "were not seeded" in capsys.readouterr().err


def test_a_compile_time_recorded_twice_keeps_the_longer(tmp_path):
    """A later early compile that found the entry point compiled (a second) does not replace its real time."""
    kernels.record_seconds(tmp_path, {"e": 104.2})
    kernels.record_seconds(tmp_path, {"e": 0.4, "f": 2.0})
    assert kernels._readable_record(tmp_path)["seconds"] == {"e": 104.2, "f": 2.0}


def test_the_dk_store_names_are_the_dk_fmus_models():
    from cosim.fmus.fmi3_build import DK3_NAME
    from cosim.fmus.rpr_build import RPR_NAME

    assert DK_STORES == (DK_NAME, DK3_NAME, RPR_NAME)


#: a child whose entry point compiled and whose tracker kernels then failed, then one where both compiled
_TRACKER_FAILED = r"""
import sys
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
print("ENTRY " + cache.bundle_key(sys.argv[1]) + " 2.0")
print("the tracker's own kernels were not compiled: ValueError: a toy map broke")
"""
_BOTH = r"""
import sys
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
print("ENTRY " + cache.bundle_key(sys.argv[1]) + " 2.0")
print("TRACKER " + cache.bundle_key(sys.argv[1]) + " 1.5")
"""


def test_the_tracker_kernels_compiled_after_the_entry_point_are_recorded_and_their_failure_fails_nothing(
        dk_script, tmp_path, monkeypatch, capsys):
    for child, seconds in ((_BOTH, {early_compile.ENTRY_KERNEL: 2.0, early_compile.TRACKER_KERNELS: 1.5}),
                           (_TRACKER_FAILED, {early_compile.ENTRY_KERNEL: 2.0})):
        monkeypatch.setattr(early_compile, "_CHILD", child)
        store = tmp_path / ("store" + str(len(seconds)))
        early = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
        assert early is not None and early.finish()              # the entry point compiled: a success
        record = json.loads((store / DK_NAME / early.key / "warm-up.json").read_text())
        assert record["seconds"] == {f"{name} {BESIDE}": s for name, s in seconds.items()}
    err = capsys.readouterr().err
    assert "the tracker's own kernels were not compiled: ValueError: a toy map broke" in err
    assert "the warm-up compiles them" in err and "failed (exit" not in err


def test_pending_says_whether_a_build_would_compile_the_entry_point(dk_script, tmp_path, monkeypatch):
    store = tmp_path / "store"
    plain = tmp_path / "Plain.py"
    plain.write_text("import math\n")
    assert not early_compile.pending(plain, project_packages(), root=store)      # no entry point
    assert early_compile.pending(dk_script, project_packages(), root=store)      # a first build of this code
    monkeypatch.setattr(early_compile, "_CHILD", _BOTH)
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
    assert early.finish()                                                        # the record is written
    assert not early_compile.pending(dk_script, project_packages(), root=store)
    assert not early_compile.pending(dk_script, ["/no/such/package"], root=store)   # cannot tell: False


def test_the_real_child_compiles_the_tracker_kernels_from_the_project_file(dk_script, tmp_path, fmus):  # noqa: F811
    """The real child (not a stand-in): solver.precompile is not bundled, so the child loads it from the
    building project's file and runs it on the staged solver; here on a copy of the session's store for
    this code (the entry point and the tracker's kernels load from it: seconds, not a compile)."""
    key = fmu_key(fmus[DK_NAME])
    store = tmp_path / "store"
    shutil.copytree(kernels.generic_root() / DK_NAME / key, store / DK_NAME / key,
                    ignore=shutil.ignore_patterns("*.tmp*", "*.lock", "*.seed-*", kernels._KEPT))
    early = early_compile.begin(dk_script, project_packages(), _scenario(), root=store)
    assert isinstance(early, early_compile.EarlyCompile) and early.key == key
    work = early._work
    early._proc.wait(timeout=600)
    out = (work / "out.txt").read_text()
    assert early.finish(), out
    assert f"ENTRY {key} " in out and f"TRACKER {key} " in out, out
    record = json.loads((store / DK_NAME / key / kernels._KEPT).read_text())
    assert f"{early_compile.TRACKER_KERNELS} {BESIDE}" in record["seconds"]


def test_a_background_build_lowers_its_own_priority_only():
    """``--background`` (what build_fmus passes on a first build of the DK's code) lowers the build process's
    priority by BACKGROUND_NICE (capped at 19), not its parent's."""
    import os
    import subprocess
    import sys

    from cosim.fmus import early_compile, fmu_set

    code = "import os; from cosim.fmus.early_compile import lower_priority; a = os.nice(0); lower_priority(); print(a, os.nice(0))"
    before, after = map(int, subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                            cwd=Path(__file__).resolve().parents[1]).stdout.split())
    assert after == min(before + early_compile.BACKGROUND_NICE, 19)
    assert os.nice(0) == before
    assert "--background" in fmu_set._build_args("RRRPlant", Path("out"), None, None, background=True)
    assert "--background" not in fmu_set._build_args("RRRPlant", Path("out"), None, None)
