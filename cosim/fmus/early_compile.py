"""The DK's C entry point compiled beside the map: the build's longest step begun before its second longest.

An FMU's generic kernels are compiled by running the built FMU along its runs
(:mod:`cosim.fmus.kernels`), and the DK FMU embeds its map, so on a first build that compile (about
2 minutes, most of it numba compiling the tracker's C entry point, :mod:`solver._kernels.c_entry`)
started only once the map tensor was built, while one of the two cores idled.  The entry point needs
no map.  :func:`begin` stages the packages the FMU will bundle, byte for byte
(:func:`cosim.fmus.packaging.bundled_files`: the same files, hence the same kernel key) and compiles
the entry point from them in a child process, for the generic CPU, into the generic store the
warm-up uses; the build makes its map meanwhile.  :meth:`EarlyCompile.finish` waits for it before
the warm-up, which then loads the entry point from the store and compiles only the rest along the
FMU's runs.

The warm-up still decides what an FMU ships (every kernel its runs call); this only fills the store
sooner.  Nothing here can fail a build: a child that fails, or cannot start, leaves the compile to
the warm-up, as before, with one line on stderr.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from fmu_src.kernel_cache import BUNDLE_MARK, GENERIC_CPU, key_of
from fmu_src.kernel_warmup import IN_PROCESS
from solver import progress

from .kernels import Scenario, generic_root, is_warmed
from .packaging import bundled_files
from .sources import SLAVE_DIR

try:
    import fcntl
except ImportError:                     # pragma: no cover - Windows: no early compile
    fcntl = None

__all__ = ["ENTRY", "EarlyCompile", "Waiting", "begin"]

#: The bundled file whose kernels :func:`begin` compiles (a bundle without it has nothing to begin).
ENTRY = "solver/_kernels/c_entry.py"

#: the child: the staged packages first on the path, the FMU runtime's cache locator, the entry point
_CHILD = r"""
import sys
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
cache.install()
from solver._kernels.c_entry import entry
entry()
print("ENTRY " + cache.bundle_key(sys.argv[1]))
"""


class EarlyCompile:
    """A child process compiling the C entry point of a bundle (made by :func:`begin`).  The child holds
    the model's early-compile lock until it exits, so another build of the model waits for it
    (:class:`Waiting`) instead of compiling the same entry point again."""

    def __init__(self, model: str, key: str, proc: subprocess.Popen, work: Path):
        self.model, self.key = model, key
        self._proc, self._work = proc, work

    def finish(self) -> bool:
        """Wait for the compile (a phase line on stderr while it runs); True when it succeeded."""
        try:
            with progress.phase(f"compiling the kernels {self.model} ships (generic x86-64 CPU): its C entry point, "
                                "begun beside the map", "the rest follows along the FMU's runs"):
                code = self._proc.wait()
            out = (self._work / "out.txt").read_text(errors="replace")
            if code == 0 and f"ENTRY {self.key}" in out:
                return True
            tail = "\n".join(out.strip().splitlines()[-5:])
            progress.note(f"{self.model}: the early compile of its C entry point failed (exit {code}); the "
                          f"warm-up compiles it instead:\n{tail}")
            return False
        finally:
            self.stop()

    def stop(self) -> None:
        """Kill the child if it still runs (its lock goes with it) and remove its staging (idempotent)."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        shutil.rmtree(self._work, ignore_errors=True)


class Waiting:
    """Another process (a build beside this one, or the :func:`cosim.fmus.builds.build_fmus` that started
    this build) compiles the model's C entry point: :meth:`finish` waits for it."""

    def __init__(self, model: str, lock_path: Path):
        self.model, self._lock_path = model, lock_path

    def finish(self) -> bool:
        """Wait until that compile ends (a phase line on stderr while it runs); True."""
        with progress.phase(f"compiling the kernels {self.model} ships (generic x86-64 CPU): its C entry point, "
                            "begun beside the map by another process", "the rest follows along the FMU's runs"), \
                open(self._lock_path, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)            # released at once, when the file closes
        return True

    def stop(self) -> None:
        """Nothing to stop: the compile is the other process's."""


def begin(script: Path, project_packages, scenario: Scenario, root: Path | None = None) -> EarlyCompile | Waiting | None:
    """Start compiling the C entry point of the FMU that :func:`cosim.fmus.packaging.build_fmu` will make of
    ``script`` with ``project_packages``, for the generic CPU into ``root`` (default
    :func:`cosim.fmus.kernels.generic_root`); None when there is nothing to begin: the bundle has no
    entry point, the store already holds this key warmed up along ``scenario``, or the platform has no file
    locks.  A :class:`Waiting` when another process compiles this model's entry point already."""
    if fcntl is None:
        return None
    script = Path(script)
    model = script.stem
    packages = {SLAVE_DIR.name: SLAVE_DIR, **{Path(p).resolve().name: Path(p).resolve() for p in project_packages}}
    files = bundled_files(script, packages)
    if ENTRY not in files:
        return None
    key = key_of((rel, path.read_bytes()) for rel, path in files.items())
    store = (Path(root) if root is not None else generic_root()) / model
    if is_warmed(store / key, scenario):
        return None
    base = Path(tempfile.gettempdir()) / f"rrr-dk-warm-up-{getattr(os, 'getuid', lambda: 0)()}"
    base.mkdir(exist_ok=True)
    lock_path = base / f"{model}-entry.lock"
    lock = open(lock_path, "a")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:                             # another process compiles it: wait for that one
        lock.close()
        return Waiting(model, lock_path)
    work = base / f"{model}-entry"
    try:
        shutil.rmtree(work, ignore_errors=True)
        resources = work / "resources"
        for rel, path in files.items():
            (resources / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, resources / rel)
        (resources / BUNDLE_MARK).write_text(model)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CPU_FEATURES")}
        env.update(NUMBA_CPU_NAME=GENERIC_CPU, NUMBA_CPU_FEATURES="", NUMBA_CACHE_DIR=str(store), PYTHONHASHSEED="0")
        env[IN_PROCESS] = "1"
        with open(work / "out.txt", "w") as out:     # the child inherits the lock: held until it exits
            proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(resources)], stdout=out,
                                    stderr=subprocess.STDOUT, env=env, cwd=work, pass_fds=(lock.fileno(),))
    except OSError as e:
        progress.note(f"{model}: the early compile of its C entry point did not start ({e}); the warm-up "
                      "compiles it instead")
        shutil.rmtree(work, ignore_errors=True)
        return None
    finally:
        lock.close()                            # this process's hold; the child's stays
    return EarlyCompile(model, key, proc, work)
