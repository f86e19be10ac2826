"""The FMI 3.0 DK FMU in a C host with no Python in its process, through a whole life, against fmpy.

``tests/c_host/fmi3_host.c`` (compiled here with the system compiler, libc and libdl only) dlopens
``binaries/x86_64-linux/RRRDirectKinematics3.so`` of the extracted FMU, nothing preloaded and no
Python variable in its environment.  That binary is the project's FMI 3.0 loader
(``fmu_src/loader/fmi3_loader.c``): it starts the interpreter recorded at build time and forwards to
pythonfmu3's wrapper.  The host instantiates, enters and exits initialization, steps on a moving
input, takes the FMU state halfway, sets it back and runs the second half again, resets, runs again,
frees the instance, instantiates again and runs again (the host's docstring).  The same call
sequence runs in fmpy's ``FMU3Slave`` in a child process (a host with Python in-process: the loader
starts no second interpreter); every printed value must be the same bit for bit, the re-run halves
the same as the first, and the C host must exit 0 (pythonfmu3's wrapper has pythonfmu's exit crash;
the loader's atexit fix, loader_common.c).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_support import CC, no_python_env, run_python  # noqa: E402

STEPS = 40
DQ = 1e-3
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (cc or gcc) on PATH: the C host cannot be built")

#: fmpy's run of the C host's call sequence; same arguments, same output
FMPY_HOST = """
    import sys
    from fmpy.fmi3 import FMU3Slave

    folder, model, token, q_vr, pose_vr, steps, dq = sys.argv[1:]
    q_vr, pose_vr, steps, dq, h = int(q_vr), int(pose_vr), int(steps), float(dq), 1e-3
    half = steps // 2

    def initialize(fmu):
        fmu.enterInitializationMode(startTime=0.0)
        fmu.exitInitializationMode()
        return list(fmu.getFloat64([q_vr], nValues=3))

    def run(fmu, tag, q, start, stop, save=-1):
        saved = None
        for k in range(start, stop):
            if k == save:
                saved = fmu.getFMUState(), list(q)
            q[1] += dq
            fmu.setFloat64([q_vr], q)
            fmu.doStep(k * h, h)
            print(tag, k, *("%.17g" % v for v in [(k + 1) * h, *fmu.getFloat64([pose_vr], nValues=3)]))
        return saved

    fmu = FMU3Slave(guid=token, unzipDirectory=folder, modelIdentifier=model, instanceName="fmpy-host")
    fmu.instantiate(loggingOn=True)
    q = initialize(fmu)
    state, saved_q = run(fmu, "a", q, 0, steps, half)
    fmu.setFMUState(state)
    run(fmu, "b", list(saved_q), half, steps)
    fmu.freeFMUState(state)
    fmu.reset()
    run(fmu, "c", initialize(fmu), 0, steps)
    fmu.terminate()
    fmu.freeInstance()
    fmu = FMU3Slave(guid=token, unzipDirectory=folder, modelIdentifier=model, instanceName="fmpy-host-2")
    fmu.instantiate(loggingOn=True)
    run(fmu, "d", initialize(fmu), 0, steps)
    fmu.terminate()
    fmu.freeInstance()
    print("end", flush=True)
"""


@pytest.fixture(scope="module")
def dk3(tmp_path_factory):
    from fmpy import extract, read_model_description

    from cosim.fmus import fmi3_build, references

    tmp = tmp_path_factory.mktemp("c_host3")
    built = fmi3_build.build_dk3(tmp / "fmu3", postures=(1,), resolution=references.REFERENCE["resolution"],
                                 cache_dir=tmp / "maps", log=lambda m: None, check=False)
    md = read_model_description(str(built.fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(str(built.fmu), unzipdir=str(tmp / "unzipped"))
    return folder, md.guid, vr


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c_host3_exe") / "fmi3_host"
    source = Path(__file__).resolve().parent / "c_host" / "fmi3_host.c"
    proc = subprocess.run([CC, "-std=c11", "-O1", "-Wall", "-o", str(exe), str(source), "-ldl"], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    assert b"libpython" not in exe.read_bytes(), "the C host must not link libpython"
    return exe


def _rows(stdout: str) -> dict:
    """{tag: [[k, t, x, y, phi], ...]} of the host's rows "a|b|c|d k t x y phi"."""
    rows: dict = {}
    for line in stdout.splitlines():
        parts = line.split()
        if parts and parts[0] in ("a", "b", "c", "d"):
            rows.setdefault(parts[0], []).append([int(parts[1]), *map(float, parts[2:])])
    return rows


