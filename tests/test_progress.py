"""Progress of long work (solver.progress): phase lines with their times, bars readable in logs, silence."""
import io
import subprocess
import sys
import time

import pytest

from solver import progress


@pytest.fixture(autouse=True)
def default_on(monkeypatch):
    monkeypatch.delenv(progress.PROGRESS_ENV, raising=False)
    progress.set_enabled(None)
    yield
    progress.set_enabled(None)


def test_a_phase_says_when_it_starts_and_how_long_it_took(capsys):
    with progress.phase("compiling kernels", "about 1 s") as ph:
        time.sleep(0.05)
        ph.summary = "3 kernels"
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "compiling kernels ... (about 1 s)"
    assert err[1].startswith("compiling kernels: done in ") and err[1].endswith(" s (3 kernels)")
    assert ph.seconds >= 0.05


def test_a_failing_phase_says_so_and_raises(capsys):
    with pytest.raises(KeyError):
        with progress.phase("loading") as ph:
            raise KeyError("x")
    assert "loading: failed after" in capsys.readouterr().err and ph.seconds is not None


def test_a_bar_in_a_log_writes_whole_lines(capsys):
    for _ in progress.bar(range(5), desc="slices", delay=0, mininterval=0):
        pass
    err = capsys.readouterr().err
    assert "\r" not in err and "slices" in err and "5/5" in err.splitlines()[-1]


def test_a_bar_on_a_terminal_redraws_in_place(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True
    stream = Tty()
    monkeypatch.setattr("sys.stderr", stream)
    for _ in progress.bar(range(5), desc="slices", delay=0, mininterval=0):
        pass
    assert "\r" in stream.getvalue() and "5/5" in stream.getvalue()


def test_short_loops_print_nothing(capsys):
    for _ in progress.bar(range(100), desc="quick"):
        pass
    assert capsys.readouterr().err == ""


def test_progress_can_be_silenced(capsys, monkeypatch):
    with progress.silenced():
        with progress.phase("quiet"):
            list(progress.bar(range(3), delay=0, mininterval=0))
        progress.note("nothing")
    assert capsys.readouterr().err == ""
    with progress.phase("loud", enabled=True):
        pass
    assert "loud: done in" in capsys.readouterr().err
    monkeypatch.setenv(progress.PROGRESS_ENV, "0")
    progress.note("nothing")
    assert capsys.readouterr().err == "" and not progress.is_on() and progress.is_on(True)
    progress.set_enabled(True)
    assert progress.is_on()


def test_without_tqdm_a_bar_counts_silently(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "tqdm", None)                      # "import tqdm" now fails
    b = progress.bar(range(4), desc="x", delay=0, mininterval=0)
    assert list(b) == [0, 1, 2, 3] and b.n == 4
    with progress.bar(total=10) as counter:
        counter.update(3)
    assert counter.n == 3 and capsys.readouterr().err == ""


def test_importing_solver_does_not_import_tqdm():
    """An FMU bundles solver and runs on hosts without tqdm: only a bar imports it."""
    code = "import sys, solver, solver.mapcache; assert 'tqdm' not in sys.modules, 'tqdm imported'"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_a_phase_that_is_slow_only_sometimes_speaks_only_when_slow(capsys):
    with progress.phase("loading kernels", after=0.5):
        pass
    assert capsys.readouterr().err == ""
    with progress.phase("loading kernels", "compiling the first time", after=0.1) as ph:
        time.sleep(0.4)
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "loading kernels ... (compiling the first time)"
    assert err[1].startswith("loading kernels: done in ") and ph.seconds >= 0.4


def test_a_long_phase_says_it_goes_on_the_innermost_only(capsys, monkeypatch):
    """With nothing written for HEARTBEAT seconds the innermost phase that spoke says how long it has run
    (a first run's compile never looks hung); an outer phase stays quiet, and a line written
    meanwhile (a note) restarts the silence."""
    monkeypatch.setattr(progress, "HEARTBEAT", 0.2)
    with progress.phase("outer"):
        with progress.phase("inner"):
            time.sleep(0.75)
            progress.note("a line of the work")
            time.sleep(0.1)
    err = capsys.readouterr().err.splitlines()
    beats = [line for line in err if line.endswith(" s so far")]
    assert 2 <= len(beats) <= 4 and all(line.startswith("inner: ") for line in beats), err
    assert err.index("a line of the work") == len(err) - 3      # no beat after it: 0.1 s is not 0.2 s
    assert err[-1].startswith("outer: done in ")
    time.sleep(0.3)
    assert capsys.readouterr().err == ""                         # the heartbeats end with their phases
