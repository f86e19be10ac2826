"""Cold start: an FMU runs its first steps on a machine that never ran it without compiling a kernel.

The FMUs ship their kernels compiled for a generic x86-64 CPU (``resources/kernels/``,
:mod:`cosim.fmus.kernels`) and :mod:`fmu_src.kernel_cache` finds them wherever the FMU is extracted.
Each check runs in a child process that has not imported ``solver`` (the FMU runs its own copy),
with empty caches (``NUMBA_CACHE_DIR``, ``RRR_DK_CACHE``), and counts numba's compile events.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

from cosim.fmus.kernels import fmu_key
from fmu_src import kernel_cache
from host_support import session_fmus

NAMES = ("RRRDirectKinematics", "RRRPlant", "ComputedTorqueController")

#: argv: FMU, extraction folder, (optional) manifest text to put in place of the shipped one.
#: Prints the kernels numba compiled, the host log's messages and where ``solver`` came from.
#: the children's first lines: ``compiled``, the kernels numba compiles in this (host) process (their
#: qualified names) once ``listen()`` was called
LISTEN = textwrap.dedent(r"""
    compiled = []

    def listen():
        from numba.core import event

        class Compiles(event.Listener):
            def on_start(self, ev):
                compiled.append(ev.data["dispatcher"].py_func.__qualname__)
            def on_end(self, ev):
                pass
        event.register("numba:compile", Compiles())
""")

CHILD = LISTEN + textwrap.dedent(r"""
    import json, os, stat, sys

    late = os.environ.get("COLD_LATE_LISTENER") == "1"  # a host that has not imported numba when it instantiates
    if not late:
        listen()

    import fmpy
    from ctypes import byref
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
    from fmpy.logging import addLoggerProxy

    path, folder = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    extract(path, unzipdir=folder)
    if len(sys.argv) > 3:
        with open(os.path.join(folder, "resources", "kernels", "manifest.json"), "w") as f:
            f.write(sys.argv[3])
    for root, dirs, files in os.walk(folder):          # a read-only extraction
        for name in dirs + files:
            p = os.path.join(root, name)
            os.chmod(p, os.stat(p).st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    messages = []
    def logger(_c, _i, status, _cat, message):
        messages.append(message.decode("utf-8", "replace"))
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
    addLoggerProxy(byref(callbacks))
    outcome = {"outputs": [], "error": None}

    def host():
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="cold")
        try:
            fmu.instantiate(callbacks=callbacks, loggingOn=True)
        except Exception as exc:
            outcome["error"] = str(exc)
            return
        if late:
            listen()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        reals = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
        for k in range(10):
            fmu.doStep(k * 1e-3, 1e-3)
            outcome["outputs"].append(fmu.getReal(reals))

    stack = int(os.environ.get("COLD_STACK", "0"))
    if stack:                                          # a host thread with a small C stack
        import threading
        threading.stack_size(stack)
        thread = threading.Thread(target=host)
        thread.start()
        thread.join()
    else:
        host()
    solver = sys.modules.get("solver")
    print("COLD " + json.dumps({"compiled": compiled, "messages": messages, **outcome,
                                "solver": getattr(solver, "__file__", None)}))
    sys.stdout.flush()
    os._exit(0)
""")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


def _cold(fmu: Path, tmp: Path, env_extra=None, manifest=None) -> tuple[dict, Path]:
    """Run :data:`CHILD` on ``fmu`` with empty caches under ``tmp``; its report and the caches' folder."""
    caches = tmp / "caches"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    env.update({"NUMBA_CACHE_DIR": str(caches / "numba"), "RRR_DK_CACHE": str(caches / "rrr-dk"), **(env_extra or {})})
    args = [sys.executable, "-c", CHILD, str(fmu), str(tmp / "extracted")] + ([manifest] if manifest else [])
    proc = subprocess.run(args, capture_output=True, text=True, env=env, cwd=str(tmp), timeout=600)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("COLD ")), None)
    assert line is not None, f"the child failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    report = json.loads(line[5:])
    report["stderr"] = proc.stderr
    return report, caches


def _written(*folders: Path) -> list[str]:
    """numba cache files in ``folders``, but those the FMU ships (``resources/kernels/``)."""
    return sorted(str(p) for f in folders if f.exists() for p in f.rglob("*")
                  if p.suffix in (".nbi", ".nbc") and "kernels" not in p.relative_to(f).parts[:2])


