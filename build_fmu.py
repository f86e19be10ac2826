"""Build the direct-kinematics FMU: map tensor(s) -> build/RRRDirectKinematics.fmu, then validate it.

    python build_fmu.py [--out build] [--posture 1 [2 ...]] [--resolution 10mm,2deg]
                        [--map FILE [FILE ...]] [--mode default|paper] [--rule real-phi]
    python build_fmu.py --write-reference      # regenerate fmu_src/reference/RRRDirectKinematics.csv

1. The map tensor of each posture (procedure 1) is taken from ``--map`` or from the cache
   ``<out>/maps/dk_posture<j>_<rule>_<mm>mm_<deg>deg_<geometry>_<code>.npz`` (``<code>``: digest of
   the solver sources that decide the labels, so a map made by older code is never reused); a
   missing or unusable cache entry is built (``MapTensor.build``, the grid of ``python -m solver
   build``) and saved there, so a rebuild with the same options and code reuses it.
2. The FMU is packaged by ``fmu_src.fmi_build.build_fmu``: the slave ``fmu_src/RRRDirectKinematics.py``
   (its ``BUILD_POSTURE``/``BUILD_MODE`` constants set to ``--posture``/``--mode``: the start values
   of the parameters ``posture`` and ``mode``), the ``solver`` package, the maps as
   ``resources/maps/posture<j>.npz`` with ``resources/maps/manifest.json`` (size and SHA-256 of each,
   checked at instantiation), and the readme as ``documentation/``.
3. The FMU is validated (``fmu_src.fmi_build.validate``); its size and the result are printed.

Same options and the same map files give a byte-identical FMU.  ``--resolution`` accepts
``"10mm,2deg"``, ``"0.04m 6deg"``, ``"1cm,0.035rad"`` or two bare numbers (mm, deg): ``40 6``.

``--write-reference`` builds the reference configuration (:data:`REFERENCE`: posture 1, default mode,
40 mm / 6 deg map) into ``<out>/reference/``, runs the paper's circle (``solver.circle_path(1000)``
mapped to joints by ``solver.ik`` in posture 1, q[k] applied at t = k*h) through it with
``fmpy.simulate_fmu`` and writes the result to ``fmu_src/reference/RRRDirectKinematics.csv``, which
``tests/test_fmu_dk.py`` compares with.
"""
from __future__ import annotations

import argparse
import hashlib
import html
import json
import re
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import solver  # noqa: E402  (import before running FMUs: the FMU then uses this copy, see fmi_build)
from solver import DEFAULT_RULE, ORDERING_RULES, Manipulator, circle_path, ik  # noqa: E402
from solver.maptensor import MapTensor, MapTensorFileError, default_bounds  # noqa: E402

SLAVE = ROOT / "fmu_src" / "RRRDirectKinematics.py"
README = ROOT / "fmu_src" / "RRRDirectKinematics.md"
REFERENCE_CSV = ROOT / "fmu_src" / "reference" / "RRRDirectKinematics.csv"
MODEL_NAME = "RRRDirectKinematics"
MODES = ("default", "paper")
#: Default node spacing of the map (the map tensor's default): 10 mm in x and y, 2 degrees in phi.
DEFAULT_RESOLUTION = (0.01, float(np.deg2rad(2.0)))
#: The configuration of the reference run (coarse map: quick to build in the tests).
REFERENCE = {"posture": 1, "mode": "default", "resolution": (0.04, float(np.deg2rad(6.0))),
             "rule": DEFAULT_RULE, "n": 1000, "h": 1e-3}
#: Output columns of the reference CSV (after time and the inputs q1..q3).
OUTPUTS = ("x", "y", "phi", "region", "near_border", "n_real", "ambiguous", "status", "cond")

_LEN_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_ANG_UNITS = {"rad": 1.0, "deg": float(np.pi / 180.0)}


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


