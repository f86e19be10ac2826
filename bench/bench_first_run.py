"""A newcomer's first run: ``python -m cosim`` in a fresh clone with empty caches, phase by phase.

    python bench/bench_first_run.py [--tests] [--keep DIR]

Clones this repository's committed HEAD (``git clone``: uncommitted changes are not measured) into a
new folder and runs the README's main command there, ``python -m cosim``, with this interpreter and
caches that have never been filled: ``XDG_CACHE_HOME`` a new empty folder (the map cache and the
FMUs' kernel cache, ``~/.cache/rrr-dk``), ``RRR_DK_CACHE`` and ``NUMBA_CACHE_DIR`` unset (numba's
cache then goes beside the clone's sources, empty too).  The clone's packages come first on
``sys.path`` (``PYTHONPATH`` = the clone), so the installed copy is not what runs.

It prints every line the command writes to stderr with the seconds since it started, then:

- the time to the first result (the command's exit, ``results/closed_loop.csv`` written), and the
  issue's target (at most 90 s on 2 cores at a load of at most 1.5);
- the longest silence between two stderr lines (target: a phase line at least every 10 s);
- the same command again in the same clone (warm caches: what every later run costs);
- with ``--tests``: the README's test command (``python -m pytest -q -n 2``) in the clone with the
  caches the first run left (cold for the test suite's own builds), then again (warm), each with
  its wall time (targets: 8 and 5 minutes) and pytest's summary line (its whole output, with the 40
  slowest tests, in ``pytest-cold.txt`` and ``pytest-warm.txt`` of the work folder: ``--keep DIR``
  keeps them).

Numbers, no assertions; the machine's load average is printed (compiles take longer on a loaded
machine).  Writes the section ``first_run`` of docs/benchmarks.md and its headline rows.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report import publish, table, target

ROOT = Path(__file__).resolve().parent.parent
#: the issue's targets (s): the first result, the longest silence, the test command cold and warm
FIRST_RESULT, SILENCE, TESTS_COLD, TESTS_WARM = 90.0, 10.0, 480.0, 300.0


def clean_env(clone: Path, cache: Path) -> dict:
    """This process's environment for a machine that never ran the project: empty caches, the clone first."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH") and not k.startswith("RRR_DK_")}
    env["XDG_CACHE_HOME"] = str(cache)
    env["PYTHONPATH"] = str(clone)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def timed_run(cmd: list, cwd: Path, env: dict, echo: bool = True, stdout: Path | None = None
              ) -> tuple[float, float, int, list]:
    """Run ``cmd``; returns (wall s, longest silence between stderr lines s, exit code, [(s, line)]).
    ``stdout``: a file for the command's standard output (default: discarded)."""
    t0 = time.perf_counter()
    out = open(stdout, "w") if stdout is not None else subprocess.DEVNULL
    try:
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.PIPE, text=True)
    finally:
        if stdout is not None:
            out.close()                 # the child holds its own copy
    lines, last, silence = [], 0.0, 0.0
    for line in proc.stderr:
        t = time.perf_counter() - t0
        silence = max(silence, t - last)
        last = t
        lines.append((t, line.rstrip()))
        if echo:
            print(f"  {t:7.1f} s  {line.rstrip()}", flush=True)
    code = proc.wait()
    wall = time.perf_counter() - t0
    return wall, max(silence, wall - last), code, lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tests", action="store_true", help="also the README's test command, cold then warm")
    ap.add_argument("--keep", metavar="DIR", default=None,
                    help="work in DIR (made empty) and keep it, instead of a temporary folder")
    args = ap.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rrr-first-run-"))
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    try:
        clone, cache = work / "clone", work / "cache"
        cache.mkdir()
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True,
                              check=True).stdout.strip()
        env = clean_env(clone, cache)
        print(f"fresh clone of {head} in {clone}; caches empty ({cache}); python -m cosim:", flush=True)
        cold, silence, code, _ = timed_run([sys.executable, "-m", "cosim"], clone, env)
        if code:
            raise SystemExit(f"python -m cosim exited with {code} in the fresh clone")
        print("again (warm caches):", flush=True)
        warm, _, code, _ = timed_run([sys.executable, "-m", "cosim"], clone, env, echo=False)
        rows = [("`python -m cosim`, first run (fresh clone, empty caches): to the first result",
                 f"{cold:.0f} s", target(f"<= {FIRST_RESULT:.0f} s", cold <= FIRST_RESULT)),
                ("the same: longest silence on stderr", f"{silence:.1f} s",
                 target(f"<= {SILENCE:.0f} s", silence <= SILENCE)),
                ("`python -m cosim` again (warm caches)", f"{warm:.1f} s", "")]
        if args.tests:
            for label, limit in (("cold", TESTS_COLD), ("warm", TESTS_WARM)):
                print(f"python -m pytest -q -n 2 ({label}):", flush=True)
                log = work / f"pytest-{label}.txt"
                t, _, code, _ = timed_run([sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "no:cacheprovider",
                                           "--durations=40"], clone, env,
                                          echo=False, stdout=log)
                print(f"  {t / 60:.1f} min, exit {code}: " + log.read_text().strip().splitlines()[-1], flush=True)
                rows.append((f"the README's test command, {label} (exit {code})", f"{t / 60:.1f} min",
                             target(f"<= {limit / 60:.0f} min", t <= limit)))
        body = table(["what", "measured", "target"], rows)
        print(body)
        note = (f"A fresh `git clone` of {head}, this interpreter and its installed dependencies, caches empty "
                "(`XDG_CACHE_HOME` a new folder; `RRR_DK_CACHE`, `NUMBA_CACHE_DIR` unset): what a newcomer's "
                "first `python -m cosim` after `pip install -e .` costs, most of it numba compiling kernels.")
        publish("first_run", body, note=note, headline=[r for r in rows if r[2]])
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
