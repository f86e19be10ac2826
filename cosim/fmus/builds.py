"""The project's three FMUs and how each is built (host side; ``python build_fmu.py`` runs them).

* ``RRRDirectKinematics`` (:func:`build_dk`): the slave ``fmu_src/RRRDirectKinematics.py`` (its
  ``BUILD_POSTURE``/``BUILD_MODE`` constants set to the start values of the parameters ``posture`` and
  ``mode``), the ``solver`` modules it imports, the map tensor of each posture as
  ``resources/maps/posture<j>.npz`` with ``resources/maps/manifest.json`` (size and SHA-256 of each,
  checked at instantiation), and its readme as ``documentation/``.  Maps come from ``map_files`` or
  from the map cache ``solver.cache_dir("maps")`` (:func:`solver.cached_map`, the one cache of ``python -m solver
  build`` too, keyed by geometry, posture, rule, resolution and the code that labels); a missing or
  unusable cache entry is built and saved there, so a rebuild with the same options and code reuses
  it.  Same options and the same map files give a byte-identical FMU.
* ``RRRPlant`` and ``ComputedTorqueController`` (:func:`build_slave`): the slave and the ``solver``
  and ``dynamics`` modules it imports (the math only: never the master, the batch or dask).

Every FMU bundles only what its slave imports (:func:`cosim.fmus.packaging.bundled_files`) and, unless
``kernels=False``, the kernels it calls compiled for a generic x86-64 CPU (:mod:`cosim.fmus.kernels`,
warmed up along :func:`warm_up_scenario`: its reference run), so it starts in seconds in a host without
our packages (:mod:`fmu_src.kernel_cache`); the DK's C entry point begins compiling before its map
is built (:mod:`cosim.fmus.early_compile`).
:func:`cosim.fmus.fmu_set.build_fmus` builds the stale ones of the three in child processes.
"""
from __future__ import annotations

import hashlib
import html
import importlib.util
import json
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from solver import DEFAULT_RULE, DEFAULT_STEP, ORDERING_RULES, Manipulator, MapTensor, cached_map, map_path

from .checks import validate
from .map_report import report_maps
from .early_compile import EarlyCompile, lower_priority
from .early_compile import begin as begin_early_compile
from .kernels import Run, Scenario, warm_up
from .robot_build import robot_circle, robot_constant, robot_slave_scenario, stage_robot, with_robot_constant
from .sources import slave_readme, slave_script
from .packaging import build_fmu

__all__ = ["FMU_NAMES", "DK_NAME", "MODES", "DEFAULT_RESOLUTION", "BuildResult", "parse_resolution",
           "resolution_step", "map_cache_path", "stage_maps", "build_dk", "build_slave", "slave_script",
           "project_packages", "warm_up_scenario"]

#: The three FMUs, in the order of the closed loop's data flow (DK -> controller -> plant).
FMU_NAMES = ("RRRDirectKinematics", "ComputedTorqueController", "RRRPlant")
DK_NAME = "RRRDirectKinematics"
#: The store folders (:mod:`cosim.fmus.kernels`) of the DK FMUs, which run one tracker step: the FMI 2.0 and
#: 3.0 3-RRR's (:mod:`cosim.fmus.fmi3_build`) and the 3-RPR's (:mod:`cosim.fmus.rpr_build`); a new folder of
#: one is seeded from another's of the same code, so one of them compiles the step for all.
DK_STORES = (DK_NAME, "RRRDirectKinematics3", "RPRDirectKinematics")
MODES = ("default", "paper")
#: Default node spacing of the DK map (the map tensor's default): 10 mm in x and y, 2 degrees in phi.
DEFAULT_RESOLUTION = (DEFAULT_STEP[0], DEFAULT_STEP[2])

_LEN_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_ANG_UNITS = {"rad": 1.0, "deg": float(np.pi / 180.0)}


def project_packages() -> list[Path]:
    """The folders of the project packages a slave may import (``solver``, ``dynamics``)."""
    return [Path(importlib.util.find_spec(name).submodule_search_locations[0]) for name in ("solver", "dynamics")]