@pytest.mark.parametrize("name", NAMES)
def test_first_steps_compile_nothing_in_a_fresh_read_only_folder(fmus, tmp_path, name):
    report, caches = _cold(fmus[name], tmp_path)
    assert report["compiled"] == [], report["stderr"][-2000:]
    assert "compiling" not in report["stderr"] and not any("compiling" in m for m in report["messages"])
    assert _written(caches, tmp_path / "extracted") == []          # nothing compiled, nothing saved
    if name == "RRRDirectKinematics":                               # it ran its own solver
        assert report["solver"].startswith(str(tmp_path / "extracted"))


def test_the_dk_fmus_python_path_compiles_nothing_either(fmus, tmp_path):
    """Without the loader's fast lane every doStep is the slave's Python step (what the lane hands back
    when a step is not routine: unreachable, singular, refused), which calls the tracker's entry point
    through :func:`solver._kernels.entry_call.call_entry`: the FMU ships that too."""
    report, caches = _cold(fmus["RRRDirectKinematics"], tmp_path, {"RRR_DK_FAST_LANE": "0"})
    assert report["error"] is None and len(report["outputs"]) == 10, report["stderr"][-2000:]
    assert report["compiled"] == [], report["compiled"]
    assert _written(caches, tmp_path / "extracted") == []


def test_another_cpu_and_an_unwritable_cache_still_load_the_shipped_kernels(fmus, tmp_path):
    """A process whose CPU is not this one's (another name in numba's key) and whose cache root
    cannot be created (under a file) still loads every kernel from the FMU."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    env = {"NUMBA_CPU_NAME": "x86-64", "NUMBA_CACHE_DIR": str(blocker / "numba"),
           "RRR_DK_CACHE": str(blocker / "rrr-dk")}
    report, _ = _cold(fmus["RRRDirectKinematics"], tmp_path, env)
    assert report["compiled"] == [], report["stderr"][-2000:]
    assert _written(tmp_path / "extracted") == []


def test_kernels_the_fmu_cannot_serve_are_announced_in_the_hosts_log(fmus, tmp_path):
    """Shipped kernels for another numba: the instance says so at instantiation, through the host's logger,
    and has them made in a child process (here it loads them: the numba is in fact the same)."""
    with zipfile.ZipFile(fmus["RRRPlant"]) as z:
        manifest = json.loads(z.read("resources/kernels/manifest.json"))
    report, _ = _cold(fmus["RRRPlant"], tmp_path, manifest=json.dumps({**manifest, "numba": "0.1.0"}))
    said = [m for m in report["messages"] if "compiling" in m]
    assert len(said) == 1 and "numba 0.1.0" in said[0] and "about" in said[0] and " s, " in said[0], report["messages"]
    assert "in a child process" in said[0] and "compiling" in report["stderr"]     # and on the Python logger
    assert report["compiled"] == [] and report["error"] is None and len(report["outputs"]) == 10


def _without_kernels(fmu: Path, out: Path, drop=(".nbi", ".nbc")) -> Path:
    """``fmu`` with the entries whose names end in ``drop`` left out (an empty kernel folder)."""
    with zipfile.ZipFile(fmu) as z, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as o:
        for info in z.infolist():
            if not info.filename.endswith(drop):
                o.writestr(info, z.read(info))
    return out


def test_a_forced_compile_runs_in_a_child_process_not_on_a_small_host_stack(fmus, tmp_path):
    """An empty kernel folder, a host thread with a 512 kB stack (numba's compiler overflows such stacks:
    the 3-RPR FMU crashed fmpy): the FMU compiles in a child process, the host compiles nothing, and the
    outputs are those of the shipped kernels; a second host finds them compiled (no child)."""
    stripped = _without_kernels(fmus["RRRPlant"], tmp_path / "RRRPlant.fmu")
    (tmp_path / "first").mkdir()
    report, caches = _cold(stripped, tmp_path / "first", {"COLD_STACK": str(512 * 1024)})
    assert report["error"] is None, report["stderr"][-3000:]
    assert report["compiled"] == [], report["compiled"]                # nothing on the host's thread
    said = " | ".join(report["messages"])
    assert "its kernel folder holds no compiled kernel: compiling them in a child process" in said, said
    assert "compiling dynamics._kernels" in said and "kernels compiled in a child process in" in said, said
    (tmp_path / "shipped").mkdir()
    shipped, _ = _cold(fmus["RRRPlant"], tmp_path / "shipped", {"COLD_STACK": str(512 * 1024)})
    assert report["outputs"] == shipped["outputs"] and len(shipped["outputs"]) == 10
    assert list(caches.rglob("warm.json")), "the child recorded no machine"
    (tmp_path / "first" / "extracted").chmod(0o755)
    import shutil

    shutil.rmtree(tmp_path / "first" / "extracted", ignore_errors=True)
    again, _ = _cold(stripped, tmp_path / "first", {"COLD_STACK": str(512 * 1024)})
    assert again["error"] is None and again["compiled"] == [] and again["outputs"] == shipped["outputs"]
    assert not any("child process" in m for m in again["messages"]), again["messages"]


def test_a_host_without_numba_imported_still_compiles_in_a_child(fmus, tmp_path):
    """The plant and the controller import their kernels in setup(), after the instantiation decides; a host
    that has not imported numba (fmpy alone) must still get the child, and each FMU its own (they share a
    kernel key, not their kernels): nothing compiled in the host, the plant then the controller in the
    plant's caches."""
    caches = None
    for n in ("RRRPlant", "ComputedTorqueController"):
        stripped = _without_kernels(fmus[n], tmp_path / f"{n}.fmu")
        work = tmp_path / n
        work.mkdir()
        env = {"COLD_LATE_LISTENER": "1"}
        if caches is not None:                      # the controller after the plant, in the plant's caches
            env.update(NUMBA_CACHE_DIR=str(caches / "numba"), RRR_DK_CACHE=str(caches / "rrr-dk"))
        report, made = _cold(stripped, work, env)
        caches = caches or made
        assert report["error"] is None, report["stderr"][-3000:]
        assert report["compiled"] == [], (n, report["compiled"])
        assert any("in a child process" in m for m in report["messages"]), (n, report["messages"])