def map_grid(model: Manipulator, resolution) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Bounds and shape of the map grid at ``resolution`` (the grid of ``python -m solver build``)."""
    step = (resolution[0], resolution[0], resolution[1])
    bounds = default_bounds(model, step)
    span = bounds[:, 1] - bounds[:, 0]
    shape = (int(round(span[0] / step[0])) + 1, int(round(span[1] / step[1])) + 1,
             int(round(span[2] / step[2])))
    return bounds, shape


def _fmt_num(v: float) -> str:
    return f"{v:.6g}".replace(".", "p")


#: The solver sources that decide a map's labels (geometry, IK, DK and its numbering, procedure 1).
LABELLING_SOURCES = ("manipulator.py", "kinematics.py", "_dk_kernel.py", "maptensor.py", "_map_kernel.py",
                     "_checks.py")


def labelling_digest() -> str:
    """SHA-256 (12 hex digits) of :data:`LABELLING_SOURCES`: a cached map built by other code is not reused."""
    h = hashlib.sha256()
    for name in LABELLING_SOURCES:
        h.update(name.encode() + b"\0" + (ROOT / "solver" / name).read_bytes())
    return h.hexdigest()[:12]


def map_cache_path(cache_dir, posture: int, resolution, rule: str, model: Manipulator) -> Path:
    """Cache file of a map: keyed by posture, ordering rule, resolution, geometry and labelling code."""
    mm, deg = resolution[0] * 1e3, float(np.rad2deg(resolution[1]))
    return Path(cache_dir) / (f"dk_posture{posture}_{rule}_{_fmt_num(mm)}mm_{_fmt_num(deg)}deg_"
                              f"{model.digest()[:8]}_{labelling_digest()[:8]}.npz")


def cached_map(cache_dir, posture: int, resolution, rule: str = DEFAULT_RULE, *, model: Manipulator | None = None,
               progress: bool = False, log=print) -> tuple[Path, MapTensor, bool]:
    """The map of ``posture`` at ``resolution``: from the cache if usable, else built and saved.

    Returns ``(path, map, built)``.
    """
    model = Manipulator.paper() if model is None else model
    path = map_cache_path(cache_dir, posture, resolution, rule, model)
    bounds, shape = map_grid(model, resolution)
    if path.is_file():
        try:
            mt = MapTensor.load(path, model=model, posture=posture)
            if mt.rule == rule and tuple(mt.shape) == shape and np.allclose(mt.bounds, bounds, rtol=0, atol=1e-12):
                return path, mt, False
            log(f"{path}: cached map does not match the requested grid; rebuilding")
        except MapTensorFileError as exc:
            log(f"{path}: unusable cached map ({exc}); rebuilding")
    mt = MapTensor.build(model, posture, bounds=bounds, shape=shape, rule=rule, progress=progress)
    mt.save(path)
    return path, mt, True


# ---------------------------------------------------------------------- the FMU
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


def _stage_script(dest: Path, posture: int, mode: str) -> Path:
    text = SLAVE.read_text()
    for pattern, value in ((r"^BUILD_POSTURE = \d+$", f"BUILD_POSTURE = {posture:d}"),
                           (r'^BUILD_MODE = "\w+"$', f'BUILD_MODE = "{mode}"')):
        text, n = re.subn(pattern, value, text, flags=re.MULTILINE)
        if n != 1:
            raise RuntimeError(f"{SLAVE}: expected one line matching {pattern!r}, found {n}")
    script = dest / SLAVE.name
    script.write_text(text)
    return script


def _stage_documentation(dest: Path) -> Path:
    doc = dest / "documentation"
    doc.mkdir()
    text = README.read_text()
    shutil.copyfile(README, doc / "index.md")
    (doc / "_main.html").write_text(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>RRRDirectKinematics</title></head>\n"
        f"<body><pre>\n{html.escape(text)}</pre></body></html>\n")
    return doc


def build(out_dir="build", postures=(1,), resolution=DEFAULT_RESOLUTION, map_files=(), mode: str = "default",
          rule: str = DEFAULT_RULE, cache_dir=None, check: bool = True, progress: bool = False,
          log=print) -> BuildResult:
    """Build ``<out_dir>/RRRDirectKinematics.fmu`` (see the module docstring).

    ``postures``: postures to embed, the first one is the start value of the parameter ``posture``;
    ``map_files``: map files to embed (their postures are added; a posture given twice is an error);
    postures without a given map use the cache ``cache_dir`` (default ``<out_dir>/maps``).
    """
    from fmu_src.fmi_build import build_fmu, validate

    t0 = time.perf_counter()
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    if rule not in ORDERING_RULES:
        raise ValueError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
    model = Manipulator.paper()
    out_dir = Path(out_dir)
    cache_dir = out_dir / "maps" if cache_dir is None else Path(cache_dir)
    maps: dict[int, Path] = {}
    for f in map_files:
        mt = MapTensor.load(f)            # raises MapTensorFileError naming the problem
        if mt.model.digest() != model.digest():
            raise ValueError(f"{f}: built for geometry {mt.model.name!r}; this FMU is the paper's 3-RRR (Table 1)")
        if mt.posture in maps:
            raise ValueError(f"{f}: a second map of posture {mt.posture}")
        maps[mt.posture] = Path(f)
    postures = [int(p) for p in postures] if postures else sorted(maps)
    if not postures:
        raise ValueError("no posture to embed")
    t_map = time.perf_counter()
    for p in postures:
        if not 1 <= p <= 8:
            raise ValueError(f"posture {p}: expected 1..8")
        if p not in maps:
            path, mt, built = cached_map(cache_dir, p, resolution, rule, model=model, progress=progress, log=log)
            log(f"map posture {p}: {'built' if built else 'reused'} {path} "
                f"({mt.shape[0]} x {mt.shape[1]} x {mt.shape[2]} nodes, {path.stat().st_size / 1e3:.0f} kB)")
            maps[p] = path
    map_seconds = time.perf_counter() - t_map
    with tempfile.TemporaryDirectory(prefix="build_fmu_") as tmp:
        tmp = Path(tmp)
        script = _stage_script(tmp, postures[0], mode)
        entries = []
        data_files = {}
        for p in sorted(maps):
            data = maps[p].read_bytes()
            name = f"maps/posture{p}.npz"
            data_files[name] = maps[p]
            entries.append({"posture": p, "file": name, "bytes": len(data),
                            "sha256": hashlib.sha256(data).hexdigest()})
        manifest = tmp / "manifest.json"
        manifest.write_text(json.dumps({"model": MODEL_NAME, "maps": entries}, indent=1, sort_keys=True) + "\n")
        data_files["maps/manifest.json"] = manifest
        fmu = build_fmu(script, out_dir, project_packages=(ROOT / "solver",), data_files=data_files,
                        documentation_dir=_stage_documentation(tmp), check=check)
    problems = validate(fmu) if check else []
    return BuildResult(fmu, maps, postures[0], mode, time.perf_counter() - t0, map_seconds, problems)


# ---------------------------------------------------------------------- the reference run
def circle_joints(n: int = 1000, posture: int = 1) -> np.ndarray:
    """The paper's circle (``solver.circle_path(n)``) mapped to joints by ``solver.ik`` in ``posture``."""
    q = ik(Manipulator.paper(), circle_path(n), posture)
    if np.isnan(q).any():
        raise RuntimeError("the circle leaves the tool space")
    return q


