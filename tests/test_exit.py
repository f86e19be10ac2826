"""pythonfmu 0.7's exit crash, its cause and its fix: plain fmpy scripts and ``fmpy simulate`` runs
of the FMUs exit with status 0 (issue 18); :func:`cosim.unit.exit_process` still ends the project's
own processes without the finalizers.

The cause (found with valgrind on the C host of ``tests/test_c_host.py``, where it aborted every
run): pythonfmu's wrapper keeps a static ``std::shared_ptr<PyState>`` and also resets it in an
``__attribute__((destructor))`` function.  When the wrapper library is still loaded at process exit,
``exit()`` runs the static's destructor first (``__cxa_atexit``) and ``_dl_fini`` then runs the
destructor function, which resets the destroyed shared_ptr and decrements the use count inside its
freed 128-byte control block (8 bytes in: the ``bk`` pointer of a free chunk).  glibc aborts at the
next free that walks that list, typically libgfortran's ``close_units`` ("corrupted double-linked
list", "corrupted unsorted chunks"); valgrind: "Invalid read of size 4 at finalizePythonInterpreter
... 8 bytes inside a block of size 128 free'd ... by __run_exit_handlers".  How often it aborted
depended on the heap state (3/100 runs of the script below with all three FMUs, 37/100 with the
plant alone).  The fix is in the FMU's loader (``fmu_src/loader/loader_common.c``; ``fmi2_loader.c`` explains it): it
registers an atexit handler after the wrapper's statics that resets the shared_ptr first.

:data:`SCRIPT` imports fmpy only.  It runs each of the three FMUs through ``fmpy.simulate_fmu``
(extract, instantiate, simulate, free, unload) twice, then through ``FMU2Slave``: instantiate,
three rounds of initialization, steps and ``fmi2Reset``, ``fmi2FreeInstance``, a second instance
from the same library, ``fmi2FreeInstance`` (the library stays loaded, as the project's driver
keeps it), and ends with a normal interpreter exit.  Some runs abort after the script's last
statement: SIGABRT, "corrupted double-linked list", raised in the C runtime's exit-time
finalizers (a core dump shows libgfortran's ``close_units``) on a heap corrupted earlier; with the
loader every run exits 0.

How often it aborts depends on the heap, so waiting for the abort needs many runs.  The tests run
each process under ``tests/c_host/quarantine_free.c`` instead (``LD_PRELOAD``): freed blocks of
that size are filled with a pattern and kept, and the process ends with status 86 and the block's
changed byte when one was written after its free().  A run with the loader's fix left out fails that
way every time (:func:`test_the_detector_catches_the_crash_every_time_without_the_loaders_fix`), so
one run per case suffices; each case also runs once as a user runs it, without the detector.

Measure the abort rate without the detector (``--import-first``: the script imports ``solver`` and
``dynamics`` first, as the project's processes do, so the FMUs use those copies)::

    python tests/test_exit.py --runs 100 [--fmu-dir build] [--import-first]
"""
from __future__ import annotations

import collections
import os
import signal
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import CC, REPO, run_python, session_fmus  # noqa: E402

SCRIPT = """
    import sys
    from fmpy import extract, read_model_description, simulate_fmu
    from fmpy.fmi2 import FMU2Slave

    fmus = sys.argv[1:]
    for _ in range(2):
        for path in fmus:
            simulate_fmu(path, stop_time=0.01, step_size=1e-3, output_interval=1e-3)
    for path in fmus:
        md = read_model_description(path)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), instanceName="x",
                        modelIdentifier=md.coSimulation.modelIdentifier)
        for instance in range(2):
            fmu.instantiate()
            for round in range(4 if instance == 0 else 1):
                fmu.setupExperiment(startTime=0.0)
                fmu.enterInitializationMode()
                fmu.exitInitializationMode()
                for k in range(5):
                    fmu.doStep(k * 1e-3, 1e-3)
                if instance == 0 and round < 3:
                    fmu.reset()
            fmu.terminate()
            fmu.fmi2FreeInstance(fmu.component)
    print("script end", flush=True)
"""
ABORT = -signal.SIGABRT
#: the exit status of a process in which the detector found a block written after its free()
DETECTED = 86
DETECTOR_SOURCE = Path(__file__).resolve().parent / "c_host" / "quarantine_free.c"
NAMES = ("RRRDirectKinematics", "RRRPlant", "ComputedTorqueController")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (cc or gcc) on PATH: the use-after-free "
                                                 "detector (tests/c_host/quarantine_free.c) cannot be built")


