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

Measure the rate (``--import-first``: the script imports ``solver`` and ``dynamics`` first, as the
project's processes do, so the FMUs use those copies)::

    python tests/test_exit.py --runs 100 [--fmu-dir build] [--import-first]
"""
from __future__ import annotations

import collections
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import run_python, session_fmus  # noqa: E402

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
#: the reproducer's runs in the test (each about 1.5 s once numba's kernel cache holds the FMUs' kernels)
RUNS = 6
#: plain ``fmpy simulate`` runs of each FMU (about 1.2 s each, two at a time)
SIMULATE_RUNS = 20
ABORT = -signal.SIGABRT


def reproduce(paths, runs: int, import_first: bool = False) -> collections.Counter:
    """Exit statuses of ``runs`` runs of :data:`SCRIPT` on ``paths``; asserts each run did all its work."""
    code = ("import solver, dynamics  # noqa: F401\n" if import_first else "") + textwrap.dedent(SCRIPT)
    statuses = collections.Counter()
    for _ in range(runs):
        proc = run_python(code, *paths, timeout=900)
        assert "script end" in proc.stdout, proc.stderr[-3000:]
        if proc.returncode == ABORT:
            assert "corrupted" in proc.stderr or "free()" in proc.stderr, proc.stderr[-2000:]
        statuses[proc.returncode] += 1
    return statuses


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.mark.parametrize("which", ["all three", "RRRPlant"])
def test_a_plain_fmpy_script_exits_cleanly(fmus, which, record_property):
    """The reproducer exits 0 every time (before the loader's fix the plant alone aborted in 37 of
    100 runs, all three in 3 of 100)."""
    paths = list(fmus.values()) if which == "all three" else [fmus[which]]
    statuses = reproduce(paths, RUNS)
    record_property("exit_statuses", dict(statuses))
    print(f"plain fmpy script, {which}, {RUNS} runs: exit statuses {dict(statuses)} ({ABORT}: SIGABRT at exit)")
    assert statuses == {0: RUNS}, statuses


def simulate_statuses(fmu, runs: int, workdir: Path) -> collections.Counter:
    """Exit statuses of ``runs`` plain ``fmpy simulate <fmu>`` command lines (two at a time)."""
    from concurrent.futures import ThreadPoolExecutor

    fmpy_cli = Path(sys.executable).with_name("fmpy")
    cmd = [str(fmpy_cli)] if fmpy_cli.exists() else [sys.executable, "-m", "fmpy"]

    def one(k):
        out = workdir / f"{Path(fmu).stem}-{k}.csv"
        proc = subprocess.run([*cmd, "simulate", str(fmu), "--stop-time", "0.05", "--output-file", str(out)],
                              capture_output=True, text=True, timeout=900, cwd=str(workdir))
        assert proc.returncode != 0 or out.is_file(), proc.stderr[-2000:]
        return proc.returncode, proc.stderr[-1500:]

    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(one, range(runs)))
    bad = [err for status, err in results if status != 0]
    assert not bad, bad[0]
    return collections.Counter(status for status, _ in results)


@pytest.mark.parametrize("name", ["RRRDirectKinematics", "RRRPlant", "ComputedTorqueController"])
def test_plain_fmpy_simulate_exits_cleanly(fmus, name, tmp_path):
    """``fmpy simulate <FMU>`` (fmpy's command line) 20 times per FMU: exit status 0 every time."""
    statuses = simulate_statuses(fmus[name], SIMULATE_RUNS, tmp_path)
    print(f"fmpy simulate {name}: {SIMULATE_RUNS} runs, exit statuses {dict(statuses)}")
    assert statuses == {0: SIMULATE_RUNS}


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
    from cosim.fmus.builds import FMU_NAMES

    paths = [Path(args.fmu_dir) / f"{n}.fmu" for n in (args.only or FMU_NAMES)]
    statuses = reproduce(paths, args.runs, args.import_first)
    print(f"{args.runs} runs ({', '.join(p.name for p in paths)}; import first: {args.import_first}): "
          + ", ".join(f"exit status {s}: {n}" for s, n in sorted(statuses.items())) + f" ({ABORT} = SIGABRT)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
