"""The closed loop's three FMUs, built together and kept current (host side): :func:`build_fmus`.

:func:`build_fmus` builds the stale ones of the three (:func:`is_stale`, or another robot's) in child
processes, ``python -m cosim.fmus.cli`` (each FMU by :mod:`cosim.fmus.builds`): a process that later
runs FMUs must load each FMU only once, and a build imports the slave and builds maps.  On a first
build of the DK's code the other builds run at a lower priority beside its early compile
(:mod:`cosim.fmus.early_compile`).
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from solver import progress as _progress

from .builds import DK_NAME, FMU_NAMES, project_packages
from .early_compile import pending as early_compile_pending
from .packaging import bundled_files
from .robot_build import other_robot
from .sources import LOADER_SOURCE, SLAVE_DIR, slave_readme, slave_script

__all__ = ["build_fmus", "is_stale", "FIRST_BUILD"]


def is_stale(name: str, fmu: Path) -> bool:
    """Whether ``fmu`` is missing or older than any source it is made of: its slave script, every module
    it bundles (of ``fmu_src``, ``solver`` and ``dynamics``), its readme, or the build code (the loader's
    C source, :mod:`cosim.fmus.native`, ``packaging``, ``kernels``, ``model_description``, ``builds``,
    ``robot_build``)."""
    if not fmu.exists():
        return True
    script = slave_script(name)
    packages = {SLAVE_DIR.name: SLAVE_DIR, **{p.name: p for p in project_packages()}}
    bundled = bundled_files(script, packages).values()
    here = Path(__file__).resolve().parent
    build_code = (*LOADER_SOURCE.parent.glob("*.[ch]"), slave_readme(name),
                  *(here / f for f in ("native.py", "packaging.py", "kernels.py", "model_description.py", "builds.py",
                                       "robot_build.py")))
    return fmu.stat().st_mtime < max(p.stat().st_mtime for p in (script, *bundled, *build_code))


#: What a first build of each FMU does, and about how long it takes (2 cores, the three at once: the DK's
#: kernels 80-86 s, its map beside them 42-44 s at a lower priority after 17-29 s of its own kernels; the
#: others' kernels 20-39 s at a lower priority; once per code version; a rebuild 3-8 s): said when the build
#: starts.
FIRST_BUILD = {
    DK_NAME: "the first time it builds the map tensor (procedure 1) and compiles the kernels it ships: about "
             "1.5 min; later builds reuse both",
    "ComputedTorqueController": "the first time it compiles the kernels it ships: about 30 s; later a few seconds",
    "RRRPlant": "the first time it compiles the kernels it ships: about 30 s; later a few seconds",
}


def build_fmus(out_dir="build", resolution=None, force: bool = False, progress: bool | None = None,
               robot=None) -> dict:
    """Build (or reuse) the three FMUs in ``out_dir``; returns {name: path}.

    The DK FMU embeds the map tensor of posture 1 at the default resolution, or at ``resolution`` =
    (m, rad), from the map cache.  ``robot``: a :class:`solver.robot.Robot` loaded from a file, with
    ``[dynamics]`` (None: the paper's robot): the three FMUs of that robot (the DK map of its home
    posture), rebuilt when the description they carry differs.  An FMU is rebuilt when ``force`` or
    :func:`is_stale`.  Each build runs in a child process, ``python -m cosim.fmus.cli`` (see the
    module docstring), all of them at once: the controller's and the plant's builds (tens of seconds)
    run beside the DK's map and kernel compile (minutes), on a second core.  The builds are one phase
    on stderr (what is built, about how long, then its time; the children's own phases, e.g. of a
    map build, show beneath, each naming its FMU); ``progress``: as in :func:`solver.progress.phase`.

    Raises
    ------
    RuntimeError
        A build failed: its exit code and the end of its output (the other builds are completed first).
    """
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    paths = {name: out / f"{name}.fmu" for name in FMU_NAMES}
    quiet = not _progress.is_on(progress)
    env = {**os.environ, _progress.PROGRESS_ENV: "0"} if quiet else None
    if robot is not None and not Path(robot.source).is_file():
        raise ValueError(f"robot: build_fmus needs a robot loaded from a file (solver.robot.load_robot), got "
                         f"one from {robot.source}")
    todo = [name for name in FMU_NAMES if force or is_stale(name, paths[name]) or other_robot(paths[name], robot)]
    if not todo:
        return paths
    detail = "; ".join(f"{name}: {FIRST_BUILD[name]}" for name in todo)
    # a first build of the DK's code: its early compile is the longest step; the other builds go lower
    background = DK_NAME in todo and early_compile_pending(slave_script(DK_NAME), project_packages())
    # the children report their own phases (and say that a long one goes on)
    with _progress.phase(f"building {', '.join(todo)} in {out}", detail, enabled=progress, heartbeat=False), \
            tempfile.TemporaryDirectory(prefix="rrr-dk-builds-") as logs, contextlib.ExitStack() as files:
        running = {}
        try:
            for name in todo:               # files, not pipes: a child never waits for us to read it
                stdout = files.enter_context(open(Path(logs) / f"{name}.out", "w+"))
                stderr = files.enter_context(open(Path(logs) / f"{name}.err", "w+")) if quiet else None
                args = _build_args(name, out, resolution, robot, background=background)
                running[name] = (subprocess.Popen(args, cwd=str(SLAVE_DIR.parent),
                                                  stdout=stdout, stderr=stderr, text=True, env=env), stdout, stderr)
            failed = [_failure(paths[name], *run) for name, run in running.items()]
        finally:                            # interrupted (Ctrl-C) or failed to start one: stop the others
            for proc, _, _ in running.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        failed = [f for f in failed if f]
        if failed:
            raise RuntimeError("\n\n".join(failed))
    return paths


def _failure(path: Path, proc, stdout, stderr) -> str:
    """Wait for the build of ``path`` in ``proc``; "" when it succeeded, else what went wrong (the end of
    its stdout and, when it was captured in the file ``stderr``, of its stderr)."""
    code = proc.wait()
    if code == 0 and path.exists():
        return ""
    stdout.seek(0)
    err = "(its stderr is above)"
    if stderr is not None:
        stderr.seek(0)
        err = stderr.read()[-3000:]
    return f"building {path.name} failed (exit {code}):\n{stdout.read()[-3000:]}\n{err}"


def _build_args(name: str, out: Path, resolution, robot, background: bool = False) -> list:
    """The command line of the child process that builds FMU ``name`` into ``out`` (``background``: beside
    the DK's early compile, at a lower priority, :data:`BACKGROUND_NICE`)."""
    args = [sys.executable, "-m", "cosim.fmus.cli", "--out", str(out), "--only", name, "--no-reference"]
    if background:
        args.append("--background")
    if robot is not None:
        args += ["--robot", str(Path(robot.source).resolve())]
    if name == DK_NAME and resolution is not None:
        args += ["--resolution", "{!r}m,{!r}rad".format(*(float(v) for v in resolution))]
    return args