# ---------------------------------------------------------------------- resolution and maps
def parse_resolution(text) -> tuple[float, float]:
    """Node spacing ``(xy in m, phi in rad)`` from ``"10mm,2deg"``, ``"0.04m 6deg"`` or ``"40 6"`` (mm, deg).

    Accepts a string or a sequence of one or two strings/numbers.
    """
    if isinstance(text, (list, tuple)):
        text = " ".join(str(t) for t in text)
    parts = [p for p in re.split(r"[\s,;/]+", str(text).strip()) if p]
    if len(parts) != 2:
        raise ValueError(f"resolution {text!r}: expected two values, e.g. '10mm,2deg' or '10 2' (mm, deg)")
    out = []
    for part, units, bare, kind in ((parts[0], _LEN_UNITS, "mm", "length"), (parts[1], _ANG_UNITS, "deg", "angle")):
        m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)([a-z]*)", part)
        if not m or (m.group(2) and m.group(2) not in units):
            raise ValueError(f"resolution {text!r}: {part!r} is not a {kind} (units {sorted(units)}; a bare "
                             f"number is in {bare})")
        value = float(m.group(1)) * units[m.group(2) or bare]
        if not value > 0:
            raise ValueError(f"resolution {text!r}: {part!r} must be positive")
        out.append(value)
    return out[0], out[1]


def resolution_step(resolution) -> tuple[float, float, float]:
    """The map node spacing ``(x, y, phi)`` (m, m, rad) of a resolution ``(xy in m, phi in rad)``."""
    return (resolution[0], resolution[0], resolution[1])


def map_cache_path(cache_dir, posture: int, resolution, rule: str, model: Manipulator) -> Path:
    """Cache file of a map in ``cache_dir`` (None: the map cache; ``solver.map_path``, the one naming scheme)."""
    return map_path(model, posture, rule, resolution_step(resolution), cache_dir)


# ---------------------------------------------------------------------- the DK FMU
@dataclass
class BuildResult:
    fmu: Path
    maps: dict[int, Path]
    posture: int
    mode: str
    seconds: float
    map_seconds: float
    problems: list[str] = field(default_factory=list)

    @property
    def size(self) -> int:
        return self.fmu.stat().st_size


def with_build_constants(text: str, posture: int, mode: str, where, robot: dict | None = None) -> str:
    """The slave script ``text`` with its build constants ``BUILD_POSTURE`` and ``BUILD_MODE`` set to
    ``posture`` and ``mode`` (the start values of its parameters) and, when ``robot`` is given (the DK
    FMU of a robot description: :func:`robot_constant`), ``BUILD_ROBOT``; ``where`` names it in the
    error when a constant is not there exactly once."""
    pairs = [(r"^BUILD_POSTURE = \d+$", f"BUILD_POSTURE = {int(posture):d}"),
             (r'^BUILD_MODE = "\w+"$', f'BUILD_MODE = "{mode}"')]
    if robot is not None:
        pairs.append((r"^BUILD_ROBOT = None$", "BUILD_ROBOT = " + repr(robot)))
    for pattern, value in pairs:
        text, n = re.subn(pattern, lambda _m: value, text, flags=re.MULTILINE)
        if n != 1:
            raise RuntimeError(f"{where}: expected one line matching {pattern!r}, found {n}")
    return text


def _stage_script(dest: Path, posture: int, mode: str, robot=None) -> Path:
    source = slave_script(DK_NAME)
    script = dest / source.name
    constant = robot_constant(robot, posture) if robot is not None else None
    script.write_text(with_build_constants(source.read_text(), posture, mode, source, constant))
    return script


def _stage_documentation(dest: Path, name: str = DK_NAME) -> Path:
    readme = slave_readme(name)
    doc = dest / "documentation"
    doc.mkdir()
    text = readme.read_text()
    shutil.copyfile(readme, doc / "index.md")
    (doc / "_main.html").write_text(
        f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{name}</title></head>\n"
        f"<body><pre>\n{html.escape(text)}</pre></body></html>\n")
    return doc


def _dk_maps(model, postures, resolution, map_files, rule, cache_dir, progress, log) -> tuple[list[int], dict]:
    maps: dict[int, Path] = {}
    for f in map_files:
        mt = MapTensor.load(f)            # raises MapTensorFileError naming the problem
        if mt.model.digest() != model.digest():
            raise ValueError(f"{f}: built for geometry {mt.model.name!r}; this FMU is the robot {model.name!r}")
        if mt.posture in maps:
            raise ValueError(f"{f}: a second map of posture {mt.posture}")
        maps[mt.posture] = Path(f)
    postures = [int(p) for p in postures] if postures else sorted(maps)
    if not postures:
        raise ValueError("no posture to embed")
    for p in postures:
        if not 1 <= p <= 8:
            raise ValueError(f"posture {p}: expected 1..8")
        if p not in maps:
            cached_map(model, p, rule, resolution_step(resolution), cache_dir, progress=progress, log=log)
            maps[p] = map_cache_path(cache_dir, p, resolution, rule, model)
    return postures, maps


