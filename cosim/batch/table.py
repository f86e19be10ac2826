"""The batch's result table: its columns, ``batch.csv`` / ``batch.parquet`` / ``batch_meta.json``, the plot.

One row per run, in run order: ``run``, ``status`` (``ok``/``failed``), ``error`` (exception type
and text, plus the messages the FMUs logged during the run, e.g. why a step was refused), the
scenario (every field; ``center`` as ``center_x``, ``center_y``), the tracking metrics
(``rms_joint_error`` after ``rms_from`` s, ``max_joint_error``, ``max_dk_vs_true`` = max |DK pose -
true pose|, ``dk_branch_errors`` = steps where they differ by more than 1e-6, ``dk_status_<name>``
counts of the DK FMU's status), timing (``wall_seconds`` of the task on the worker =
``load_seconds`` + ``init_seconds`` + ``sim_seconds`` + metrics, ``realtime_factor``) and where it
ran (``worker``, ``host``, ``pid``, ``loop_runs`` = runs served by that FMU set so far).  The CSV
writes floats with 17 significant digits (round trip exact).
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver import STATUS

from .sweep import DEFAULTS, SCENARIO_FIELDS, STR_FIELDS, field_name

__all__ = ["COLUMNS", "METRIC_COLUMNS", "TIMING_COLUMNS", "WHERE_COLUMNS", "STRING_COLUMNS", "INT_COLUMNS",
           "BatchResult", "scenario_columns", "write_table", "plot_summary", "varying_columns", "as_float", "short"]


def scenario_columns(params: dict) -> dict:
    """The scenario part of a row: every field (``center`` as ``center_x``, ``center_y``)."""
    cols = {}
    for name in SCENARIO_FIELDS:
        v = params.get(name, DEFAULTS[name])
        if name == "center":
            try:
                cols["center_x"], cols["center_y"] = float(v[0]), float(v[1])
            except Exception:  # noqa: BLE001
                cols["center_x"] = cols["center_y"] = float("nan")
        else:
            cols[name] = v
    return cols


METRIC_COLUMNS = ("rms_joint_error", "max_joint_error", "max_dk_vs_true", "dk_branch_errors",
                  *(f"dk_status_{s}" for s in STATUS.values()), "n_steps", "rms_from")
TIMING_COLUMNS = ("wall_seconds", "load_seconds", "init_seconds", "sim_seconds", "realtime_factor")
WHERE_COLUMNS = ("worker", "host", "pid", "loop_runs")
COLUMNS = ("run", "status", "error", *(c for c in scenario_columns({})), *METRIC_COLUMNS, *TIMING_COLUMNS,
           *WHERE_COLUMNS)
#: Columns written as strings and as integers to Parquet (the others as floats).
STRING_COLUMNS = frozenset(("error", "status", "worker", "host", *STR_FIELDS))
INT_COLUMNS = {"dk_branch_errors", "n_steps", "pid", "loop_runs", *(f"dk_status_{s}" for s in STATUS.values())}


@dataclass
class BatchResult:
    """Rows (one per run, in run order) and facts about the batch."""

    rows: list
    meta: dict

    @property
    def n_failed(self) -> int:
        return sum(r["status"] != "ok" for r in self.rows)

    def column(self, name) -> list:
        return [r[name] for r in self.rows]


def _csv_cell(v):
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return v


def write_table(result: BatchResult, out_dir) -> list[Path]:
    """``batch.csv`` (+ ``batch.parquet`` with pyarrow) and ``batch_meta.json`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "batch.csv"]
    with open(paths[0], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in result.rows:
            w.writerow([_csv_cell(r.get(c)) for c in COLUMNS])
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        pa = None
    if pa is not None:
        cols = {}
        for c in COLUMNS:
            vals = [r.get(c) for r in result.rows]
            if c in INT_COLUMNS:
                cols[c] = pa.array([None if v is None else int(v) for v in vals], type=pa.int64())
            elif c in STRING_COLUMNS:
                cols[c] = pa.array([None if v is None else str(v) for v in vals], type=pa.string())
            elif c == "run":
                cols[c] = pa.array(vals, type=pa.int64())
            else:
                cols[c] = pa.array([None if v is None else as_float(v) for v in vals], type=pa.float64())
        paths.append(out / "batch.parquet")
        pq.write_table(pa.table(cols), paths[-1])
    paths.append(out / "batch_meta.json")
    paths[-1].write_text(json.dumps(result.meta, indent=2, default=str) + "\n")
    return paths


def as_float(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def varying_columns(rows) -> list[str]:
    keys = [k for k in scenario_columns({}) if k != "run"]
    out = []
    for k in keys:
        vals = {repr(r.get(k)) for r in rows}
        if len(vals) > 1:
            out.append(k)
    return out


#: The summary plot's panels: (metric column, title, y label).
_PANELS = (("rms_joint_error", "RMS joint error after {rms_from:g} s", "RMS joint error [rad]"),
           ("max_dk_vs_true", "max |DK pose - true pose|", "max error [m] or [rad]"))


def _plot_group(axes, grows, x, label, plotted, failed_labelled) -> None:
    """One line per panel for the runs ``grows`` of one combination; failed runs as red crosses."""
    ok = [r for r in grows if r["status"] == "ok"]
    xs = [r[x] if x else r["run"] for r in ok]
    order = np.argsort(np.asarray(xs, float), kind="stable") if xs else []
    for k, (ax, (metric, _, _)) in enumerate(zip(axes, _PANELS)):
        ys = np.array([as_float(ok[j][metric]) for j in order])
        xv = np.array([as_float(xs[j]) for j in order])
        plotted[k] |= bool(np.isfinite(ys).any())
        if len(ys):
            ax.plot(xv, np.maximum(ys, 1e-18), "o-", ms=4, lw=1, label=label)
    bad = [as_float(r[x] if x else r["run"]) for r in grows if r["status"] != "ok"]
    if bad:
        for ax in axes:
            ax.plot(bad, [0.03] * len(bad), "x", color="tab:red", ms=7, transform=ax.get_xaxis_transform(),
                    label=None if failed_labelled[0] else "failed run")
        failed_labelled[0] = True


def _summary_axis(x: str | None, varying: list) -> str | None:
    """The swept parameter on the x axis: ``x`` (a field name or ``center``) or the first numeric one."""
    if x is not None:
        return "center_x" if x == "center" else field_name(x) if x not in ("center_x", "center_y") else x
    numeric = [k for k in varying if k not in STR_FIELDS]
    return numeric[0] if numeric else None


def plot_summary(result: BatchResult, path, x: str | None = None, max_lines: int = 16) -> Path | None:
    """PNG: RMS joint error and max |DK - true| vs one swept parameter, a line per other combination.

    ``x``: the swept parameter on the x axis (default the first numeric one that varies; none: the
    run number); ``max_lines``: combinations named in the legend at most.  Returns ``path``.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result.rows
    varying = varying_columns(rows)
    x = _summary_axis(x, varying)
    others = [k for k in varying if k != x]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), dpi=110)
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in others), []).append(r)
    n_failed = sum(r["status"] != "ok" for r in rows)
    plotted, failed_labelled = [False, False], [False]
    for gi, (gkey, grows) in enumerate(sorted(groups.items(), key=lambda kv: repr(kv[0]))):
        label = ", ".join(f"{k}={short(v)}" for k, v in zip(others, gkey)) or "all runs"
        _plot_group(axes, grows, x, label if gi < max_lines else None, plotted, failed_labelled)
    for ax, any_data, (_, title, ylabel) in zip(axes, plotted, _PANELS):
        ax.set_title(title.format(rms_from=result.meta.get("rms_from", 0.5)), fontsize=10)
        ax.set_xlabel(x or "run")
        ax.set_ylabel(ylabel)
        if any_data:
            ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"batch: {len(rows)} runs, {n_failed} failed (red x at the bottom: a failed run)", fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    if len(groups) > 1 or n_failed:
        ncol = 2 if len(labels) > 3 else max(len(labels), 1)
        extra = 0.2 * math.ceil(len(labels) / ncol) + 0.3
        fig.set_size_inches(12, 4.8 + extra)
        fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7, frameon=False)
        fig.tight_layout(rect=(0, extra / (4.8 + extra), 1, 1))
    else:
        fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def short(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)
