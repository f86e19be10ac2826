"""cosim.batch: sweeps of closed-loop co-simulations on dask (local process pool and a separate cluster).

The FMUs are built once per session into a temporary folder with a coarse DK map (40 mm, 6 deg);
runs are short (t_end = 0.6 s).  No FMU is loaded into the pytest process itself: the runs happen in
dask worker processes, and the serial mode runs in a subprocess (``python -m cosim.batch --serial``).
The external cluster is a ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, started
here and always killed at the end.
"""
from __future__ import annotations

import csv
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cosim import batch
from cosim.batch import ConfigError, expand, parse_sweep_arg, parse_value

ROOT = Path(__file__).resolve().parents[1]
T_END = 0.6
#: A circle whose start is reachable but that leaves the workspace at ~0.2 s: an FMU refuses a step.
LEAVES_WORKSPACE = 0.85
#: A circle whose start pose is outside the workspace: the run fails before the first step.
OUTSIDE = 2.0
METRICS = ("rms_joint_error", "max_joint_error", "max_dk_vs_true", "dk_branch_errors", "dk_status_ok",
           "dk_status_unreachable", "dk_status_singular", "dk_status_rejected", "dk_status_diverged", "n_steps")


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory):
    """The folder of the session's three FMUs (coarse map; :func:`host_support.session_fmus`)."""
    from host_support import session_fmus

    return Path(session_fmus(tmp_path_factory)["RRRDirectKinematics"]).parent


