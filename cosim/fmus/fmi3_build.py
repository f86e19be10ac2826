"""The FMI 3.0 DK FMU, ``RRRDirectKinematics3`` (host side; ``python build_fmu.py --fmi 3``).

:func:`build_dk3` builds ``<out>/RRRDirectKinematics.fmu`` (``build/fmi3/`` by default): the slave
``fmu_src/RRRDirectKinematics3.py`` (pythonfmu3, an :class:`fmu_src.fmi3_adapter.Fmi3Adapter` around
the FMI 2.0 slave ``RRRDirectKinematics``) with what the FMI 2.0 DK FMU carries:

1. ``resources/``: the script, the modules of ``fmu_src`` and ``solver`` it imports (with the FMI 2.0
   slave and its runtime), pythonfmu's Python files (the FMI 2.0 slave's base class imports
   pythonfmu; pythonfmu's own builder bundles them the same way, binaries left out), the map tensors
   and their manifest (:func:`cosim.fmus.builds.stage_maps`), ``requirements.txt`` (numpy, numba...:
   checked by the script's first statement on the host, :mod:`fmu_src.requirements`) and, unless
   ``kernels=False``, the kernels compiled for a generic x86-64 CPU along the reference circle
   (:mod:`cosim.fmus.kernels`);
2. pythonfmu3's ``FmuBuilder`` makes the archive; its modelDescription.xml is replaced by
   :func:`cosim.fmus.fmi3_description.model_description_xml` (the instantiation token derived from
   the content), the binaries of platforms never run here are dropped (pythonfmu3 ships
   ``x86_64-windows`` too; the FMU keeps ``x86_64-linux``), and the zip is written deterministically.

The FMU's file is named like the FMI 2.0 one; its modelIdentifier (and slave module) is
``RRRDirectKinematics3``: pythonfmu3's wrapper imports the slave module by name into the host's
``sys.modules``, shared with a pythonfmu FMU loaded in the same process.

Hosts without Python: pythonfmu3's wrapper, like pythonfmu's, calls the Python C API without being
linked to libpython.  :func:`_archive` puts the project's FMI 3.0 loader in front of it
(:func:`cosim.fmus.native.loader_entries` with ``fmi=3``): ``binaries/x86_64-linux/RRRDirectKinematics3.so``
is ``fmu_src/loader/fmi3_loader.c`` compiled with the system C compiler, pythonfmu3's wrapper sits
beside it as ``libpythonfmu3-export.so`` and ``resources/python_runtime.txt`` records the building
interpreter.  The loader starts a Python in a C host as the FMI 2.0 FMUs' loader does, keeps FMI
3.0's Co-Simulation state table per instance (fmi3Error for a forbidden or refused call, fmi3Discard
for a refused step) and is otherwise transparent.  Without a C compiler the FMU keeps pythonfmu3's
binary (a :class:`cosim.fmus.native.NativeBuildWarning`) and runs in hosts that have Python only
(see ``fmu_src/RRRDirectKinematics3.md``).
"""
from __future__ import annotations

import hashlib
import importlib.util
import shutil
import sys
import tempfile
import time
import uuid
import zipfile
from pathlib import Path

from fmu_src import requirements
from solver import DEFAULT_RULE, Manipulator

from . import builds, native
from .builds import DEFAULT_RESOLUTION, MODES, BuildResult
from .fmi3_description import model_description_xml
from .kernels import Run, Scenario, warm_up
from .robot_build import robot_constant, stage_robot
from .packaging import (BuildError, _check_module_name_is_free, _isolated_module, _stage_data_files, bundled_files,
                        declared_requirements, third_party_modules, write_zip)
from .sources import SLAVE_DIR, slave_script

__all__ = ["DK3_NAME", "DK3_FILE", "PLATFORM", "build_dk3", "warm_up_scenario3"]

