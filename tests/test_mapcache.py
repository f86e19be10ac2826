"""The map cache: one documented location, deterministic map files, the CLI on several files."""
import json
import time
from pathlib import Path

import numpy as np
import pytest

from solver import CACHE_ENV, FORMAT_VERSION, MapTensor, SolverInputError, cache_dir, cached_map, map_path
from solver.__main__ import main
from solver.mapcache import default_cache_dir

#: A coarse grid of posture 2 (60 mm, 15 deg): a fraction of a second to build once compiled.
STEP = (0.06, 0.06, float(np.deg2rad(15.0)))


def test_cache_dir_follows_the_documented_rule(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "mine"))
    assert cache_dir() == (tmp_path / "mine").resolve()
    assert cache_dir("maps") == (tmp_path / "mine" / "maps").resolve()
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir("maps") == (tmp_path / "xdg" / "rrr-dk" / "maps").resolve()
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == (tmp_path / "home" / ".cache" / "rrr-dk").resolve()
    assert default_cache_dir() == cache_dir("maps")
    for bad in ("", "/abs", "../up"):
        with pytest.raises(SolverInputError, match="parts"):
            cache_dir(bad)


def test_cached_map_writes_to_the_cache_not_the_working_folder_and_says_where(model, monkeypatch, tmp_path,
                                                                               capsys):
    work, cache = tmp_path / "work", tmp_path / "cache"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv(CACHE_ENV, str(cache))
    mt = cached_map(model, 2, step=STEP, progress=True)
    path = map_path(model, 2, step=STEP)
    assert path.parent == (cache / "maps").resolve() and path.is_file()
    assert list(work.iterdir()) == []                                      # nothing in the working folder
    err = capsys.readouterr().err
    assert "building map tensor posture 2 at 60 mm, 15 deg" in err and str(path.parent) in err
    assert f"built {path}" in err and "done in" in err
    assert mt.build_seconds is not None and mt.build_seconds > 0
    again = cached_map(model, 2, step=STEP, progress=True)
    err = capsys.readouterr().err
    assert f"reused {path}" in err and "building" not in err
    assert again.build_seconds is None and again.labels.tobytes() == mt.labels.tobytes()
    cached_map(model, 2, step=STEP, progress=False)
    assert capsys.readouterr().err == ""


def test_two_fresh_builds_of_a_map_are_byte_identical(model, tmp_path):
    first = cached_map(model, 2, step=STEP, cache_dir=tmp_path / "a", progress=False)
    time.sleep(2.1)                                      # zip entry times have a 2 s resolution
    second = cached_map(model, 2, step=STEP, cache_dir=tmp_path / "b", progress=False)
    a, b = (map_path(model, 2, step=STEP, cache_dir=tmp_path / d) for d in "ab")
    assert first.build_seconds != second.build_seconds                    # the wall times differ...
    assert a.read_bytes() == b.read_bytes()                               # ...the files do not
    meta = json.loads(str(np.load(a)["metadata"]))
    assert meta["format_version"] == FORMAT_VERSION and "build_seconds" not in json.dumps(meta)
    assert MapTensor.load(a).labels.tobytes() == first.labels.tobytes()


def test_the_loader_says_which_version_it_reads(model, tmp_path):
    mt = cached_map(model, 2, step=STEP, cache_dir=tmp_path, progress=False)
    old = tmp_path / "old.npz"
    meta = json.loads(str(np.load(map_path(model, 2, step=STEP, cache_dir=tmp_path))["metadata"]))
    meta["format_version"] = FORMAT_VERSION - 1
    np.savez_compressed(old, labels=np.asarray(mt.labels), metadata=np.array(json.dumps(meta)))
    with pytest.raises(ValueError, match=rf"format version {FORMAT_VERSION - 1}.*reads only version "
                                         rf"{FORMAT_VERSION}.*build the map again"):
        MapTensor.load(old)


def test_cli_inspects_every_file_it_is_given(model, tmp_path, capsys):
    coarse = (0.08, 0.08, float(np.deg2rad(20.0)))
    files = [map_path(model, 2, step=s, cache_dir=tmp_path) for s in (STEP, coarse)]
    for s in (STEP, coarse):
        cached_map(model, 2, step=s, cache_dir=tmp_path, progress=False)
    assert main(["inspect", *map(str, files)]) == 0
    out = capsys.readouterr().out
    for f in files:
        assert f"{f}:" in out
    assert out.count("map tensor: posture 2") == 2
    assert main(["inspect", str(files[0]), str(tmp_path / "missing.npz")]) == 2
    captured = capsys.readouterr()
    assert f"{files[0]}:" in captured.out and "no such map tensor file" in captured.err


def test_cli_build_reports_where_and_how_fast(model, tmp_path, capsys):
    out = tmp_path / "maps"
    assert main(["build", "--posture", "2", "--step-mm", "60", "--step-deg", "15", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    f = map_path(model, 2, step=STEP, cache_dir=out)
    assert f"built {f}" in captured.out and Path(f).is_file()
    assert "building map tensor posture 2" in captured.err and "nodes/s" in captured.err


def test_loading_compiled_kernels_is_silent_once_they_are_compiled(model, capsys):
    from solver.mapcache import warm_up
    warm_up(model, 2, progress=False)                                     # compiled (or loaded) here
    seconds = warm_up(model, 2, progress=True)
    assert seconds < 2.0 and capsys.readouterr().err == ""