def run_circle(fmu, n: int = REFERENCE["n"], h: float = REFERENCE["h"], posture: int = 1):
    """The circle through ``fmu`` with ``fmu_src.fmi_build.simulate`` (fmpy.simulate_fmu).

    q[k] is the input on [k*h, (k+1)*h]; result row 0 (t = 0) is the initial pose, row k + 1 the pose
    for q[k].  The initial pose is the first point of the circle.  Returns fmpy's structured array.
    """
    from fmu_src.fmi_build import input_table, simulate

    q = circle_joints(n, posture)
    X0 = circle_path(n)[0]
    t = np.arange(n) * h
    table = input_table(t, q1=q[:, 0], q2=q[:, 1], q3=q[:, 2])
    return simulate(fmu, stop_time=n * h, step_size=h, inputs=table,
                    start_values={"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": posture},
                    outputs=["q1", "q2", "q3", *OUTPUTS])


def reference_header(result: BuildResult) -> list[str]:
    mt = MapTensor.load(result.maps[result.posture])
    return [
        "RRRDirectKinematics reference run: the paper's circle, solver.circle_path(1000) -> solver.ik posture 1,",
        "q[k] applied at t = k*h through fmpy.simulate_fmu; x0, y0, phi0 = circle_path(1000)[0].",
        "Row 0 is the initial pose; row k+1 the pose for q[k]; q1..q3 are the FMU's inputs when the row was sampled.",
        f"map: posture {mt.posture}, rule {mt.rule}, shape {list(mt.shape)}, "
        f"step {mt.step[0] * 1e3:g} mm {np.rad2deg(mt.step[2]):g} deg, labels_sha256 {mt.checksum()}",
        f"mode: {result.mode}; h = {REFERENCE['h']!r} s; n = {REFERENCE['n']}",
        "regenerate: python build_fmu.py --write-reference",
    ]