#: the FMI 3.0 DK slave (module, class, modelIdentifier) and the FMU's file name
DK3_NAME = "RRRDirectKinematics3"
DK3_FILE = "RRRDirectKinematics.fmu"
#: the one platform whose binary the FMU keeps (the only one its tests ran on)
PLATFORM = "x86_64-linux"
_TOKEN_NAMESPACE = uuid.UUID("0b6e0f0e-3d5a-4c1f-8f61-2f7d5c3a9e41")


def _stage(staging: Path, script: Path, data_files: dict) -> None:
    """resources/: the script, what it imports of fmu_src and solver, pythonfmu's Python files, the data
    files, requirements.txt (third-party packages but pythonfmu and pythonfmu3, which are bundled)."""
    shutil.copyfile(script, staging / script.name)
    packages = {SLAVE_DIR.name: SLAVE_DIR, **{p.name: p for p in builds.project_packages()}}
    bundled = bundled_files(script, packages)
    for rel, src in bundled.items():
        (staging / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, staging / rel)
    pythonfmu = Path(importlib.util.find_spec("pythonfmu").origin).parent
    (staging / "pythonfmu").mkdir()
    for src in sorted(pythonfmu.glob("*.py")):
        shutil.copyfile(src, staging / "pythonfmu" / src.name)
    needs = declared_requirements(third_party_modules([script, *bundled.values()],
                                                      {*packages, "pythonfmu", "pythonfmu3"}))
    (staging / requirements.FILE).write_text(requirements.format_requirements(Path(DK3_FILE).stem, needs))
    _stage_data_files(staging, data_files)


