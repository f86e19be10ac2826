"""The DK's C entry point compiled beside the map: the build's longest step begun before its second longest.

An FMU's generic kernels are compiled by running the built FMU along its runs
(:mod:`cosim.fmus.kernels`), and the DK FMU embeds its map, so on a first build that compile (about
70 s on one core, 64 s of it numba compiling the tracker's C entry point, :mod:`solver._kernels.c_entry`)
started only once the map tensor was built, while one of the two cores idled.  The entry point needs
no map.  :func:`begin` stages the packages the FMU will bundle, byte for byte
(:func:`cosim.fmus.packaging.bundled_files`: the same files, hence the same kernel key) and compiles
the entry point from them in a child process, for the generic CPU, into the generic store the
warm-up uses; the build makes its map meanwhile.  :meth:`EarlyCompile.finish` waits for it before
the warm-up, which then loads the entry point from the store and compiles only the rest along the
FMU's runs.

After the entry point the child compiles the kernels the tracker's Python side calls
(:func:`solver.precompile.compile_tracker`: the start's proof, the DK, procedure 2's look-up, ...).
They call the entry point's callees, which this process has typed already; the warm-up, another
process, would type them all again (5.5 s here; the warm-up took 29.7 s when it compiled them, 1.1-1.6 s
now).  And on a first build of this code
(:func:`pending`) :func:`cosim.fmus.fmu_set.build_fmus` runs its other builds at a lower priority
(``BACKGROUND_NICE``), so that this child keeps a core: it is the longest step of that build.

The warm-up still decides what an FMU ships (every kernel its runs call); this only fills the store
sooner.  Nothing here can fail a build: a child that fails, or cannot start, leaves the compile to
the warm-up, as before, with one line on stderr.
"""
from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from fmu_src.kernel_cache import BUNDLE_MARK, key_of
from solver import progress

from .kernels import (BESIDE, Scenario, generic_env, generic_root, has_record, is_warmed, record_seconds, seed,
                      warm_up_base)
from .packaging import bundled_files
from .sources import SLAVE_DIR

try:
    import fcntl
except ImportError:                     # pragma: no cover - Windows: no early compile
    fcntl = None

__all__ = ["ENTRY", "EarlyCompile", "Waiting", "begin", "pending", "lower_priority", "BACKGROUND_NICE"]

#: How much :func:`cosim.fmus.fmu_set.build_fmus`' children lower their priority (``os.nice``) beside the DK's
#: early compile, the longest step of a first build of the DK's code: the plant's and controller's builds from their start, the
#: DK's own once that compile has begun (its map and warm-up), so that the compile keeps a core of its own.
#: (10: a task at nice 0 then gets about nine tenths of a core it shares with one of them; 19 measured the
#: same and would starve these builds beside other work.)
BACKGROUND_NICE = 10
#: The bundled file whose kernels :func:`begin` compiles (a bundle without it has nothing to begin).
ENTRY = "solver/_kernels/c_entry.py"

#: the child: the staged packages first on the path, the FMU runtime's cache locator, the entry point, then
#: the kernels the tracker's Python side calls (solver.precompile, argv[2]: not bundled, so loaded from the
#: building project's file, running the staged solver; the kernels share the entry point's callees, typed
#: once here; a failure there leaves them to the warm-up and fails nothing)
_CHILD = r"""
import importlib.util, sys, time
sys.path.insert(0, sys.argv[1])
import fmu_src.kernel_cache as cache
import fmu_src.kernel_locator as locator
locator.install()
from solver._kernels.c_entry import entry
key = cache.bundle_key(sys.argv[1])
start = time.perf_counter()
entry()
print("ENTRY %s %.1f" % (key, time.perf_counter() - start), flush=True)
try:
    spec = importlib.util.spec_from_file_location("solver.precompile", sys.argv[2])
    precompile = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(precompile)
    start = time.perf_counter()
    precompile.compile_tracker()
    print("TRACKER %s %.1f" % (key, time.perf_counter() - start), flush=True)
except Exception as exc:
    print("the tracker's own kernels were not compiled: %s: %s" % (type(exc).__name__, exc), flush=True)
"""

