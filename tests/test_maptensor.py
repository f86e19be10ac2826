"""Procedure 1 (map tensor) and procedure 2 (near labels)."""
import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from solver import (FORMAT_VERSION, Manipulator, MapTensor, MapTensorFileError, default_bounds, dk_all, ik,
                    label_poses, map_path)
from conftest import pose_distance

STEP = (0.05, 0.05, np.deg2rad(10.0))


@pytest.fixture(scope="module")
def small_map(model):
    b = default_bounds(model, STEP)
    span = b[:, 1] - b[:, 0]
    shape = (int(round(span[0] / STEP[0])) + 1, int(round(span[1] / STEP[1])) + 1, 36)
    return MapTensor.build(model, 3, bounds=b, shape=shape)


def all_nodes(mt):
    xs, ys, ps = mt.axes()
    return np.stack(np.meshgrid(xs, ys, ps, indexing="ij"), axis=-1)


def test_every_labelled_node_is_its_own_solution(model, small_map):
    X = all_nodes(small_map).reshape(-1, 3)
    lab = small_map.labels.ravel()
    q = ik(model, X, small_map.posture)
    np.testing.assert_array_equal(lab == 0, np.isnan(q[:, 0]))      # 0 exactly where IK fails
    on = lab > 0
    sol = dk_all(model, q[on], rule=small_map.rule)
    mine = sol.poses[np.arange(on.sum()), lab[on] - 1]
    assert np.all(sol.real[np.arange(on.sum()), lab[on] - 1])
    assert np.max(pose_distance(mine.real, X[on])) < 1e-8
    assert small_map.stats["max_node_solution_distance"] < 1e-8
    assert len(np.unique(lab[on])) >= 3


def test_build_is_deterministic_and_checks_arguments(model, small_map):
    again = MapTensor.build(model, small_map.posture, bounds=small_map.bounds, shape=small_map.shape)
    assert again.checksum() == small_map.checksum()
    assert again.labels.tobytes() == small_map.labels.tobytes()
    with pytest.raises(ValueError, match="posture"):
        MapTensor.build(model, 9, shape=(5, 5, 5))
    with pytest.raises(ValueError, match="rule"):
        MapTensor.build(model, 1, shape=(5, 5, 5), rule="random")
    with pytest.raises(ValueError, match="bounds"):
        MapTensor.build(model, 1, bounds=[[1, 0], [0, 1], [-3, 3]], shape=(5, 5, 5))
    with pytest.raises(ValueError, match="shape"):
        MapTensor.build(model, 1, shape=(5, 1, 5))


def test_default_bounds_cover_the_reachable_tool_space(model, rng):
    b = default_bounds(model)
    X = np.column_stack([rng.uniform(-1, 2, 400000), rng.uniform(-1, 2, 400000),
                         rng.uniform(-np.pi, np.pi, 400000)])
    reach = ~np.isnan(ik(model, X, 1)[:, 0])
    inside = np.all((X[:, :2] >= b[:2, 0]) & (X[:, :2] <= b[:2, 1]), axis=1)
    assert np.all(inside[reach])
    # and they are tight: reachable poses come within 2 cm of every side
    Xr = X[reach]
    assert np.all(Xr[:, :2].min(axis=0) - b[:2, 0] < 0.02)
    assert np.all(b[:2, 1] - Xr[:, :2].max(axis=0) < 0.02)
    np.testing.assert_allclose(b[2], [-np.pi, np.pi])


# ------------------------------------------------------------------ file format
def test_save_load_round_trip(model, small_map, tmp_path):
    path = small_map.save(tmp_path / "m.npz")
    back = MapTensor.load(path, model=model, posture=small_map.posture)
    assert back.labels.tobytes() == small_map.labels.tobytes()
    assert back.shape == small_map.shape and back.rule == small_map.rule
    np.testing.assert_array_equal(back.bounds, small_map.bounds)
    meta = json.loads(str(np.load(path)["metadata"]))
    for key in ("format_version", "geometry", "posture", "bounds", "shape", "rule", "library_version",
                "labels_sha256"):
        assert key in meta


def _rewrite(path, out, labels=None, meta_update=None):
    with np.load(path) as d:
        lab = np.array(d["labels"]) if labels is None else labels
        meta = json.loads(str(d["metadata"]))
    meta.update(meta_update or {})
    np.savez_compressed(out, labels=lab, metadata=np.array(json.dumps(meta)))
    return out


def test_loader_refuses_bad_files(model, small_map, tmp_path):
    good = small_map.save(tmp_path / "good.npz")
    tampered_labels = np.array(small_map.labels)
    i = np.argwhere(tampered_labels > 0)[0]
    tampered_labels[tuple(i)] = tampered_labels[tuple(i)] % 6 + 1
    cases = {
        "checksum": _rewrite(good, tmp_path / "tampered.npz", labels=tampered_labels),
        "format version": _rewrite(good, tmp_path / "v99.npz", meta_update={"format_version": 99}),
        "unreadable or truncated": tmp_path / "trunc.npz",
        "not a map tensor": tmp_path / "other.npz",
        "no such": tmp_path / "missing.npz",
        "geometry record": _rewrite(good, tmp_path / "geo.npz",
                                    meta_update={"geometry_sha256": "0" * 64}),
    }
    cases["unreadable or truncated"].write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    np.savez(cases["not a map tensor"], x=np.zeros(3))
    for word, path in cases.items():
        with pytest.raises(MapTensorFileError, match=word):
            MapTensor.load(path)
    other = Manipulator.symmetric(base_side=1.0, l1=0.6, l2=0.65, platform_side=0.3, name="longer")
    with pytest.raises(MapTensorFileError, match="expected 'longer'"):
        MapTensor.load(good, model=other)
    with pytest.raises(MapTensorFileError, match="posture 3, expected 1"):
        MapTensor.load(good, posture=1)
    assert issubclass(MapTensorFileError, ValueError)
    assert FORMAT_VERSION == json.loads(str(np.load(good)["metadata"]))["format_version"]


