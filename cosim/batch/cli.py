"""Batches of closed-loop co-simulations (Fig. 2) on dask: ``python -m cosim.batch``.

Sweeps over the fields of :class:`cosim.Scenario`; every run is one
:meth:`cosim.ClosedLoop.run` of the three FMUs through fmpy.  Results land in one table
(``batch.csv``, ``batch.parquet``), with ``batch_meta.json`` (FMU hashes, cluster, timing) and a
summary plot ``batch_summary.png``.  The command line, the config file, the table and running on a
multi-node dask cluster are described in docs/batch.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cosim.fmus.builds import parse_resolution
from cosim.fmus.fmu_set import build_fmus
from cosim.fmus.robot_build import loop_robot
from cosim.unit import exit_process

from .execution import default_workers, run_batch
from .sweep import BATCH_OPTIONS, ConfigError, expand, field_name, load_config, parse_sweep_arg, parse_value
from .table import as_float, plot_summary, scenario_columns, short, varying_columns, write_table
from .worker import STATE

__all__ = ["main", "main_and_exit"]

_EPILOG = """examples:
  python -m cosim.batch --sweep h=0.001,0.002 --sweep plant_mass_scale=0.8,1.0,1.2 --t-end 1.0
  python -m cosim.batch --config bench/sweep_example.toml [--out results/batch]
  python -m cosim.batch --config sweep.toml --scheduler tcp://10.0.0.5:8786
  python -m cosim.batch --sweep bandwidth=20:80:4 --set order=jacobi --dry-run