def _read_csv(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _num(v):
    return None if v == "" else float(v)


@pytest.fixture(scope="module")
def local_batch(fmu_dir, tmp_path_factory):
    """A config-file sweep (2 x 2 product + 2 failing cases) on a LocalCluster of 2 processes, via the CLI."""
    tmp = tmp_path_factory.mktemp("batch_local")
    cfg = tmp / "sweep.toml"
    cfg.write_text(f"""
[batch]
fmu_dir = "{fmu_dir}"
out = "{tmp / 'out'}"
workers = 2
plot_x = "h"

[base]
t_end = {T_END}

[sweep]
h = [0.001, 0.002]
plant_mass_scale = [0.8, 1.2]

[[cases]]
radius = {OUTSIDE}

[[cases]]
radius = {LEAVES_WORKSPACE}
""")
    t0 = time.perf_counter()
    assert batch.main(["--config", str(cfg), "--no-progress"]) == 0
    return {"out": tmp / "out", "cfg": cfg, "seconds": time.perf_counter() - t0}


class _Procs:
    """Processes started by a test; each in its own session, killed by process group in close()."""

    def __init__(self):
        self.procs = []

    def start(self, args, log: Path, env=None):
        f = open(log, "wb")
        p = subprocess.Popen(args, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                             cwd=str(log.parent))
        f.close()
        self.procs.append(p)
        return p

    def close(self):
        for p in self.procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + 15
        for p in self.procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)
            try:  # the nanny's worker child is in the same group
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _wait_for(pattern: str, log: Path, proc, timeout: float) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = log.read_text(errors="replace") if log.exists() else ""
        m = re.search(pattern, text)
        if m:
            return m.group(1)
        if proc.poll() is not None:
            raise RuntimeError(f"{proc.args[:3]} exited with {proc.returncode}:\n{text[-2000:]}")
        time.sleep(0.1)
    raise TimeoutError(f"no {pattern!r} in {log} after {timeout} s:\n{log.read_text(errors='replace')[-2000:]}")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``dask scheduler`` + two ``dask worker`` processes on 127.0.0.1 (one process, one thread each)."""
    from distributed import Client

    tmp = tmp_path_factory.mktemp("dask_cluster")
    # the workers' own cache root (their FMU copies under fmus/); their compiled kernels are where this
    # process keeps its own (numba's places, stamped with the kernels' content), so they compile nothing
    env = dict(os.environ, RRR_DK_CACHE=str(tmp / "cache"), PYTHONUNBUFFERED="1")
    cache = tmp / "cache" / "fmus"
    procs = _Procs()
    client = None
    try:
        sched = procs.start([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                             "--port", "0", "--no-dashboard"], tmp / "scheduler.log", env)
        address = _wait_for(r"Scheduler at:\s*(tcp://127\.0\.0\.1:\d+)", tmp / "scheduler.log", sched, 60)
        for name in ("w1", "w2"):
            procs.start([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "1",
                         "--nthreads", "1", "--name", name, "--host", "127.0.0.1", "--no-dashboard",
                         "--local-directory", str(tmp / name)], tmp / f"{name}.log", env)
        client = Client(address, timeout="30s")
        client.wait_for_workers(2, timeout=90)
        yield {"address": address, "client": client, "cache": cache, "tmp": tmp}
    finally:
        if client is not None:
            client.close()
        procs.close()


# ---------------------------------------------------------------------- sweeps and config (no FMU)
def test_parse_sweep_arg():
    assert parse_sweep_arg("h=0.001,0.002") == ("h", [0.001, 0.002])
    assert parse_sweep_arg("plant-mass-scale=0.8:1.2:3") == ("plant_mass_scale", [0.8, 1.0, 1.2])
    assert parse_sweep_arg("order=jacobi,gauss-seidel") == ("order", ["jacobi", "gauss-seidel"])
    assert parse_sweep_arg("center=[0.45,0.3],[0.5, 0.3]") == ("center", [(0.45, 0.3), (0.5, 0.3)])
    assert parse_sweep_arg("posture=1,2") == ("posture", [1, 2])
    for bad in ("h", "nope=1", "h=abc", "posture=1.5", "center=[1,2,3]", "h="):
        with pytest.raises(ConfigError):
            parse_sweep_arg(bad)
    with pytest.raises(ConfigError, match="number"):
        parse_value("radius", True)


def test_expand_product_groups_and_cases():
    runs = expand({"t_end": 1}, {"h": [1e-3, 2e-3], "order": ["gauss-seidel", "jacobi"],
                                 "circle": {"radius": [0.2, 0.25], "center": [[0.45, 0.3], [0.5, 0.3]]}},
                  [{"radius": 0.85}])
    assert len(runs) == 2 * 2 * 2 + 1
    assert all(r["t_end"] == 1.0 and isinstance(r["t_end"], float) for r in runs)
    # product order: the first dimension varies slowest
    assert [(r["h"], r["order"], r["radius"]) for r in runs[:3]] == [
        (1e-3, "gauss-seidel", 0.2), (1e-3, "gauss-seidel", 0.25), (1e-3, "jacobi", 0.2)]
    assert {(r["radius"], r["center"]) for r in runs[:-1]} == {(0.2, (0.45, 0.3)), (0.25, (0.5, 0.3))}
    assert runs[-1]["radius"] == 0.85 and runs[-1]["h"] == 1e-3          # a case is base + its fields
    assert set(runs[0]) == set(batch.SCENARIO_FIELDS)
    with pytest.raises(ConfigError, match="equal length"):
        expand({}, {"g": {"radius": [0.2], "period": [1.0, 2.0]}})
    with pytest.raises(ConfigError, match="twice"):
        expand({}, {"radius": [0.2], "g": {"radius": [0.3]}})


def test_example_config_and_dry_run(capsys, tmp_path):
    cfg = batch.load_config(ROOT / "bench" / "sweep_example.toml")
    assert len(expand(cfg["base"], cfg["sweep"], cfg["cases"])) == 25
    assert batch.main(["--config", str(ROOT / "bench" / "sweep_example.toml"), "--sweep", "h=0.001",
                       "--t-end", "0.3", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("13 runs; varying: order,") and " h=" not in out      # h no longer varies
    bad = tmp_path / "bad.toml"
    bad.write_text("[sweeep]\nh = [1]\n")
    assert batch.main(["--config", str(bad), "--dry-run"]) == 2
    assert batch.main(["--sweep", "radius=big", "--dry-run"]) == 2


# ---------------------------------------------------------------------- local process pool
def test_local_cluster_sweep(local_batch):
    out = local_batch["out"]
    rows = _read_csv(out / "batch.csv")
    assert [int(r["run"]) for r in rows] == list(range(6))
    assert list(rows[0]) == list(batch.COLUMNS)
    ok = rows[:4]
    assert [r["status"] for r in rows] == ["ok"] * 4 + ["failed", "failed"]
    assert {(float(r["h"]), float(r["plant_mass_scale"])) for r in ok} == {
        (h, m) for h in (0.001, 0.002) for m in (0.8, 1.2)}
    for r in ok:
        n = round(T_END / float(r["h"]))
        assert int(r["n_steps"]) == n and int(r["dk_status_ok"]) == n and int(r["dk_branch_errors"]) == 0
        assert 0 < float(r["rms_joint_error"]) < 1e-2
        assert float(r["max_joint_error"]) >= float(r["rms_joint_error"])
        assert float(r["max_dk_vs_true"]) < 1e-9
        assert float(r["wall_seconds"]) > float(r["sim_seconds"]) > 0
        assert r["error"] == "" and r["worker"] in ("0", "1") and r["host"]
    # the first run of a process loads the FMUs; later ones reuse the ClosedLoop (reset), except
    # after a failed run (its instances are retired)
    for worker in {r["worker"] for r in ok}:
        mine = sorted((int(r["loop_runs"]), float(r["load_seconds"])) for r in ok if r["worker"] == worker)
        assert mine[0][1] > 0
    outside, leaves = rows[4], rows[5]
    assert "start pose" in outside["error"] and "outside posture 1" in outside["error"]
    assert outside["rms_joint_error"] == "" and float(outside["radius"]) == OUTSIDE
    assert "fmi2DoStep failed" in leaves["error"] and "refused" in leaves["error"]      # the FMU's reason
    meta = json.loads((out / "batch_meta.json").read_text())
    assert meta["n_runs"] == 6 and meta["n_failed"] == 2 and meta["fmu_transfer"] == "path"
    assert len(meta["workers"]) == 2 and all(w["nthreads"] == 1 for w in meta["workers"].values())
    import pyarrow.parquet as pq

    table = pq.read_table(out / "batch.parquet").to_pylist()
    assert [t["status"] for t in table] == [r["status"] for r in rows]
    for t, r in zip(table, rows):                                    # CSV floats round-trip exactly
        for k in ("rms_joint_error", "max_dk_vs_true", "h", "center_x"):
            assert (t[k] is None and r[k] == "") or t[k] == float(r[k])
    png = out / "batch_summary.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_serial_subprocess_matches_workers(local_batch, tmp_path):
    """The same config run serially in one process (one ClosedLoop reused) gives the same numbers bit for bit."""
    out = tmp_path / "serial"
    p = subprocess.run([sys.executable, "-m", "cosim.batch", "--config", str(local_batch["cfg"]), "--serial",
                        "--out", str(out), "--no-plot", "--no-progress"], capture_output=True, text=True,
                       timeout=300, cwd=str(tmp_path))
    assert p.returncode == 0, p.stdout + p.stderr
    assert "4/6 runs ok" in p.stdout
    serial, pooled = _read_csv(out / "batch.csv"), _read_csv(local_batch["out"] / "batch.csv")
    for s, q in zip(serial, pooled):
        assert s["status"] == q["status"] and s["worker"] == "local"
        assert [s[k] for k in METRICS] == [q[k] for k in METRICS]
        assert s["error"].split(" | ")[0] == q["error"].split(" | ")[0]


# ---------------------------------------------------------------------- separate scheduler and workers
def test_cli_on_external_cluster_with_fmu_bytes(cluster, fmu_dir, tmp_path):
    out = tmp_path / "out"
    code = batch.main(["--scheduler", cluster["address"], "--fmu-dir", str(fmu_dir), "--t-end", str(T_END),
                       "--sweep", "bandwidth=40,60", "--sweep", "order=gauss-seidel,jacobi",
                       "--out", str(out), "--no-plot", "--no-progress"])
    assert code == 0
    rows = _read_csv(out / "batch.csv")
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert {r["worker"] for r in rows} <= {"w1", "w2"}
    meta = json.loads((out / "batch_meta.json").read_text())
    assert meta["fmu_transfer"] == "bytes" and meta["cluster"] == cluster["address"]
    # the workers wrote the files they received under their cache folder, named by SHA-256
    for name, info in meta["fmus"].items():
        cached = cluster["cache"] / info["sha256"] / f"{name}.fmu"
        assert cached.read_bytes() == (fmu_dir / f"{name}.fmu").read_bytes()
    assert batch.main(["--scheduler", cluster["address"], "--fmu-dir", str(fmu_dir), "--strict", "--no-plot",
                       "--set", f"radius={OUTSIDE}", "--t-end", "0.1", "--out", str(tmp_path / "strict")]) == 1


def test_determinism_across_workers_and_failures(cluster, fmu_dir):
    """Each worker runs A, B, F (fails), A, B: every A (and B) gives the same metrics, on both workers."""
    client = cluster["client"]
    spec = batch.fmu_spec({n: fmu_dir / f"{n}.fmu" for n in batch.FMU_NAMES})
    (a,) = expand({"t_end": T_END, "plant_mass_scale": 1.1, "bandwidth": 40.0})
    (b,) = expand({"t_end": T_END, "h": 0.002, "order": "jacobi", "tracker_mode": "paper", "damping": 0.7})
    (f,) = expand({"t_end": T_END, "radius": LEAVES_WORKSPACE})
    workers = sorted(client.scheduler_info()["workers"])
    assert len(workers) == 2
    seen = {"A": [], "B": []}
    for w in workers:
        for i, (label, params) in enumerate([("A", a), ("B", b), ("F", f), ("A", a), ("B", b)]):
            row = client.submit(batch.run_task, i, params, spec, None, 0.5, workers=[w],
                                allow_other_workers=False, pure=False).result(timeout=180)
            if label == "F":
                assert row["status"] == "failed" and "refused" in row["error"]
                continue
            assert row["status"] == "ok", row["error"]
            if i == 1 or i == 4:
                assert row["load_seconds"] == 0.0          # B after A: the same ClosedLoop, reset
            if i == 3:
                assert row["load_seconds"] > 0.0           # A after the failure: fresh instances
            seen[label].append(row)
    assert {r["worker"] for r in seen["A"]} == {"w1", "w2"}
    for label, rows in seen.items():
        ref = [repr(rows[0][k]) for k in METRICS]
        for r in rows[1:]:
            assert [repr(r[k]) for k in METRICS] == ref, label       # bit for bit (repr of the floats)
        assert all(math.isfinite(r["rms_joint_error"]) for r in rows)
    assert seen["A"][0]["rms_joint_error"] != seen["B"][0]["rms_joint_error"]
    # the FMU set loaded from bytes by the CLI test (same SHA-256) is reused for these path-mode runs;
    # the failure retired the instances, so the A after it ran on fresh ones
    states = client.run(batch.worker_state)
    for st in states.values():
        assert len(st["fmu_sets"]) == 1 and set(st["loaded"]) == set(batch.FMU_NAMES)
        assert st["instances_created"] >= 2


# ---------------------------------------------------------------------- worker-side helpers (no FMU loaded)
def test_materialize_checks_hash_and_reuses(tmp_path, monkeypatch):
    import hashlib

    monkeypatch.setenv("RRR_DK_CACHE", str(tmp_path))
    data = b"not really an FMU"
    sha = hashlib.sha256(data).hexdigest()
    path = batch.materialize("RRRPlant", sha, data)
    assert path == tmp_path / "fmus" / sha / "RRRPlant.fmu" and path.read_bytes() == data
    assert batch.materialize("RRRPlant", sha, data) == path               # already there
    with pytest.raises(RuntimeError, match="SHA-256"):
        batch.materialize("RRRPlant", "0" * 64, data)
    assert sorted(p.name for p in tmp_path.rglob("*")) == sorted(["fmus", sha, "RRRPlant.fmu"])   # no temp left


def test_another_build_in_the_same_process_is_refused(monkeypatch, fmu_dir):
    spec = batch.fmu_spec({n: fmu_dir / f"{n}.fmu" for n in batch.FMU_NAMES})
    monkeypatch.setitem(batch.worker.STATE, "loaded", {"RRRPlant": "f" * 64})
    monkeypatch.setitem(batch.worker.STATE, "loops", {})
    created = batch.worker.STATE["created"]
    with pytest.raises(batch.FMUBuildConflict, match="restart the workers"):
        batch.get_loop(spec, None)
    row = batch.run_task(7, expand({"t_end": 0.1})[0], spec)
    assert row["status"] == "failed" and row["error"].startswith("FMUBuildConflict")
    assert batch.worker.STATE["created"] == created                              # nothing was loaded here