def test_c_host_without_python_lives_as_fmpy_does(dk3, host, tmp_path):
    folder, guid, vr = dk3
    args = [folder, "RRRDirectKinematics3", guid, str(vr["q"]), str(vr["pose"]), str(STEPS), repr(DQ)]
    py = run_python(FMPY_HOST, *args, timeout=600)
    assert py.returncode == 0 and py.stdout.rstrip().endswith("end"), py.stderr[-3000:]
    c = subprocess.run([str(host), *args], capture_output=True, text=True, timeout=600, env=no_python_env(),
                       cwd=str(tmp_path))
    assert c.returncode == 0 and c.stdout.rstrip().endswith("end"), \
        f"status {c.returncode}\n{c.stdout[-1500:]}\n{c.stderr[-3000:]}"
    assert "python_before 0" in c.stdout, "the C host had Python before the FMU was loaded"
    assert "python_after 1" in c.stdout, "the FMU's loader did not bring in Python"
    ours, theirs = _rows(c.stdout), _rows(py.stdout)
    assert ours == theirs                                       # every value, bit for bit (%.17g round-trips)
    half = STEPS // 2
    assert [len(ours[t]) for t in "abcd"] == [STEPS, STEPS - half, STEPS, STEPS]
    assert ours["b"] == ours["a"][half:]                        # rolled back and re-run: the same outputs
    assert ours["c"] == ours["a"] and ours["d"] == ours["a"]    # after fmi3Reset, in a new instance
    assert not [line for line in c.stderr.splitlines() if line.startswith(("[2 ", "[3 ", "[4 "))], c.stderr[-2000:]
    print(f"C host (no Python) vs fmpy: {sum(map(len, ours.values()))} poses identical; exit 0")


def test_c_host_without_any_python_fails_cleanly(dk3, host, tmp_path):
    """Nothing fits (recorded interpreter gone, nothing on PATH): fmi3InstantiateCoSimulation returns
    NULL after logging every candidate and the fix; the host exits by itself (status 1), no crash."""
    folder, guid, vr = dk3
    record = Path(folder) / "resources" / "python_runtime.txt"
    original = record.read_text()
    gone = tmp_path / "moved-venv" / "bin" / "python"
    try:
        record.write_text("".join(f"python={gone}\n" if line.startswith("python=") else line + "\n"
                                  for line in original.splitlines()))
        empty = tmp_path / "empty-bin"
        empty.mkdir()
        run = subprocess.run([str(host), folder, "RRRDirectKinematics3", guid, str(vr["q"]), str(vr["pose"]), "2",
                              repr(DQ)], capture_output=True, text=True, timeout=600, env=no_python_env(PATH=str(empty)))
    finally:
        record.write_text(original)
    assert run.returncode == 1 and "instantiate failed" in run.stdout, (run.returncode, run.stderr[-2000:])
    for part in ("no Python interpreter fits the FMU RRRDirectKinematics3", "$RRR_DK_PYTHON: not set",
                 f"{gone}: missing", "python3 on PATH: none found", "Fix: set $RRR_DK_PYTHON"):
        assert part in run.stderr, (part, run.stderr[-2000:])


def test_the_build_puts_the_loader_in_front_of_pythonfmu3s_wrapper(monkeypatch):
    """native.loader_entries(..., fmi=3): the loader as the binary (the same bytes every time), pythonfmu3's
    wrapper beside it, the runtime record, x86_64-linux only; without a C compiler the entries keep
    pythonfmu3's binary with a NativeBuildWarning."""
    from cosim.fmus import native

    model = "RRRDirectKinematics3"
    entries = {f"binaries/x86_64-linux/{model}.so": b"wrapper", f"binaries/x86_64-windows/{model}.dll": b"win",
               "resources/a.txt": b"a"}
    out = native.loader_entries(entries, model, fmi=3)
    assert sorted(out) == sorted([f"binaries/x86_64-linux/{model}.so", "binaries/x86_64-linux/libpythonfmu3-export.so",
                                  "resources/a.txt", "resources/python_runtime.txt"])
    assert out["binaries/x86_64-linux/libpythonfmu3-export.so"] == b"wrapper"
    assert out[f"binaries/x86_64-linux/{model}.so"][:4] == b"\x7fELF"
    assert out == native.loader_entries(entries, model, fmi=3)          # deterministic
    assert f"python={sys.executable}" in out["resources/python_runtime.txt"].decode()
    monkeypatch.setattr(native, "compiler", lambda: None)
    with pytest.warns(native.NativeBuildWarning, match="no C compiler.*keeps pythonfmu3's binary"):
        bare = native.loader_entries(entries, model, fmi=3)
    assert bare == {k: v for k, v in entries.items() if "windows" not in k}