#: the names its compile seconds are recorded under (the warm-up names kernels by module and function)
ENTRY_KERNEL = "solver._kernels.c_entry.entry"
TRACKER_KERNELS = "solver.precompile.compile_tracker"
#: how the child's line begins when the tracker's own kernels failed to compile (the entry point did not)
TRACKER_FAILED = "the tracker's own kernels were not compiled"


class EarlyCompile:
    """A child process compiling the C entry point of a bundle (made by :func:`begin`).  The child holds
    the early-compile lock of the model's store folder of this key until it exits, so another build of
    the same model and code waits for it (:class:`Waiting`) instead of compiling the same entry point again."""

    def __init__(self, model: str, key: str, proc: subprocess.Popen, work: Path, folder: Path):
        self.model, self.key = model, key
        self._proc, self._work, self._folder = proc, work, folder

    def finish(self) -> bool:
        """Wait for the compile (a phase line on stderr while it runs); True when it succeeded."""
        try:
            with progress.phase(f"compiling the kernels {self.model} ships (generic x86-64 CPU): its C entry point "
                                "and the tracker's own, begun beside the map", "the rest follows along the FMU's runs"):
                code = self._proc.wait()
            try:
                out = (self._work / "out.txt").read_text(errors="replace")
            except OSError as e:
                out = f"(its output is gone: {e})"
            done = {name: [line.split() for line in out.splitlines() if line.startswith(f"{tag} {self.key} ")]
                    for tag, name in (("ENTRY", ENTRY_KERNEL), ("TRACKER", TRACKER_KERNELS))}
            if done[ENTRY_KERNEL]:               # the entry point is in the store, even if the rest failed
                # its compile seconds join the warm-up's (what a host that must compile is told to expect)
                record_seconds(self._folder, {f"{name} {BESIDE}": float(lines[-1][2])
                                              for name, lines in done.items() if lines})
                failed = [line for line in out.splitlines() if line.startswith(TRACKER_FAILED)]
                if failed:
                    progress.note(f"{self.model}: {failed[-1]} (the warm-up compiles them)")
                elif not done[TRACKER_KERNELS]:      # the child died after the entry point (a crash, a kill)
                    progress.note(f"{self.model}: the early compile ended (exit {code}) after its C entry point, "
                                  "before the tracker's own kernels (the warm-up compiles them)")
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
    """Another process (a build beside this one, or the :func:`cosim.fmus.fmu_set.build_fmus` that started
    this build) compiles the model's C entry point: :meth:`finish` waits for it."""

    def __init__(self, model: str, lock_path: Path):
        self.model, self._lock_path = model, lock_path

    def finish(self) -> bool:
        """Wait until that compile ends (a phase line on stderr while it runs); True, or False when the lock
        cannot be waited for (the warm-up then compiles what is missing)."""
        try:
            with progress.phase(f"compiling the kernels {self.model} ships (generic x86-64 CPU): its C entry "
                                "point, begun beside the map by another process",
                                "the rest follows along the FMU's runs"), open(self._lock_path, "a") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)        # released at once, when the file closes
        except OSError:
            return False
        return True

    def stop(self) -> None:
        """Nothing to stop: the compile is the other process's."""


def begin(script: Path, project_packages, scenario: Scenario, root: Path | None = None,
          seeds: tuple = ()) -> EarlyCompile | Waiting | None:
    """Start compiling the C entry point of the FMU that :func:`cosim.fmus.packaging.build_fmu` will make of
    ``script`` with ``project_packages``, for the generic CPU into ``root`` (default
    :func:`cosim.fmus.kernels.generic_root`).  ``seeds``: the models whose store folder of the same key
    seeds a new one (:func:`cosim.fmus.kernels.seed`; the child then loads the entry point in seconds).
    None when there is nothing to begin (the bundle has no
    entry point, the store already holds this key warmed up along ``scenario``, another build warms up
    this key now, the platform has no file locks) or it could not begin (said on stderr): the warm-up
    then compiles it.  A :class:`Waiting` when another process compiles this model's entry point of this
    code (the same store folder)."""
    if fcntl is None:
        return None
    try:
        return _begin(Path(script), project_packages, scenario, root, seeds)
    except Exception as e:  # noqa: BLE001 - an optimization: never a build's failure
        progress.note(f"{Path(script).stem}: the early compile of its C entry point did not start ({e}); the "
                      "warm-up compiles it instead")
        return None