#: argv: FMUs.  Runs each in turn as ``fmpy.simulate_fmu`` does (extract, instantiate, steps, free,
#: delete the extraction) in one process; prints each instance's fast-lane steps and numba's compiles.
SEQUENCE = LISTEN + textwrap.dedent(r"""
    import gc, json, shutil, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    listen()
    steps = []
    for path in sys.argv[1:]:
        md = read_model_description(path)
        folder = extract(path)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="x")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        for k in range(5):
            fmu.doStep(k * 1e-3, 1e-3)
        slave, = [o for o in gc.get_objects() if type(o).__name__ == md.modelName]
        steps.append([md.modelName, None if slave._lane is None else int(slave._lane.struct.fast_steps)])
        fmu.terminate()
        fmu.freeInstance()
        del slave
        shutil.rmtree(folder)
    print("SEQ " + json.dumps({"steps": steps, "compiled": compiled}))
""")


def test_fmus_run_one_after_another_from_deleted_extractions_keep_their_lanes(fmus, tmp_path):
    """Python keeps the packages of the first FMU that brought them, and fmpy's ``simulate_fmu`` deletes
    each extraction after its run.  The DK FMU after the plant runs the plant's ``solver`` (which
    ships none of the DK's kernels: it compiled them on the host's thread, 86 s), and the controller
    after the plant makes its fast lane from a deleted file (it had none): each kernel is found in the
    shipped kernels of a live FMU of the same code, nothing is compiled, every instance has its lane."""
    order = ("RRRPlant", "ComputedTorqueController", "RRRDirectKinematics", "RRRPlant")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), RRR_DK_CACHE=str(tmp_path / "rrr-dk"))
    proc = subprocess.run([sys.executable, "-c", SEQUENCE, *(str(fmus[n]) for n in order)], capture_output=True,
                          text=True, env=env, cwd=str(tmp_path), timeout=600)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("SEQ ")), None)
    assert line is not None, f"the child failed ({proc.returncode}):\n{proc.stderr[-4000:]}"
    report = json.loads(line[4:])
    assert "no fast lane" not in proc.stderr, proc.stderr[-3000:]
    assert [name for name, _ in report["steps"]] == list(order)
    assert all(steps and steps > 0 for _, steps in report["steps"]), report["steps"]
    assert report["compiled"] == [], report["compiled"]


def test_a_failed_child_compile_fails_the_instantiation_with_the_reason(fmus, tmp_path):
    """No kernels and no warm-up runs to compile them with: instantiation fails, the reason is on the host's
    logger, and the host goes on (the child script exits normally)."""
    stripped = _without_kernels(fmus["RRRPlant"], tmp_path / "RRRPlant.fmu", (".nbi", ".nbc", "kernel_runs.json"))
    report, _ = _cold(stripped, tmp_path)
    assert report["error"] == "Failed to instantiate model" and report["compiled"] == []
    assert any("carries no warm-up runs (resources/kernel_runs.json)" in m for m in report["messages"]), \
        report["messages"]