# ------------------------------------------------------------------ procedure 2
def brute_near(mt, X, r, w):
    nodes = all_nodes(mt)
    d = nodes - X
    d[..., 2] = np.angle(np.exp(1j * d[..., 2]))
    near = np.einsum("...k,k->...", d * d, w) <= r * r
    out = np.zeros(7, bool)
    out[np.unique(mt.labels[near])] = True
    return out


def test_near_labels_match_brute_force(small_map, rng):
    mt = small_map
    b = mt.bounds
    X = np.column_stack([rng.uniform(b[0, 0] - 0.1, b[0, 1] + 0.1, 300),
                         rng.uniform(b[1, 0] - 0.1, b[1, 1] + 0.1, 300),
                         rng.uniform(-np.pi, np.pi, 300)])
    X[:40, 2] = np.pi - rng.uniform(0, 0.05, 40)                   # across the phi wrap
    X[40:80, 2] = -np.pi + rng.uniform(0, 0.05, 40)
    X[80:100, 0] = b[0, 0] + rng.uniform(-0.02, 0.02, 20)          # at the grid edges
    X[100:120, 1] = b[1, 1] + rng.uniform(-0.02, 0.02, 20)
    for r, w in ((None, None), (0.07, (1.0, 1.0, 0.01)), (0.2, (2.0, 0.5, 0.1)), (0.03, (1, 1, 1))):
        ww = mt.default_weights if w is None else np.asarray(w, float)
        rr = mt.default_radius(ww) if r is None else r
        got = mt.near_labels(X, r, w)
        for k in range(len(X)):
            np.testing.assert_array_equal(got[k], brute_near(mt, X[k], rr, ww), err_msg=f"{X[k]} r={rr}")
        single = mt.near_labels(X[0], r, w)
        np.testing.assert_array_equal(single, got[0])


def test_label_at_is_the_nearest_node(small_map, rng):
    mt = small_map
    nodes = all_nodes(mt).reshape(-1, 3)
    X = nodes[rng.integers(0, len(nodes), 200)] + rng.uniform(-0.4, 0.4, (200, 3)) * mt.step
    X[:20, 2] = np.pi - 0.2 * mt.step[2]                           # nearest node across the wrap
    X[20:40, 2] = -np.pi + 0.2 * mt.step[2]
    for k, x in enumerate(X):
        d = np.abs(nodes - x) / mt.step
        d[:, 2] = np.abs(np.angle(np.exp(1j * (nodes[:, 2] - x[2])))) / mt.step[2]
        j = np.argmin(np.max(d, axis=1))
        assert mt.label_at(x) == mt.labels.ravel()[j]
    assert mt.label_at([5.0, 5.0, 0.0]) == 0


def test_border_nodes_match_brute_force(small_map, rng):
    mt = small_map
    border = mt.border_nodes()
    reach = np.argwhere(mt.labels > 0)
    for idx in reach[rng.integers(0, len(reach), 150)]:
        X = mt.node_pose(idx)
        near = brute_near(mt, X, mt.default_radius(), mt.default_weights)
        near[0] = False
        assert border[tuple(idx)] == (near.sum() > 1)
    assert 0 < mt.border_fraction() < 1


def test_label_poses_outside_is_zero(model):
    lab, mm = label_poses(model, np.array([[5.0, 5.0, 0.0], [0.5, 0.3, 0.1]]), 1)
    assert lab[0] == 0 and lab[1] > 0 and mm[1] < 1e-9


def test_cli_build_inspect_plot(tmp_path):
    out = tmp_path / "maps"
    run = lambda *a, pkg="solver": subprocess.run([sys.executable, "-m", pkg, *a], capture_output=True,
                                                  text=True, timeout=300)
    r = run("build", "--posture", "2", "--step-mm", "60", "--step-deg", "15", "--out", str(out))
    assert r.returncode == 0, r.stderr
    f = map_path(Manipulator.paper(), 2, step=(0.06, 0.06, np.deg2rad(15.0)), cache_dir=out)
    assert f.exists()
    r = run("inspect", str(f))
    assert r.returncode == 0 and "posture 2" in r.stdout and "reachable nodes" in r.stdout
    r = run("plot", str(f), "--phi", "0", "--out", str(tmp_path / "png"), pkg="experiments")
    assert r.returncode == 0, r.stderr
    assert list((tmp_path / "png").glob("*.png"))
    r = run("inspect", str(tmp_path / "nothing.npz"))
    assert r.returncode != 0 and "no such map tensor file" in r.stderr