def _load_class(path: Path):
    spec = importlib.util.spec_from_file_location(DK3_NAME, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[DK3_NAME] = mod
    sys.path.insert(0, str(path.parent))
    spec.loader.exec_module(mod)
    return getattr(mod, DK3_NAME)


def _archive(raw: Path, final: Path, cls, extra: dict | None = None) -> None:
    """The FMU from pythonfmu3's archive ``raw``: our modelDescription.xml, the binary of :data:`PLATFORM`
    only, behind the FMI 3.0 loader (module docstring), ``extra`` entries added, written
    deterministically (sorted, fixed times and modes)."""
    with zipfile.ZipFile(raw) as z:
        entries = {i.filename: z.read(i) for i in z.infolist() if not i.is_dir()}
    if entries.get("resources/slavemodule.txt", b"").decode().strip() != DK3_NAME:
        raise BuildError("resources/slavemodule.txt does not name the slave module")
    if f"binaries/{PLATFORM}/{DK3_NAME}.so" not in entries:
        raise BuildError(f"pythonfmu3 wrote no binaries/{PLATFORM}/{DK3_NAME}.so")
    entries = {n: b for n, b in entries.items()
               if not n.startswith("binaries/") or n.startswith(f"binaries/{PLATFORM}/")}
    entries = native.loader_entries(entries, DK3_NAME, fmi=3)
    entries.update(extra or {})
    del entries["modelDescription.xml"]
    digest = hashlib.sha256(model_description_xml(cls, token=""))
    for name in sorted(entries):
        digest.update(name.encode() + b"\0" + hashlib.sha256(entries[name]).digest())
    token = "{" + str(uuid.uuid5(_TOKEN_NAMESPACE, digest.hexdigest())) + "}"
    entries["modelDescription.xml"] = model_description_xml(cls, token=token)
    write_zip(final, entries)


def build_dk3(out_dir="build/fmi3", postures=(1,), resolution=None, map_files=(), mode: str = "default",
              rule: str = DEFAULT_RULE, cache_dir=None, check: bool = True, progress: bool | None = None,
              log=print, kernels: bool = True, robot=None) -> BuildResult:
    """Build ``<out_dir>/RRRDirectKinematics.fmu``, the FMI 3.0 DK FMU (the module docstring).

    The arguments are those of :func:`cosim.fmus.builds.build_dk` (the same maps, from the same map
    cache; ``robot``: a robot description's FMU, its maps, start values and description, as there);
    ``postures[0]`` and ``mode`` are the start values of the parameters ``posture`` and ``mode``.
    ``check``: fmpy's validation (the result's ``problems``).
    """
    from pythonfmu3 import FmuBuilder

    t0 = time.perf_counter()
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    script = slave_script(DK3_NAME)
    _check_module_name_is_free(DK3_NAME, script)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cache_dir = None if cache_dir is None else Path(cache_dir)
    t_map = time.perf_counter()
    if robot is not None and robot.kind != "3-RRR":
        raise ValueError(f"robot: {robot.source} describes a {robot.kind}; the FMI 3.0 DK FMU is a 3-RRR's")
    model = robot.model if robot is not None else Manipulator.paper()
    if resolution is None:
        resolution = robot.resolution if robot is not None else DEFAULT_RESOLUTION
    postures, maps = builds._dk_maps(model, postures, resolution, map_files, rule, cache_dir, progress, log)
    map_seconds = time.perf_counter() - t_map
    final = out_dir / DK3_FILE
    with tempfile.TemporaryDirectory(prefix="build_fmu3_") as tmp:
        tmp = Path(tmp)
        staging = tmp / "resources"
        staging.mkdir()
        _stage(staging, script, {**builds.stage_maps(tmp, maps), **stage_robot(tmp, robot)})
        _set_start(staging / script.name, postures[0], mode, robot)
        with _isolated_module(DK3_NAME):
            cls = _load_class(staging / script.name)
            entries = sorted(p for p in staging.iterdir() if p.name != script.name)
            raw = FmuBuilder.build_FMU(staging / script.name, dest=tmp / "raw", project_files=entries,
                                       documentation_folder=builds._stage_documentation(tmp, DK3_NAME))
        _archive(Path(raw), final, cls)
        if kernels:
            kernel_entries = warm_up(warm_up_scenario3(postures[0], mode, robot), model=DK3_NAME,
                                     seeds=builds.DK_STORES)(final)
            _archive(Path(raw), final, cls, kernel_entries)
    problems = _validate(final) if check else []
    return BuildResult(final, maps, postures[0], mode, time.perf_counter() - t0, map_seconds, problems)


def _set_start(script: Path, posture: int, mode: str, robot=None) -> None:
    """The start values of ``posture`` and ``mode`` (and the robot's): the build constants of the staged
    script, rewritten as the FMI 2.0 build rewrites its own."""
    constant = robot_constant(robot, posture) if robot is not None else None
    script.write_text(builds.with_build_constants(script.read_text(), posture, mode, script, constant))


def _validate(fmu: Path) -> list[str]:
    """fmpy's validation of the FMU, plus the layout pythonfmu3's wrapper needs."""
    from fmpy.validation import validate_fmu

    problems = list(validate_fmu(str(fmu)))
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
    for need in (f"binaries/{PLATFORM}/{DK3_NAME}.so", f"resources/{DK3_NAME}.py", "resources/slavemodule.txt"):
        if need not in names:
            problems.append(f"{need} missing")
    if any("__pycache__" in n or n.endswith(".pyc") for n in names):
        problems.append("compiled Python files in the archive")
    return problems


def warm_up_scenario3(posture: int = 1, mode: str = "default", robot=None) -> Scenario:
    """The runs that compile the kernels the FMI 3.0 FMU ships: the FMI 2.0 DK FMU's
    (:func:`cosim.fmus.builds.warm_up_scenario`, of ``robot`` if given), with ``q`` and ``pose0`` as arrays."""
    runs = []
    for run in builds.warm_up_scenario(builds.DK_NAME, posture, mode, robot).runs:
        start = {k: v for k, v in run.start.items() if k not in ("x0", "y0", "phi0")}
        if "x0" in run.start:
            start["pose0"] = [float(run.start[k]) for k in ("x0", "y0", "phi0")]
        inputs = {}
        if run.inputs:
            inputs["q"] = [[float(v) for v in row] for row in zip(*(run.inputs[f"q{j}"] for j in (1, 2, 3)))]
        runs.append(Run(run.n, run.h, start, inputs))
    return Scenario(runs)

