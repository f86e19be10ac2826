"""The life of an FMU instance in a host process, for all three FMUs (issue 27): several
instantiate/free cycles in one process, two instances alive at once, fmi2Reset and a second run,
all with the first run's outputs bit for bit, and the process exits with status 0.

* In the C host (``tests/c_host/fmi2_host.c`` in its ``life`` mode, no Python in the process: the
  FMU's loader starts the interpreter once and never finalizes it), which also checks that a call the
  state forbids (fmi2DoStep right after fmi2Instantiate) returns fmi2Error.
* In fmpy with a new ``FMU2Slave`` per cycle (a child process): fmpy's ``freeInstance`` also
  unloads the FMU's library, and the next cycle loads it again from the same folder.

And the FMU lists only the platform these tests run on (pythonfmu's win64 binary is dropped).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import CC, H, OUTPUTS, compile_host, host_case, no_python_env, run_python  # noqa: E402
from host_support import session_fmus  # noqa: E402

STEPS = 40
CYCLES = 3
NAMES = list(OUTPUTS)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return session_fmus(tmp_path_factory)


@pytest.mark.skipif(CC is None, reason="no C compiler (cc or gcc) on PATH: the C host cannot be built")
@pytest.mark.parametrize("name", NAMES)
def test_c_host_life(fmus, tmp_path, name):
    host = compile_host(tmp_path)
    args = host_case(name, fmus[name], tmp_path, STEPS)
    run = subprocess.run([str(host), *args[:1], name, *args[1:2], repr(H), str(STEPS), *args[2:], "life",
                          str(CYCLES)], capture_output=True, text=True, timeout=600, env=no_python_env(),
                         cwd=str(tmp_path))
    assert run.returncode == 0 and run.stdout.rstrip().endswith("end"), \
        f"status {run.returncode}\n{run.stdout[-1500:]}\n{run.stderr[-3000:]}"
    out = run.stdout
    assert "python_before 0" in out and "refused_status 3" in out, out
    assert out.count("life cycle identical") == CYCLES - 1, out
    for what in ("two_instances_a", "two_instances_b", "reset"):
        assert f"life {what} identical" in out, out
    assert "fmi2DoStep refused in state instantiated" in run.stderr, run.stderr[-2000:]


#: fmpy's life cycles: argv = folder, model, guid, h, steps, inputs file or "-", output vrs, start values, cycles
FMPY_LIFE = """
    import sys
    from fmpy.fmi2 import FMU2Slave

    folder, model, guid, h, steps, inputs, outputs, starts, cycles = sys.argv[1:]
    h, steps, cycles, out_vr = float(h), int(steps), int(cycles), [int(v) for v in outputs.split(",")]
    in_vr, rows = [], []
    if inputs != "-":
        lines = open(inputs).read().split("\\n")
        in_vr = [int(v) for v in lines[0].split()]
        rows = [[float(v) for v in line.split()] for line in lines[1:] if line.strip()]
    start = [] if starts == "-" else [(int(a), float(b)) for a, b in (s.split("=") for s in starts.split(","))]

    def new(name):
        fmu = FMU2Slave(guid=guid, unzipDirectory=folder, modelIdentifier=model, instanceName=name)
        fmu.instantiate()
        return fmu

    def initialize(fmu):
        for vr, value in start:
            fmu.setReal([vr], [value])
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        if in_vr:
            fmu.setReal(in_vr, rows[0])
        fmu.exitInitializationMode()

    def step(fmu, k):
        if in_vr:
            fmu.setReal(in_vr, rows[k])
        fmu.doStep(k * h, h)
        return fmu.getReal(out_vr)

    def run(fmu):
        initialize(fmu)
        out = [step(fmu, k) for k in range(steps)]
        fmu.terminate()
        return out

    runs = []
    for cycle in range(cycles):                  # a new FMU2Slave each time; freeInstance unloads the library
        fmu = new(f"cycle{cycle}")
        runs.append(run(fmu))
        fmu.freeInstance()
    print("cycles identical", all(r == runs[0] for r in runs))
    a, b = new("a"), new("b")
    initialize(a)
    initialize(b)
    both = [(step(a, k), step(b, k)) for k in range(steps)]
    print("two instances identical", [x for x, _ in both] == runs[0] and [y for _, y in both] == runs[0])
    a.terminate()
    a.reset()
    print("reset identical", run(a) == runs[0])
    b.terminate()
    a.freeInstance()
    b.freeInstance()
    print("end", flush=True)
"""


@pytest.mark.parametrize("name", NAMES)
def test_fmpy_life_with_a_new_fmu2slave_per_cycle(fmus, tmp_path, name):
    folder, guid, inputs, outputs, starts = host_case(name, fmus[name], tmp_path, STEPS)
    run = run_python(FMPY_LIFE, folder, name, guid, repr(H), STEPS, inputs, outputs, starts, CYCLES, timeout=600)
    assert run.returncode == 0 and run.stdout.rstrip().endswith("end"), \
        f"status {run.returncode}\n{run.stdout[-1500:]}\n{run.stderr[-3000:]}"
    for what in ("cycles", "two instances", "reset"):
        assert f"{what} identical True" in run.stdout, run.stdout


@pytest.mark.parametrize("name", NAMES)
def test_the_fmu_lists_only_the_platform_its_tests_run_on(fmus, name):
    """pythonfmu ships a win64 binary too, never run here (no Windows toolchain, no loader for it): the
    FMU keeps the binaries of this platform only, the one the tests above ran."""
    import zipfile

    from fmpy import platform, supported_platforms

    assert supported_platforms(str(fmus[name])) == [platform]
    with zipfile.ZipFile(fmus[name]) as z:
        folders = {n.split("/")[1] for n in z.namelist() if n.startswith("binaries/") and n.count("/") >= 2}
    assert folders == {platform}


#: a slave that logs in its constructor: the message waits in pythonfmu's queue until the next call
QUEUED_SLAVE = """
from fmu_src.table_slave import TableSlave, Var

class FmuQueuedLog(TableSlave):
    VARIABLES = (Var("u", "Real", "input", start=0.0, unit="m"),
                 Var("y", "Real", "output", unit="m", depends_on=()))

    def setup(self):
        self.log("a message logged in the constructor")

    def step(self, t, dt):
        self.y += self.u * dt
"""

#: instantiate and free at once, with and without loggingOn, in one process
FREE_AT_ONCE = """
    import sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(sys.argv[1])
    folder = extract(sys.argv[1])
    for logging_on in (True, False, True):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier="FmuQueuedLog", instanceName="q")
        fmu.instantiate(loggingOn=logging_on)
        fmu.fmi2FreeInstance(fmu.component)
        print("freed", logging_on, flush=True)
    print("end", flush=True)
"""


def test_free_right_after_instantiate_with_a_queued_message(tmp_path):
    """pythonfmu 0.7's wrapper crashes (SIGSEGV) freeing an instance whose constructor's message is
    still queued while its logging is on; the loader turns the wrapper's logging off before the free."""
    from cosim.fmus.packaging import build_fmu

    script = tmp_path / "FmuQueuedLog.py"
    script.write_text(QUEUED_SLAVE)
    fmu = build_fmu(script, tmp_path / "out")
    run = run_python(FREE_AT_ONCE, fmu, timeout=300)
    assert run.returncode == 0 and run.stdout.count("freed") == 3 and "end" in run.stdout, \
        f"status {run.returncode}\n{run.stdout}\n{run.stderr[-2000:]}"
