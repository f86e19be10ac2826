"""The compiled kernels an FMU ships (host side, build time; the runtime half is :mod:`fmu_src.kernel_cache`).

``build_fmu(..., kernels=warm_up(scenario))`` (:mod:`cosim.fmus.packaging`) builds the FMU, hands
it to :func:`shipped_kernels` and builds it again with the entries returned:

1. a child process (no project package imported, ``PYTHONPATH`` dropped: the FMU runs its bundled
   copies, as in a host without them) with ``NUMBA_CPU_NAME=generic`` (machine code for any
   x86-64 CPU, no CPU features) and ``NUMBA_CACHE_DIR`` = :func:`generic_root` extracts the FMU
   and runs it through fmpy along the runs of a :class:`Scenario` (instantiate, initialize, the
   steps; its reference run, so every kernel its slave calls on that path is compiled);
2. the child's numba cache of the FMU's key (``<generic root>/<key>/``, :func:`fmu_src.kernel_cache.
   bundle_key`) becomes ``resources/kernels/`` with ``resources/kernels/manifest.json``: numba and
   Python versions, machine, key, and the compile seconds of each outermost kernel (what the
   runtime quotes when it must compile one after all).

The generic cache lives under the project's cache root (``cache_dir("fmu-kernels-generic")``),
keyed by the bundled code: a rebuild of unchanged code compiles nothing (the child loads every
kernel) and ships the same bytes, and FMUs of one code that differ only in start values (the DK
FMU's posture and mode) share it.  The seconds measured when a kernel was first compiled are kept
beside it (``seconds.json``), so a rebuild quotes them unchanged.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from fmu_src.kernel_cache import GENERIC_CPU, MANIFEST, SHIPPED
from solver import cache_dir

__all__ = ["Run", "Scenario", "generic_root", "shipped_kernels", "warm_up", "KernelBuildError"]

_SECONDS = "seconds.json"

#: the child: runs the FMU (argv: FMU, scenario JSON, extraction folder) and prints what it compiled
_CHILD = r"""
import json, os, sys, time
from numba.core import event

SECONDS, DEPTH = {}, [0, 0.0]
class Outermost(event.Listener):
    def on_start(self, ev):
        if DEPTH[0] == 0:
            DEPTH[1] = time.perf_counter()
        DEPTH[0] += 1
    def on_end(self, ev):
        DEPTH[0] -= 1
        if DEPTH[0] == 0:
            f = ev.data["dispatcher"].py_func
            name = f"{f.__module__}.{f.__qualname__}"
            SECONDS[name] = SECONDS.get(name, 0.0) + time.perf_counter() - DEPTH[1]
event.register("numba:compile", Outermost())

import numba, numpy as np
from fmpy import extract, simulate_fmu
folder = extract(sys.argv[1], unzipdir=sys.argv[3])
with open(sys.argv[2]) as f:
    runs = json.load(f)
for run in runs:
    names = sorted(run["inputs"])
    table = None
    if names:
        t = np.arange(len(run["inputs"][names[0]])) * run["h"]
        table = np.array(list(zip(t, *(run["inputs"][n] for n in names))),
                         dtype=[("time", np.float64)] + [(n, np.float64) for n in names])
    simulate_fmu(folder, stop_time=run["n"] * run["h"], step_size=run["h"], output_interval=run["h"],
                 start_values=run["start"], input=table, fmi_type="CoSimulation")
resources = os.path.join(folder, "resources")
for name in ("solver", "dynamics"):
    module = sys.modules.get(name)
    if module is not None and not os.path.abspath(module.__file__).startswith(resources):
        raise SystemExit(f"the warm-up ran the host's {name} ({module.__file__}), not the FMU's")
cache = sys.modules["fmu_src.kernel_cache"]
print("KERNELS " + json.dumps({"key": cache.bundle_key(resources), "seconds": SECONDS, "numba": numba.__version__,
                               "python": "%d.%d" % sys.version_info[:2]}))
sys.stdout.flush()
os._exit(0)
"""


class KernelBuildError(RuntimeError):
    """The warm-up run of an FMU failed; the message carries its output."""


@dataclass
class Run:
    """One fmpy run of the warm-up: ``n`` steps of ``h`` s, start values, inputs ``{name: n values}``."""

    n: int
    h: float
    start: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        return {"n": int(self.n), "h": float(self.h), "start": {k: (v if isinstance(v, (int, bool)) else float(v))
                                                                for k, v in self.start.items()},
                "inputs": {k: [float(x) for x in v] for k, v in self.inputs.items()}}


@dataclass
class Scenario:
    """The runs that call every kernel an FMU's slave uses (its reference run, at least)."""

    runs: list[Run]


def generic_root() -> Path:
    """Where the warm-up keeps the generic kernels: ``cache_dir("fmu-kernels-generic")``."""
    return cache_dir("fmu-kernels-generic")


def _run_child(fmu: Path, scenario: Scenario, root: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CPU_FEATURES")}
    env.update(NUMBA_CPU_NAME=GENERIC_CPU, NUMBA_CPU_FEATURES="", NUMBA_CACHE_DIR=str(root))
    with tempfile.TemporaryDirectory(prefix="fmu_kernels_") as tmp:
        runs = Path(tmp) / "runs.json"
        runs.write_text(json.dumps([r.as_json() for r in scenario.runs]))
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(fmu), str(runs), str(Path(tmp) / "x")],
                              capture_output=True, text=True, env=env, cwd=tmp)
    for line in proc.stdout.splitlines():
        if line.startswith("KERNELS "):
            return json.loads(line[len("KERNELS "):])
    raise KernelBuildError(f"the warm-up run of {fmu.name} failed (exit {proc.returncode}):\n"
                           f"{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")


def shipped_kernels(fmu: Path, scenario: Scenario, root: Path | None = None) -> dict[str, bytes]:
    """Run ``fmu`` along ``scenario`` in a generic-CPU child (module docstring) and return the
    entries ``{"resources/kernels/...": bytes}`` of its compiled kernels and their manifest.

    ``root``: the generic kernel cache (default :func:`generic_root`).
    """
    root = Path(root) if root is not None else generic_root()
    found = _run_child(Path(fmu), scenario, root)
    folder = root / found["key"]
    kept = folder / _SECONDS
    seconds = json.loads(kept.read_text()) if kept.is_file() else {}
    if found["seconds"]:
        seconds.update({k: round(v, 1) for k, v in found["seconds"].items()})
        kept.write_text(json.dumps(seconds, indent=1, sort_keys=True) + "\n")
    entries = {f"resources/{SHIPPED}/{p.relative_to(folder).as_posix()}": p.read_bytes()
               for p in sorted(folder.rglob("*")) if p.suffix in (".nbi", ".nbc")}
    if not entries:
        raise KernelBuildError(f"the warm-up run of {Path(fmu).name} compiled no kernel into {folder}")
    manifest = {"numba": found["numba"], "python": found["python"], "machine": platform.machine().lower(), "cpu": GENERIC_CPU,
                "key": found["key"], "seconds": seconds, "total_seconds": round(sum(seconds.values()), 1)}
    entries[f"resources/{SHIPPED}/{MANIFEST}"] = (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()
    return entries


def warm_up(scenario: Scenario, root: Path | None = None):
    """The ``kernels`` argument of :func:`cosim.fmus.packaging.build_fmu` for ``scenario``."""
    return lambda fmu: shipped_kernels(fmu, scenario, root)