def write_reference_csv(path, rows, header_lines) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = ["time", "q1", "q2", "q3", *OUTPUTS]
    lines = [f"# {h}" for h in header_lines] + [",".join(names)]
    for row in rows:
        cells = []
        for name in names:
            v = row[name]
            cells.append(repr(float(v)) if isinstance(v, (float, np.floating)) else str(int(v)))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def read_reference_csv(path=REFERENCE_CSV) -> tuple[list[str], np.ndarray]:
    """``(header lines, structured array)`` of a reference CSV (Boolean columns as 0/1 integers)."""
    lines = Path(path).read_text().splitlines()
    header = [ln[2:] for ln in lines if ln.startswith("# ")]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    names = body[0].split(",")
    ints = {"region", "near_border", "n_real", "ambiguous", "status"}
    dtype = [(n, np.int64 if n in ints else np.float64) for n in names]
    data = np.array([tuple((int if n in ints else float)(c) for n, c in zip(names, ln.split(",")))
                     for ln in body[1:]], dtype=dtype)
    return header, data


def write_reference(out_dir="build", csv_path=REFERENCE_CSV, log=print) -> Path:
    """Build the reference configuration into ``<out_dir>/reference`` and write the reference CSV."""
    result = build(Path(out_dir) / "reference", postures=(REFERENCE["posture"],),
                   resolution=REFERENCE["resolution"], mode=REFERENCE["mode"], rule=REFERENCE["rule"],
                   cache_dir=Path(out_dir) / "maps", log=log)
    if result.problems:
        raise RuntimeError("reference FMU does not validate: " + "; ".join(result.problems))
    rows = run_circle(result.fmu)
    return write_reference_csv(csv_path, rows, reference_header(result))


# ---------------------------------------------------------------------- command line
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "build"), help="output folder (default build/)")
    ap.add_argument("--posture", type=int, nargs="+", default=None,
                    help="posture(s) 1..8 to embed; the first is the parameter's start value (default 1)")
    ap.add_argument("--resolution", nargs="+", default=None,
                    help="map node spacing: '10mm,2deg' (default), '0.04m 6deg' or two numbers in mm and deg")
    ap.add_argument("--map", nargs="+", default=(), metavar="FILE", help="embed these map files (no rebuild)")
    ap.add_argument("--mode", choices=MODES, default="default", help="start value of the parameter 'mode'")
    ap.add_argument("--rule", choices=sorted(ORDERING_RULES), default=DEFAULT_RULE,
                    help="ordering rule of maps built here")
    ap.add_argument("--write-reference", action="store_true",
                    help=f"build the reference configuration and rewrite {REFERENCE_CSV.relative_to(ROOT)}")
    args = ap.parse_args(argv)
    try:
        if args.write_reference:
            t0 = time.perf_counter()
            path = write_reference(args.out)
            print(f"{path}: {len(path.read_text().splitlines())} lines in {time.perf_counter() - t0:.1f} s")
            return 0
        resolution = DEFAULT_RESOLUTION if args.resolution is None else parse_resolution(args.resolution)
        postures = args.posture if args.posture is not None else ([] if args.map else [1])
        result = build(args.out, postures=postures, resolution=resolution, map_files=args.map, mode=args.mode,
                       rule=args.rule, progress=sys.stderr.isatty())
    except (ValueError, MapTensorFileError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{result.fmu}: {result.size / 1e6:.3f} MB ({result.size:,} bytes), postures {sorted(result.maps)} "
          f"(start {result.posture}), mode {result.mode}; built in {result.seconds:.1f} s "
          f"(maps {result.map_seconds:.1f} s)")
    if result.problems:
        print("validation: FAILED\n  " + "\n  ".join(result.problems))
        return 1
    print("validation: OK (fmpy.validation + fmu_src.fmi_build.validate report nothing)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