def test_what_the_fmu_carries(fmus):
    """The kernels of its own code (its key), for the generic CPU, with their compile seconds; and the
    size (with kernels: the DK FMU 9.9 MB with the budget's resumable proofs, the others about 1 MB;
    without, 0.43-0.54 MB): a bound that catches kernels shipped twice or for every CPU."""
    for name in NAMES:
        with zipfile.ZipFile(fmus[name]) as z:
            names = z.namelist()
            manifest = json.loads(z.read("resources/kernels/manifest.json"))
        assert manifest["cpu"] == kernel_cache.GENERIC_CPU and manifest["key"] == fmu_key(fmus[name])
        assert manifest["python"] == "%d.%d" % sys.version_info[:2] and manifest["total_seconds"] > 0
        assert any(n.endswith(".nbi") for n in names) and any(n.endswith(".nbc") for n in names)
        assert fmus[name].stat().st_size < (12 if name == "RRRDirectKinematics" else 3) * 2**20


# ---------------------------------------------------------------------- the runtime's lookup, on a tiny bundle
KERNEL = "from numba import njit\n\n@njit(cache=True)\ndef thrice(x):\n    return 3.0 * x\n"

#: argv: resources folder; calls the bundle's kernel, prints the compiled kernels and the announcements
TINY = LISTEN + textwrap.dedent(r"""
    import json, logging, sys
    from fmu_src import kernel_cache, kernel_locator
    kernel_locator.install()
    listen()
    class Slave:                                   # what kernel_cache.attach needs of a pythonfmu slave
        def __init__(self, resources):
            self.resources, self.said = resources, []
        def log(self, msg, *args):
            self.said.append(msg)
    slave = Slave(sys.argv[1])
    kernel_cache.attach(slave)
    sys.path.insert(0, sys.argv[1])
    from pkg.kern import thrice
    assert thrice(2.0) == 6.0
    print("TINY " + json.dumps({"compiled": compiled, "said": slave.said}))
""")


def _tiny(resources: Path, tmp: Path, **env_extra) -> dict:
    tmp.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "numba"), RRR_DK_CACHE=str(tmp / "rrr-dk"), **env_extra)
    env["PYTHONPATH"] = str(Path(kernel_cache.__file__).resolve().parents[1])
    proc = subprocess.run([sys.executable, "-c", TINY, str(resources)], capture_output=True, text=True, env=env,
                          cwd=str(tmp), timeout=300)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("TINY ")), None)
    assert line is not None, proc.stderr[-3000:]
    return json.loads(line[5:])


def test_a_generic_kernel_shipped_in_resources_is_loaded_and_a_missing_one_announced(tmp_path):
    res = tmp_path / "resources"
    (res / "pkg").mkdir(parents=True)
    (res / "slavemodule.txt").write_text("Model")
    (res / "pkg" / "__init__.py").write_text("")
    (res / "pkg" / "kern.py").write_text(KERNEL)
    # the build: a generic compile, in its own process (RRR_DK_KERNELS_IN_PROCESS)
    first = _tiny(res, tmp_path / "build", NUMBA_CPU_NAME="generic", RRR_DK_KERNELS_IN_PROCESS="1")
    assert first["compiled"] == ["thrice"]
    # announced when the kernel is compiled
    assert len(first["said"]) == 1 and "no compiled kernels" in first["said"][0], first["said"]
    assert "compiling pkg.kern.thrice" in first["said"][0]
    key = kernel_cache.bundle_key(str(res))
    shipped = res / kernel_cache.SHIPPED / "pkg"
    shipped.mkdir(parents=True)
    for f in (tmp_path / "build" / "numba" / key / "pkg").iterdir():
        f.rename(shipped / f.name)
    info = {"numba": __import__("numba").__version__, "python": "%d.%d" % sys.version_info[:2],
            "machine": __import__("platform").machine().lower(), "cpu": "generic", "key": key,
            "seconds": {"pkg.kern.thrice": 7.0}, "total_seconds": 7.0}
    (res / kernel_cache.SHIPPED / kernel_cache.MANIFEST).write_text(json.dumps(info))
    loaded = _tiny(res, tmp_path / "host")                                      # this CPU, empty caches
    assert loaded == {"compiled": [], "said": []}
    (res / "pkg" / "kern.py").write_text(KERNEL.replace("3.0 * x", "3.0 * x + 0.0"))   # other code, other key
    again = _tiny(res, tmp_path / "changed", RRR_DK_KERNELS_IN_PROCESS="1")
    assert again["compiled"] == ["thrice"]
    assert any("compiling pkg.kern.thrice" in m and "about 7 s" in m for m in again["said"]), again["said"]