--sweep KEY=V1,V2,... is one dimension of the cartesian product (lo:hi:n gives n values from lo to
hi; center=[0.45,0.3],[0.5,0.3] for the centre); all --zip keys vary together.  Names are the
Scenario fields ('-' may replace '_')."""


def _build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m cosim.batch", description=__doc__,
                                 epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", help="TOML sweep file")
    ap.add_argument("--sweep", action="append", default=[], metavar="KEY=V1,V2", help="a product dimension")
    ap.add_argument("--zip", action="append", default=[], metavar="KEY=V1,V2", help="keys that vary together")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=V", help="a fixed Scenario field")
    ap.add_argument("--t-end", type=float, help="simulated time of every run, s")
    ap.add_argument("--robot", metavar="FILE", help="a robot description (TOML with [dynamics], docs/robots.md): "
                    "its FMUs and its reference circle as the base of every run")
    ap.add_argument("--fmu-dir", help="folder of the three FMUs (built there if missing; with --robot default "
                                      "build/robots/<name>-<digest>)")
    ap.add_argument("--resolution", help="DK map resolution if the DK FMU must be built, e.g. 40mm,6deg")
    ap.add_argument("--out", help="output folder (default results/batch)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--scheduler", help="address of an existing dask scheduler (tcp://host:port)")
    where.add_argument("--serial", action="store_true", help="run in this process, no dask")
    ap.add_argument("--workers", type=int, help="local cluster size (default: the cores)")
    ap.add_argument("--fmu-transfer", choices=("auto", "path", "bytes"),
                    help="how workers get the FMUs: path (a shared file system), bytes (sent with the "
                         "tasks, cached per node) or auto (bytes on a given --scheduler, else path; default)")
    ap.add_argument("--restart-workers", action="store_true", help="Client.restart() before the runs")
    ap.add_argument("--rms-from", type=float, help="start of the RMS window, s (default 0.5)")
    ap.add_argument("--plot-x", help="x axis of the summary plot (a swept field)")
    ap.add_argument("--no-plot", action="store_true", help="no batch_summary.png")
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                    help="a progress bar on stderr, also when it is not a terminal (default: on)")
    ap.add_argument("--dry-run", action="store_true", help="list the runs and stop")
    ap.add_argument("--strict", action="store_true", help="exit status 1 if a run failed")
    return ap


def _plan(args) -> tuple[dict, list[dict]]:
    cfg = load_config(args.config) if args.config else {"batch": {}, "base": {}, "sweep": {}, "cases": []}
    opts = dict(BATCH_OPTIONS)
    opts.update(cfg["batch"])
    for name in ("fmu_dir", "resolution", "out", "workers", "scheduler", "fmu_transfer", "plot_x", "rms_from"):
        v = getattr(args, name)
        if v is not None:
            opts[name] = v
    if args.serial:
        opts["scheduler"] = None
    robot = _robot(args.robot)
    if robot is not None and args.fmu_dir is None and "fmu_dir" not in cfg["batch"]:
        opts["fmu_dir"] = f"build/robots/{robot.name}-{robot.digest}"
    opts["robot"] = robot
    base = dict(_robot_base(robot), **cfg["base"])
    for item in args.set:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        base[field_name(k)] = parse_value(k, v)
    if args.t_end is not None:
        base["t_end"] = args.t_end
    sweep = {(field_name(k) if not isinstance(v, dict) else k): v for k, v in cfg["sweep"].items()}
    for item in args.sweep:
        name, values = parse_sweep_arg(item)
        _drop_key(sweep, name)
        sweep[name] = values
    if args.zip:
        group = {}
        for item in args.zip:
            name, values = parse_sweep_arg(item)
            _drop_key(sweep, name)
            group[name] = values
        sweep["--zip"] = group
    params = expand(base, sweep, cfg["cases"])
    opts["base"], opts["sweep"], opts["cases"] = base, sweep, cfg["cases"]
    return opts, params


def _robot(path):
    """The robot description of ``--robot`` (None without it), with the dynamics the loop needs; a bad one
    is a :class:`ConfigError` naming the file and the field."""
    from solver.robot import RobotDescriptionError

    try:
        return loop_robot(path, "the batch's closed loop (its plant and controller)")
    except RobotDescriptionError as exc:
        raise ConfigError(str(exc)) from None


def _robot_base(robot) -> dict:
    """The Scenario fields a robot sets (its home posture and reference circle); {} for none."""
    if robot is None:
        return {}
    from cosim.loop.scenario import robot_scenario

    sc = robot_scenario(robot)
    return {"posture": sc.posture, "center": tuple(sc.center), "radius": sc.radius, "phi": sc.phi}


def _drop_key(sweep: dict, name: str):
    for k in list(sweep):
        v = sweep[k]
        if k == name:
            del sweep[k]
        elif isinstance(v, dict) and name in v:
            raise ConfigError(f"{name!r} is part of the sweep group {k!r} of the config; sweep the group there")


def _parse_resolution(text):
    return None if text is None else parse_resolution(text)


def main(argv=None) -> int:
    """Command line (see the module docstring); returns the exit status."""
    args = _build_parser().parse_args(argv)
    try:
        opts, params = _plan(args)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not params:
        print("error: no run to do", file=sys.stderr)
        return 2
    if args.dry_run:
        keys = varying_columns([scenario_columns(p) for p in params]) or ["t_end"]
        print(f"{len(params)} runs; varying: {', '.join(keys)}")
        for i, p in enumerate(params):
            cols = scenario_columns(p)
            print(f"  {i:4d}  " + "  ".join(f"{k}={short(cols[k])}" for k in keys))
        return 0
    progress = True if args.progress is None else args.progress
    try:
        fmus = build_fmus(opts["fmu_dir"], resolution=_parse_resolution(opts["resolution"]), progress=progress,
                          robot=opts["robot"])
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    n_local = opts["workers"] or default_workers()
    where = "this process" if args.serial else (opts["scheduler"] or f"a local cluster of {n_local} processes")
    print(f"{len(params)} runs on {where}")
    result = run_batch(params, fmus, scheduler=opts["scheduler"], n_workers=opts["workers"], serial=args.serial,
                       fmu_transfer=opts["fmu_transfer"], rms_from=float(opts["rms_from"]), progress=progress,
                       restart_workers=args.restart_workers)
    result.meta.update(base=opts["base"], sweep=opts["sweep"], cases=opts["cases"], argv=sys.argv[1:] if argv is None
                       else list(argv), robot=None if opts["robot"] is None else opts["robot"].source)
    paths = write_table(result, opts["out"])
    if not args.no_plot:
        try:
            paths.append(plot_summary(result, Path(opts["out"]) / "batch_summary.png", x=opts["plot_x"]))
        except ConfigError as exc:
            print(f"warning: no plot: {exc}", file=sys.stderr)
    for p in paths:
        print(f"wrote {p}")
    ok = [r for r in result.rows if r["status"] == "ok"]
    print(f"{len(ok)}/{len(result.rows)} runs ok, {result.n_failed} failed, {result.meta['wall_seconds']:.1f} s wall")
    failed = [r for r in result.rows if r["status"] != "ok"]
    for r in failed[:10]:
        print(f"  run {r['run']} failed: {r['error'][:300]}")
    if len(failed) > 10:
        print(f"  ... and {len(failed) - 10} more (see the table)")
    if ok:
        rms = np.array([as_float(r["rms_joint_error"]) for r in ok])
        print(f"RMS joint error after {opts['rms_from']:g} s: min {np.nanmin(rms):.3e}, max {np.nanmax(rms):.3e} rad"
              if np.isfinite(rms).any() else "RMS joint error: no sample in the window")
    if result.meta.get("interrupted"):
        return 130
    return 1 if (args.strict and result.n_failed) else 0


def main_and_exit():
    """``python -m cosim.batch``: :func:`main`, then exit (without the FMU libraries' finalizers
    when this process loaded FMUs, ``--serial``: a known issue of pythonfmu 0.7)."""
    code = main()
    if STATE["created"]:
        exit_process(code)
    sys.exit(code)
