"""The direct-kinematics FMU (fmu_src/RRRDirectKinematics.py, built by build_fmu.py): build, model
description, the paper's circle (fmpy.simulate_fmu, libcosim), build options, damaged map resources.

Built once per module into a temporary folder with a coarse map (40 mm / 6 deg, the reference
configuration of ``cosim.fmus.references.REFERENCE``) and run for real in this process, compared with the
in-process ``solver.Tracker``.  Stepping it through FMU2Slave: test_fmu_dk_stepping.py.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import shutil
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from cosim.fmus import builds, kernels, references
from cosim.fmus.checks import smoke_check, validate
from cosim.fmus.cli import main as build_main
from cosim.hosts.libcosim import LibcosimError, run_libcosim
from cosim.simulation import input_table, simulate
from cosim.unit import FMUUnit
from solver import CACHE_ENV, DEFAULT_RULE, HOME_POSE, MapTensor, Tracker, cache_dir, dk_all, ik, singularity_measures

from dk_fmu_support import (BOUND, BUDGET, CERTAINTY, H, MODEL, N, OUTPUTS, PATH, RES, X0, Q, circle_start, result_rows,
                            tracker_rows)
from dk_fmu_support import built, built_multi, fmu, hygiene, make, map1, md, tmp, unzipdir  # noqa: F401 (fixtures)


# ---------------------------------------------------------------------- build and model description
def test_fmu_validates(built, fmu):
    assert built.problems == []
    assert validate(fmu) == []
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
    assert {"resources/maps/posture1.npz", "resources/maps/manifest.json", "resources/solver/tracker.py",
            "resources/RRRDirectKinematics.py", "documentation/_main.html", "documentation/index.md"} <= names


def test_model_description(md, map1):
    v = {x.name: x for x in md.modelVariables}
    expected = {"q1": ("input", "continuous", "rad"), "q2": ("input", "continuous", "rad"),
                "q3": ("input", "continuous", "rad"),
                "x0": ("parameter", "fixed", "m"), "y0": ("parameter", "fixed", "m"),
                "phi0": ("parameter", "fixed", "rad"), "posture": ("parameter", "fixed", None),
                "mode": ("parameter", "fixed", None), "joint_tolerance": ("parameter", "fixed", "rad"),
                "speed_bound_linear": ("parameter", "fixed", "m/s"),
                "speed_bound_angular": ("parameter", "fixed", "rad/s"),
                "stuck_after": ("parameter", "fixed", None),
                "start_tolerance_linear": ("parameter", "fixed", "m"),
                "start_tolerance_angular": ("parameter", "fixed", "rad"),
                "step_budget_share": ("parameter", "fixed", "1"), "out_of_budget": ("output", "discrete", None),
                "geometry_tolerance": ("parameter", "fixed", "m"),
                "x_bound": ("output", "continuous", "m"), "y_bound": ("output", "continuous", "m"),
                "phi_bound": ("output", "continuous", "rad"), "trust": ("output", "discrete", None),
                "x": ("output", "continuous", "m"), "y": ("output", "continuous", "m"),
                "phi": ("output", "continuous", "rad"), "cond": ("output", "continuous", "1"),
                "region": ("output", "discrete", None), "near_border": ("output", "discrete", None),
                "n_real": ("output", "discrete", None), "ambiguous": ("output", "discrete", None),
                "status": ("output", "discrete", None),
                "certain": ("output", "discrete", None), "uncertain_since": ("output", "discrete", "s")}
    assert {n: (x.causality, x.variability, x.unit) for n, x in v.items()} == expected
    ints = ("posture", "mode", "region", "n_real", "status", "stuck_after", "trust")
    assert {n: v[n].type for n in ints} == dict.fromkeys(ints, "Integer")
    assert v["near_border"].type == v["ambiguous"].type == "Boolean"
    # every output depends on exactly q1..q3; InitialUnknowns list every output
    assert {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs} == \
        {n: ["q1", "q2", "q3"] for n in OUTPUTS + CERTAINTY + BOUND + BUDGET}
    assert {u.variable.name for u in md.initialUnknowns} == set(OUTPUTS + CERTAINTY + BOUND + BUDGET)
    assert {u.name for u in md.unitDefinitions} == {"1", "m", "rad", "s", "m/s", "rad/s"}
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    # start values: the home pose and its joints in posture 1; posture 1 (1..8), default mode
    assert [float(v[n].start) for n in ("x0", "y0", "phi0")] == list(HOME_POSE)
    q_home = ik(MODEL, np.array(HOME_POSE), 1)
    assert [float(v[n].start) for n in ("q1", "q2", "q3")] == q_home.tolist()
    assert (int(v["posture"].start), int(v["posture"].min), int(v["posture"].max)) == (1, 1, 8)
    assert int(v["mode"].start) == 0


def test_home_pose_is_inside_and_far_from_singularities(map1, make):
    X = np.array(HOME_POSE)
    q = ik(MODEL, X, 1)
    sm = singularity_measures(MODEL, X, q)
    assert np.all(np.isfinite(q))
    assert sm.type1 > 0.5 and sm.type2 > 0.5          # 0.75 and 0.63: well away from both singularities
    assert map1.near_labels(X)[0] == 0 and map1.label_at(X) != 0          # inside the tool space, no border
    # the FMU with its start values: outputs = the home pose, status ok, one region, no warning
    m = make()
    x, y, phi, region, near_border, n_real, ambiguous, status, cond = m.outputs()
    # the honest start: the DK solution of the joints within start_tolerance of (x0, y0, phi0), proved
    start = Tracker(MODEL, map1).reset(X, q)
    assert start.certain and (x, y, phi) == tuple(start.X) and np.abs(start.X - X).max() < 1e-12
    assert m.get_values(BOUND + ("certain",)) == [*start.pose_bound.tolist(), 2, True]
    assert status == 0 and not ambiguous and not near_border
    assert region == map1.label_at(X) and n_real == dk_all(MODEL, q).n_real and cond > 0.4
    assert m.errors(least=1) == []


def test_build_is_deterministic_and_reuses_the_map(built, tmp):
    logs = []
    again = builds.build_dk(tmp / "again", postures=(1,), resolution=RES, cache_dir=tmp / "maps", log=logs.append)
    assert any("reused" in m for m in logs) and not any("built " in m for m in logs)
    assert again.fmu.read_bytes() == built.fmu.read_bytes()


def test_two_fresh_builds_are_byte_identical(built, tmp):
    """A build from scratch (a map built anew, in another folder) gives the same bytes: no wall times,
    paths or dates in the artifacts, so the GUID is a function of the inputs alone."""
    logs = []
    fresh = builds.build_dk(tmp / "fresh", postures=(1,), resolution=RES, cache_dir=tmp / "fresh_maps",
                            log=logs.append)
    assert any("built" in m for m in logs) and not any("reused" in m for m in logs)
    assert fresh.maps[1].read_bytes() == built.maps[1].read_bytes()
    assert fresh.fmu.read_bytes() == built.fmu.read_bytes()


def test_command_line(built, tmp, capsys, monkeypatch):
    out = tmp / "cli"
    generic = kernels.generic_root()
    monkeypatch.setenv(CACHE_ENV, str(tmp / "cli_cache"))              # the CLI uses the one map cache
    shutil.copytree(generic, kernels.generic_root(),                    # and kernel cache: reused, not compiled
                    ignore=shutil.ignore_patterns("*.tmp*", "*.lock", "*.seed-*"))   # (not another worker's writes)
    cached = builds.map_cache_path(tmp / "maps", 1, RES, DEFAULT_RULE, MODEL)
    in_cache = builds.map_cache_path(None, 1, RES, DEFAULT_RULE, MODEL)
    assert in_cache.parent == cache_dir("maps")
    in_cache.parent.mkdir(parents=True)
    in_cache.write_bytes(cached.read_bytes())                           # reused, not rebuilt
    assert build_main(["--out", str(out), "--resolution", "40mm,6deg"]) == 0
    text = capsys.readouterr().out
    assert "reused" in text and "validation: OK" in text and "MB" in text
    assert (out / "RRRDirectKinematics.fmu").read_bytes() == built.fmu.read_bytes()
    # built with the reference's options: the reference runs ran these FMUs, none built again
    assert text.count("equal to the kept") == 3 and not list((out / "reference").glob("*.fmu"))
    # a given map file (the DK FMU only: the command's default path, all three and the references, ran above)
    assert build_main(["--out", str(out), "--map", str(cached), "--posture", "1", "--only", "RRRDirectKinematics",
                       "--no-reference"]) == 0
    assert "validation: OK" in capsys.readouterr().out
    assert (out / "RRRDirectKinematics.fmu").read_bytes() == built.fmu.read_bytes()
    assert build_main(["--out", str(out), "--resolution", "40 furlongs"]) == 2


@pytest.mark.parametrize("text, expected", [
    ("10mm,2deg", (0.01, np.deg2rad(2))), ("40 6", (0.04, np.deg2rad(6))), (["40", "6"], (0.04, np.deg2rad(6))),
    ("0.04m 6deg", (0.04, np.deg2rad(6))), ("1cm,0.05rad", (0.01, 0.05)), ("2.5mm;1.5deg", (0.0025, np.deg2rad(1.5))),
])
def test_parse_resolution(text, expected):
    assert builds.parse_resolution(text) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("text", ["10mm", "10kg,2deg", "0mm,2deg", "a,b", "1 2 3"])
def test_parse_resolution_rejects(text):
    with pytest.raises(ValueError, match="resolution"):
        builds.parse_resolution(text)


# ---------------------------------------------------------------------- the paper's circle
def test_circle_in_fmpy_matches_tracker_and_reference(fmu, map1):
    result = references.run_circle(fmu)                              # fmpy.simulate_fmu, raises on refusals
    assert len(result) == N + 1
    np.testing.assert_array_equal(result["time"], np.arange(N + 1) * H)
    rows = result_rows(result)
    # row 0: the initial pose before any doStep; row k+1: the pose for q[k], exactly the in-process tracker's
    assert rows[0][:3] == tuple(Tracker(MODEL, map1).reset(X0, Q[0]).X) and rows[0][OUTPUTS.index("status")] == 0
    assert rows[1:] == tracker_rows(map1, Q)
    # the tracker follows the circle (the true solution, not another assembly mode)
    pose = np.column_stack([result["x"], result["y"], result["phi"]])
    assert np.abs(pose[1:] - PATH).max() < 1e-9
    assert set(result["status"]) == {0} and 0 not in set(result["region"])
    # ... and matches the stored reference run (fmu_src/reference/RRRDirectKinematics.csv): first what does
    # not depend on the map's numbering of the solutions, then the numbering-dependent columns
    header, ref = references.read_reference_csv()
    assert len(ref) == len(result)
    for name in ("time", "q1", "q2", "q3", "x", "y", "phi", "cond"):
        np.testing.assert_allclose(result[name], ref[name], rtol=0, atol=1e-12, err_msg=name)
    for name in ("n_real", "status"):
        np.testing.assert_array_equal(result[name].astype(int), ref[name], err_msg=name)
    assert any(f"labels_sha256 {map1.checksum()}" in h for h in header), \
        "the reference was made with another map (labels): python build_fmu.py --write-reference"
    for name in ("region", "near_border", "ambiguous"):
        np.testing.assert_array_equal(result[name].astype(int), ref[name], err_msg=name)


def test_paper_mode_parameter(fmu, map1):
    table = input_table(np.arange(N) * H, q1=Q[:, 0], q2=Q[:, 1], q3=Q[:, 2])
    result = simulate(fmu, stop_time=N * H, step_size=H, inputs=table, outputs=list(OUTPUTS),
                      start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2], "mode": 1})
    assert result_rows(result)[1:] == tracker_rows(map1, Q, mode="paper")


def test_libcosim_runs_the_circle(fmu, map1):
    n = 300
    result = run_libcosim(fmu, step_size=H, n_steps=n, inputs={"q1": Q[:n, 0], "q2": Q[:n, 1], "q3": Q[:n, 2]},
                          start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]})
    np.testing.assert_allclose(result.time, (np.arange(n) + 1) * H, rtol=1e-12)
    got = list(zip(*(result[name].tolist() for name in OUTPUTS)))
    # the tracker does not use the time step: libcosim's output is the tracker's, bit for bit
    assert got == tracker_rows(map1, Q[:n])
    # a bad input: libcosim's step fails ("Step not complete"); the helper raises with the slave's reason
    bad = Q[:20, 0].copy()
    bad[7] = math.nan
    with pytest.raises(LibcosimError, match="Step not complete") as info:
        run_libcosim(fmu, step_size=H, n_steps=20, inputs={"q1": bad, "q2": Q[:20, 1], "q3": Q[:20, 2]},
                     start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]})
    assert "'q1' = nan" in str(info.value) and len(info.value.partial.time) == 7


def test_smoke_check(fmu):
    q = Q[:40]
    assert smoke_check(fmu, n_steps=40, step_size=H, inputs={"q1": q[:, 0], "q2": q[:, 1], "q3": q[:, 2]},
                       start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2]}) == []


# ---------------------------------------------------------------------- postures and build options
def test_several_postures_and_the_mode_build_option(built_multi, tmp, make):
    assert sorted(built_multi.maps) == [1, 2] and built_multi.problems == []
    md2 = read_model_description(str(built_multi.fmu))
    v = {x.name: x for x in md2.modelVariables}
    assert (int(v["posture"].start), int(v["mode"].start)) == (2, 1)
    assert [float(v[n].start) for n in ("q1", "q2", "q3")] == ik(MODEL, np.array(HOME_POSE), 2).tolist()
    dir2 = extract(str(built_multi.fmu), unzipdir=str(tmp / "multi_unzipped"))
    q2 = ik(MODEL, PATH, 2)
    map2 = MapTensor.load(built_multi.maps[2])
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2]}
    m = make("p2", fmu_=built_multi.fmu, dir_=dir2, **start, q1=q2[0, 0], q2=q2[0, 1], q3=q2[0, 2])
    assert [m.step(q) for q in q2[:150]] == tracker_rows(map2, q2[:150], mode="paper")
    m1 = make("p1", fmu_=built_multi.fmu, dir_=dir2, **circle_start(), posture=1, mode=0)
    assert [m1.step(q) for q in Q[:150]] == tracker_rows(MapTensor.load(built_multi.maps[1]), Q[:150])
    # a posture without an embedded map: exitInitializationMode refuses it with fmi2Error (state error),
    # and every step is refused (fmi2Error, by the loader's state table) with the state and the reason
    m3 = FMUUnit(built_multi.fmu, "p3", unzip_dir=dir2, logging_on=True)
    try:
        with pytest.raises(FMICallException) as init:
            m3.initialize(0.0, {"posture": 3})
        assert init.value.status == fmi2Error
        assert any("fmi2ExitInitializationMode: initialization failed" in msg
                   and "embeds maps of posture(s) [1, 2] only" in msg for msg in m3.errors())
        assert m3.get_values(OUTPUTS)[OUTPUTS.index("status")] == 3
        with pytest.raises(FMICallException) as info:
            m3.fmu.doStep(0.0, H)
        assert info.value.status == fmi2Error
        assert any("fmi2DoStep refused in state error" in msg and "embeds maps" in msg for msg in m3.errors())
    finally:
        m3.close()


# ---------------------------------------------------------------------- damaged map resources
def _rewrite(src: Path, dest: Path, replace: dict[str, bytes | None]) -> Path:
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for info in z.infolist():
            if info.filename in replace:
                if replace[info.filename] is not None:
                    out.writestr(info, replace[info.filename])
            else:
                out.writestr(info, z.read(info))
    return dest


def _manifest_for(fmu: Path, data: bytes) -> bytes:
    with zipfile.ZipFile(fmu) as z:
        manifest = json.loads(z.read("resources/maps/manifest.json"))
    manifest["maps"][0].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())
    return json.dumps(manifest).encode()


def _altered_labels(path: Path) -> bytes:
    """The map file with one label changed and its metadata (recorded checksum) kept."""
    with np.load(path) as data:
        labels, meta = np.array(data["labels"]), data["metadata"]
    flat = labels.reshape(-1)
    flat[np.flatnonzero(flat)[0]] ^= 3
    buf = io.BytesIO()
    np.savez_compressed(buf, labels=labels, metadata=meta)
    return buf.getvalue()


@pytest.mark.parametrize("damage, message", [
    ("truncated", "is truncated or modified"),
    ("missing", "resources/maps/posture1.npz, is missing"),
    ("no manifest", "manifest.json is missing"),
    ("labels", "labels checksum"),
    ("foreign", "built for posture 2, expected 1"),
])
def test_damaged_map_fails_instantiation(fmu, built_multi, md, tmp, caplog, damage, message):
    with zipfile.ZipFile(fmu) as z:
        original = z.read("resources/maps/posture1.npz")
    if damage == "truncated":
        replace = {"resources/maps/posture1.npz": original[: len(original) // 2]}
    elif damage == "missing":
        replace = {"resources/maps/posture1.npz": None}
    elif damage == "no manifest":
        replace = {"resources/maps/manifest.json": None}
    else:
        # map bytes that pass the manifest check (updated with them): MapTensor.load must catch them
        data = (_altered_labels(Path(built_multi.maps[1])) if damage == "labels"
                else Path(built_multi.maps[2]).read_bytes())
        replace = {"resources/maps/posture1.npz": data, "resources/maps/manifest.json": _manifest_for(fmu, data)}
    bad = _rewrite(fmu, tmp / f"damaged_{damage.replace(' ', '_')}.fmu", replace)
    unzipped = extract(str(bad), unzipdir=str(tmp / f"damaged_{damage.replace(' ', '_')}"))
    with pytest.raises(Exception, match="Failed to instantiate") as failed:
        FMUUnit(bad, "bad", unzip_dir=unzipped, logging_on=True)
    messages = failed.value.messages
    assert any("MapTensorFileError" in m and message in m for _, m in messages), messages
    assert any(message in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)
    caplog.clear()
    with pytest.raises(Exception, match="Failed to instantiate"):          # what a user of fmpy sees ...
        fmpy.simulate_fmu(str(bad), stop_time=0.01)
    assert any(message in r.getMessage() for r in caplog.records)           # ... and the reason, on stderr


def test_the_fmu_bundles_only_what_its_slave_imports(fmu):
    with zipfile.ZipFile(fmu) as z:
        packages = {n.split("/")[1] for n in z.namelist() if n.startswith("resources/") and n.count("/") > 1}
        names = set(z.namelist())
    assert packages == {"fmu_src", "kernels", "maps", "pythonfmu", "solver"}    # no dynamics (kernels: compiled)
    assert "resources/fmu_src/table_slave.py" in names and "resources/cosim/fmus/packaging.py" not in names
    assert not {"resources/solver/__main__.py"} & names