def compile_detector(folder: Path) -> Path:
    """``tests/c_host/quarantine_free.c`` compiled into ``folder`` (a library for ``LD_PRELOAD``)."""
    lib = folder / "quarantine_free.so"
    proc = subprocess.run([CC, "-std=c11", "-O1", "-Wall", "-Werror", "-fPIC", "-shared", "-o", str(lib),
                           str(DETECTOR_SOURCE), "-lpthread"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return lib


def detector_env(lib: Path | None) -> dict | None:
    """The environment of a child run under the detector ``lib`` (None: this process's)."""
    return None if lib is None else dict(os.environ, LD_PRELOAD=str(lib))


def run_script(paths, detector: Path | None = None, import_first: bool = False) -> subprocess.CompletedProcess:
    """One run of :data:`SCRIPT` on ``paths`` (under ``detector``, if given); asserts it did all its work."""
    code = ("import solver, dynamics  # noqa: F401\n" if import_first else "") + textwrap.dedent(SCRIPT)
    proc = subprocess.run([sys.executable, "-c", code, *map(str, paths)], capture_output=True, text=True,
                          timeout=900, cwd=str(REPO), env=detector_env(detector))
    assert "script end" in proc.stdout, proc.stderr[-3000:]
    _checked(proc, detector)
    return proc


def _checked(proc: subprocess.CompletedProcess, detector: Path | None) -> None:
    """A run under the detector that exited 0 did check at exit (its line on stderr): not a check that
    never ran (a program's fflush(NULL) would run it early)."""
    if detector is not None and proc.returncode == 0:
        assert "freed blocks intact (at exit)" in proc.stderr, proc.stderr[-2000:]


def reproduce(paths, runs: int, import_first: bool = False) -> collections.Counter:
    """Exit statuses of ``runs`` plain runs of :data:`SCRIPT` on ``paths``."""
    statuses = collections.Counter()
    for _ in range(runs):
        proc = run_script(paths, import_first=import_first)
        if proc.returncode == ABORT:
            assert "corrupted" in proc.stderr or "free()" in proc.stderr, proc.stderr[-2000:]
        statuses[proc.returncode] += 1
    return statuses


def fmpy_simulate(fmu: Path, workdir: Path, detector: Path | None = None) -> subprocess.CompletedProcess:
    """One plain ``fmpy simulate <fmu>`` command line (under ``detector``, if given)."""
    fmpy_cli = Path(sys.executable).with_name("fmpy")
    cmd = [str(fmpy_cli)] if fmpy_cli.exists() else [sys.executable, "-m", "fmpy"]
    out = workdir / f"{fmu.stem}-{'detector' if detector else 'plain'}.csv"
    proc = subprocess.run([*cmd, "simulate", str(fmu), "--stop-time", "0.05", "--output-file", str(out)],
                          capture_output=True, text=True, timeout=900, cwd=str(workdir), env=detector_env(detector))
    assert proc.returncode != 0 or out.is_file(), proc.stderr[-2000:]
    _checked(proc, detector)
    return proc


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.fixture(scope="module")
def detector(tmp_path_factory):
    """The detector library, or None without a C compiler (the plain runs still run)."""
    return None if CC is None else compile_detector(tmp_path_factory.mktemp("detector"))


def _without_the_fix(fmu: Path, out: Path) -> Path:
    """``fmu`` with its loader compiled from sources that leave out the atexit fix (loader_common.c)."""
    from cosim.fmus import native

    sources = out.parent / "unfixed-loader"
    sources.mkdir(exist_ok=True)
    files = []
    for source in native.LOADER_FILES:
        text = source.read_text()
        if source.name == "loader_common.c":
            fixed = "if (release_py_state) atexit(release_wrapper_state);"
            assert fixed in text, "the loader's fix moved: update this test"
            text = text.replace(fixed, "(void)release_wrapper_state;")
        (sources / source.name).write_text(text)
        files.append(sources / source.name)
    loader = native.compile_loader(files=tuple(files))
    binary = f"binaries/{native.PLATFORMS[0]}/{fmu.stem}.so"
    with zipfile.ZipFile(fmu) as z, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as o:
        assert binary in z.namelist()
        for info in z.infolist():
            o.writestr(info, loader if info.filename == binary else z.read(info))
    return out


@needs_cc
def test_the_detector_catches_the_crash_every_time_without_the_loaders_fix(fmus, detector, tmp_path):
    """Without the loader's atexit handler every run under the detector ends with its status and the
    block's byte 8 (the use count of the freed control block) one less: the one-run tests below can fail."""
    unfixed = _without_the_fix(fmus["RRRPlant"], tmp_path / "RRRPlant.fmu")
    for proc in (run_script([unfixed], detector), fmpy_simulate(unfixed, tmp_path, detector)):
        assert proc.returncode == DETECTED, (proc.returncode, proc.stderr[-2000:])
        assert "was written after free() (byte 8 is 0x10, not 0x11)" in proc.stderr, proc.stderr[-2000:]


@pytest.mark.parametrize("which", ["all three", "RRRPlant"])
def test_a_plain_fmpy_script_exits_cleanly(fmus, detector, which, record_property):
    """The reproducer writes no freed block (the detector, with a C compiler) and exits 0 as a user runs it
    (before the loader's fix the plant alone aborted in 37 of 100 runs, all three in 3 of 100)."""
    paths = list(fmus.values()) if which == "all three" else [fmus[which]]
    runs = (("detector", detector), ("plain", None)) if detector else (("plain", None),)
    statuses = {kind: run_script(paths, lib).returncode for kind, lib in runs}
    record_property("exit_statuses", statuses)
    assert statuses == {kind: 0 for kind, _ in runs}, statuses


@pytest.mark.parametrize("name", NAMES)
def test_plain_fmpy_simulate_exits_cleanly(fmus, detector, name, tmp_path):
    """``fmpy simulate <FMU>`` (fmpy's command line) writes no freed block (with a C compiler) and exits 0."""
    for lib in (detector, None) if detector else (None,):
        proc = fmpy_simulate(Path(fmus[name]), tmp_path, lib)
        assert proc.returncode == 0, (lib, proc.returncode, proc.stderr[-2000:])


EXIT = """
    import atexit, sys
    import solver, dynamics  # noqa: F401
    from cosim.unit import FMUUnit, exit_process

    atexit.register(lambda: print("atexit ran", flush=True))
    if len(sys.argv) > 1:
        with FMUUnit(sys.argv[1], "plant") as unit:
            unit.initialize(0.0)
            unit.fmu.doStep(0.0, 1e-3)
    print("work done", flush=True)
    exit_process(5)
"""


def test_exit_process_skips_the_finalizers_only_after_fmus(fmus):
    """With FMUs loaded, exit_process ends the process at once (no atexit, no library finalizers)
    with the given status; without, the process exits normally with it."""
    loaded = run_python(EXIT, fmus["RRRPlant"])
    assert (loaded.returncode, loaded.stdout.split()) == (5, ["work", "done"]), loaded.stderr[-2000:]
    plain = run_python(EXIT)
    assert (plain.returncode, plain.stdout.split()) == (5, ["work", "done", "atexit", "ran"]), plain.stderr[-2000:]


def main(argv=None) -> int:
    """``python tests/test_exit.py --runs N [--fmu-dir build] [--import-first]``: print the exit statuses."""
    import argparse

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--fmu-dir", default=str(Path(__file__).resolve().parent.parent / "build"))
    ap.add_argument("--import-first", action="store_true")
    ap.add_argument("--only", nargs="+", default=None, metavar="NAME", help="these FMUs (default: all three)")
    args = ap.parse_args(argv)
    paths = [Path(args.fmu_dir) / f"{n}.fmu" for n in (args.only or NAMES)]
    statuses = reproduce(paths, args.runs, args.import_first)
    print(f"{args.runs} runs ({', '.join(p.name for p in paths)}; import first: {args.import_first}): "
          + ", ".join(f"exit status {s}: {n}" for s, n in sorted(statuses.items())) + f" ({ABORT} = SIGABRT)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