def stage_maps(tmp: Path, maps: dict[int, Path]) -> dict[str, Path]:
    """The DK FMU's data files ``{"maps/posture<j>.npz": map file, "maps/manifest.json": ...}``: each map
    of ``maps`` ({posture: file}) and the manifest (size and SHA-256 of each) written into ``tmp``."""
    entries, data_files = [], {}
    for p in sorted(maps):
        data = maps[p].read_bytes()
        name = f"maps/posture{p}.npz"
        data_files[name] = maps[p]
        entries.append({"posture": p, "file": name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    manifest = tmp / "manifest.json"
    manifest.write_text(json.dumps({"model": DK_NAME, "maps": entries}, indent=1, sort_keys=True) + "\n")
    data_files["maps/manifest.json"] = manifest
    return data_files


def build_dk(out_dir="build", postures=(1,), resolution=None, map_files=(), mode: str = "default",
             rule: str = DEFAULT_RULE, cache_dir=None, check: bool = True, progress: bool | None = None,
             log=print, kernels: bool = True, robot=None, background: bool = False) -> BuildResult:
    """Build ``<out_dir>/RRRDirectKinematics.fmu`` (see the module docstring).

    ``robot``: a :class:`solver.robot.Robot` (a 3-RRR description, :func:`solver.robot.load_robot`), or
    None for the paper's robot: its geometry gives the maps, its home pose (or, in another posture, the
    nearest well-conditioned pose) the start values, and the FMU carries its description
    (``resources/robot.json``, ``robot.toml``) and digest (in the model description's ``description``).
    ``resolution``: the maps' node spacing (m, rad); None: the robot's (:attr:`Robot.resolution`), for
    the paper's robot :data:`DEFAULT_RESOLUTION`.

    ``postures``: postures to embed, the first one is the start value of the parameter ``posture``;
    ``map_files``: map files to embed (their postures are added; a posture given twice is an error);
    postures without a given map use the map cache ``cache_dir`` (default: the project's one map cache,
    ``solver.cache_dir("maps")``, moved by ``$RRR_DK_CACHE``); ``progress``: a map build's progress
    on stderr (None: the process default, :mod:`solver.progress`); ``kernels``: ship the compiled
    kernels (:mod:`cosim.fmus.kernels`); ``background``: once the C entry point's early compile has
    begun, this process lowers its own priority by :data:`BACKGROUND_NICE` for good (a build child of
    :func:`build_fmus`; not for a process that goes on with other work).
    """
    t0 = time.perf_counter()
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    if rule not in ORDERING_RULES:
        raise ValueError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
    if robot is not None and robot.kind != "3-RRR":
        raise ValueError(f"robot: {robot.source} describes a {robot.kind}; the DK FMU of this build is a 3-RRR's "
                         "(a 3-RPR: python build_fmu.py --manipulator 3rpr)")
    model = robot.model if robot is not None else Manipulator.paper()
    if resolution is None:
        resolution = robot.resolution if robot is not None else DEFAULT_RESOLUTION
    out_dir = Path(out_dir)
    cache_dir = None if cache_dir is None else Path(cache_dir)
    early = _early_compile(postures, mode, robot) if kernels else None   # the C entry point, beside the map
    if background and isinstance(early, EarlyCompile):
        lower_priority()                        # the compile began at ours: it now outranks the map and the rest
    try:
        t_map = time.perf_counter()
        postures, maps = _dk_maps(model, postures, resolution, map_files, rule, cache_dir, progress, log)
        map_seconds = time.perf_counter() - t_map
        report_maps(maps, log)
        if early is not None:
            early.finish()
        with tempfile.TemporaryDirectory(prefix="build_fmu_") as tmp:
            tmp = Path(tmp)
            script = _stage_script(tmp, postures[0], mode, robot)
            data_files = {**stage_maps(tmp, maps), **stage_robot(tmp, robot)}
            scenario = (warm_up(warm_up_scenario(DK_NAME, postures[0], mode, robot), seeds=DK_STORES)
                        if kernels else None)
            fmu = build_fmu(script, out_dir, project_packages=project_packages(), data_files=data_files,
                            documentation_dir=_stage_documentation(tmp), check=check, kernels=scenario)
    finally:
        if early is not None:
            early.stop()
    problems = validate(fmu) if check else []
    return BuildResult(fmu, maps, postures[0], mode, time.perf_counter() - t0, map_seconds, problems)


def _early_compile(postures, mode: str, robot):
    """The DK's C entry point compiling beside the map (:mod:`cosim.fmus.early_compile`), or None (nothing to
    begin, or postures the map step will refuse)."""
    if not postures or not all(1 <= int(p) <= 8 for p in postures):
        return None
    first = int(postures[0])                # the slave's imports, hence the bundle, do not depend on its constants
    return begin_early_compile(slave_script(DK_NAME), project_packages(), warm_up_scenario(DK_NAME, first, mode, robot),
                               seeds=DK_STORES)


# ---------------------------------------------------------------------- the plant and the controller
def build_slave(name: str, out_dir="build", check: bool = True, kernels: bool = True, robot=None) -> Path:
    """Build ``<out_dir>/<name>.fmu`` of the plant or the controller (see the module docstring);
    ``kernels``: ship the compiled kernels (:mod:`cosim.fmus.kernels`); ``robot``: a
    :class:`solver.robot.Robot` with ``[dynamics]`` (None: the paper's robot): its geometry, dynamics,
    start pose and reference circle become the slave's (``BUILD_ROBOT``,
    :func:`cosim.fmus.robot_build.robot_constant`)."""
    if name not in FMU_NAMES or name == DK_NAME:
        raise ValueError(f"name: expected one of {[n for n in FMU_NAMES if n != DK_NAME]}, got {name!r}")
    if robot is None:
        return build_fmu(slave_script(name), out_dir, project_packages=project_packages(), check=check,
                         kernels=warm_up(warm_up_scenario(name)) if kernels else None)
    constant = robot_constant(robot, robot.home_posture, loop=True)
    with tempfile.TemporaryDirectory(prefix="build_fmu_") as tmp:
        script = Path(tmp) / slave_script(name).name
        script.write_text(with_robot_constant(slave_script(name).read_text(), constant, slave_script(name)))
        return build_fmu(script, out_dir, project_packages=project_packages(), check=check,
                         data_files=stage_robot(Path(tmp), robot),
                         kernels=warm_up(robot_slave_scenario(name, constant)) if kernels else None)


# ---------------------------------------------------------------------- the warm-up of the shipped kernels
def warm_up_scenario(name: str, posture: int = 1, mode: str = "default", robot=None) -> Scenario:
    """The runs that compile the kernels FMU ``name`` ships: its reference run (:mod:`cosim.fmus.references`;
    the DK FMU's circle in ``posture``, in ``mode`` and a part of it in the other mode, or 10 steps from
    its start values when the circle leaves that posture's tool space).  For a ``robot``'s DK FMU, the
    circle is one about its start pose (:func:`robot_circle`)."""
    from . import references

    if robot is not None:
        h, n = references.REFERENCE["h"], references.REFERENCE["n"]
        modes = [MODES.index(mode), 1 - MODES.index(mode)]
        X, q = robot_circle(robot, posture, n)
        if q is None:
            return Scenario([Run(10, h, {"mode": m}) for m in modes])
        start = {"x0": X[0, 0], "y0": X[0, 1], "phi0": X[0, 2], "posture": posture}
        inputs = {f"q{j + 1}": q[:, j] for j in range(3)}
        return Scenario([Run(n, h, {**start, "mode": modes[0]}, inputs),
                         Run(n // 5, h, {**start, "mode": modes[1]}, {k: v[:n // 5] for k, v in inputs.items()})])
    if name != DK_NAME:
        inputs, start, _ = references.RUNS[name]
        t, signals = inputs()
        return Scenario([Run(references.N, references.H, dict(start()),
                             {k: v[:references.N] for k, v in signals.items()})])
    h, n = references.REFERENCE["h"], references.REFERENCE["n"]
    modes = [MODES.index(mode), 1 - MODES.index(mode)]
    try:
        q = references.circle_joints(n, posture)
    except RuntimeError:
        return Scenario([Run(10, h, {"mode": m}) for m in modes])
    X0 = references.circle_path(n)[0]
    start = {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": posture}
    inputs = {f"q{j + 1}": q[:, j] for j in range(3)}
    return Scenario([Run(n, h, {**start, "mode": modes[0]}, inputs),
                     Run(n // 5, h, {**start, "mode": modes[1]}, {k: v[:n // 5] for k, v in inputs.items()})])