def _flocked(path: Path):
    """``path`` opened and locked without waiting: the file, or None when another process holds the lock."""
    f = open(path, "a")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        f.close()
        if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise                                   # no locks here (a file system without them): not begun
    return f


def lower_priority() -> None:
    """Lower this process's priority by :data:`BACKGROUND_NICE` (POSIX ``nice``; for good: an unprivileged
    process cannot raise it again).  Nothing where the system has no ``nice`` or refuses."""
    try:
        os.nice(BACKGROUND_NICE)
    except (AttributeError, OSError):       # pragma: no cover - Windows, or a refusal
        pass


def pending(script: Path, project_packages, root: Path | None = None) -> bool:
    """Whether a build of ``script`` is a first build of its code: its bundle has the C entry point and the
    store holds no warm-up of its key (then the build compiles the entry point beside the map).  What
    :func:`cosim.fmus.fmu_set.build_fmus` asks before it lowers its other builds' priority (cheap: no
    scenario, no kernel); False when it cannot tell."""
    try:
        files, key = _bundle(Path(script), project_packages)
        root = Path(root) if root is not None else generic_root()
        return files is not None and not has_record(root / Path(script).stem / key)
    except Exception:  # noqa: BLE001 - a hint for the scheduling only
        return False


def _package_dirs(project_packages) -> dict:
    """``{name: folder}`` of the packages a bundle is made of (the slaves' and ``project_packages``)."""
    return {SLAVE_DIR.name: SLAVE_DIR, **{Path(p).resolve().name: Path(p).resolve() for p in project_packages}}


def _bundle(script: Path, project_packages):
    """The files the FMU of ``script`` bundles and their kernel key, or (None, None) without an entry point."""
    files = bundled_files(script, _package_dirs(project_packages))
    if ENTRY not in files:
        return None, None
    return files, key_of((rel, path.read_bytes()) for rel, path in files.items())


def _begin(script: Path, project_packages, scenario: Scenario, root: Path | None, seeds: tuple = ()):
    model = script.stem
    files, key = _bundle(script, project_packages)
    if files is None:
        return None
    precompile = _package_dirs(project_packages)["solver"] / "precompile.py"
    root = Path(root) if root is not None else generic_root()
    store = root / model
    if is_warmed(store / key, scenario):
        return None
    base = warm_up_base()
    (store / key).mkdir(parents=True, exist_ok=True)
    lock_path = store / key / ".entry.lock"     # in the store: builds into other stores, or of other code, never wait
    held = []
    try:
        entry_lock = _flocked(lock_path)
        if entry_lock is None:                  # another process compiles it: wait for that one
            return Waiting(model, lock_path)
        held.append(entry_lock)
        key_lock = _flocked(store / key / ".lock")     # the warm-up's lock of this key (cosim.fmus.kernels)
        if key_lock is None:                    # another build warms this key up now; ours waits for it
            return None
        held.append(key_lock)
        seed(store / key, [root / m / key for m in seeds])     # under the key's lock, as the warm-up seeds
        work = Path(tempfile.mkdtemp(prefix=f"{model}-entry-", dir=base))
        resources = work / "resources"
        for rel, path in files.items():
            (resources / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, resources / rel)
        (resources / BUNDLE_MARK).write_text(model)
        env = generic_env(store)
        try:
            with open(work / "out.txt", "w") as out:   # the child inherits both locks: held until it exits
                proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(resources), str(precompile)], stdout=out,
                                        stderr=subprocess.STDOUT, env=env, cwd=work,
                                        pass_fds=tuple(f.fileno() for f in held))
        except BaseException:
            shutil.rmtree(work, ignore_errors=True)
            raise
        return EarlyCompile(model, key, proc, work, store / key)
    finally:
        for f in held:
            f.close()                           # this process's hold; the child's stays
