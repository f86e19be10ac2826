"""The closed loop's results: the time series (:class:`ClosedLoopResult`), its CSV and its plots.

A run's table has one row per communication point ``t_k`` and the columns :data:`COLUMNS`; each
column but ``time`` is an output of an instance (:data:`COLUMN_SOURCES`), read by the master at
``t_k`` (the plant's outputs before its step, the DK pose and the torque of the step from ``t_k``).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver import STATUS, wrap_angle

from .scenario import Scenario

__all__ = ["ClosedLoopResult", "COLUMNS", "COLUMN_SOURCES", "FLAG_COLUMNS", "write_csv", "plot_closed_loop"]

#: Result column -> the "instance.output" it records (None: the time).
COLUMN_SOURCES = {
    "time": None,
    **{f"q{i}": f"plant.q{i}" for i in (1, 2, 3)},
    **{f"dq{i}": f"plant.dq{i}" for i in (1, 2, 3)},
    **{f"tau{i}": f"controller.tau{i}" for i in (1, 2, 3)},
    **{v: f"dk.{v}" for v in ("x", "y", "phi")},
    **{f"{v}_true": f"plant.{v}_true" for v in ("x", "y", "phi")},
    "x_ref": "controller.x_ref", "y_ref": "controller.y_ref", "phi_ref": "controller.phi_ref_out",
    **{f"q{i}_ref": f"controller.q{i}_ref" for i in (1, 2, 3)},
    "dk_status": "dk.status", "region": "dk.region", "n_real": "dk.n_real",
    "near_border": "dk.near_border", "ambiguous": "dk.ambiguous",
    "certain": "dk.certain", "uncertain_since": "dk.uncertain_since",
}
#: Columns of :meth:`cosim.ClosedLoop.run`'s result, in order.
COLUMNS = tuple(COLUMN_SOURCES)
#: The columns of the DK's status outputs: its Integer and Boolean outputs and ``uncertain_since``
#: (``ClosedLoop.run(..., flags=False)`` omits them).
FLAG_COLUMNS = ("dk_status", "region", "n_real", "near_border", "ambiguous", "certain", "uncertain_since")


@dataclass
class ClosedLoopResult:
    """Time series of a closed-loop run (row ``k`` is time ``t0 + k h``) and its metrics.

    ``wall_seconds``: wall-clock time of the step loop (and of building the columns);
    ``cpu_seconds``: the process's CPU time over the same span (the same on an idle machine, and
    free of the time other processes took on a loaded one).
    """

    scenario: Scenario
    columns: dict
    wall_seconds: float
    cpu_seconds: float = float("nan")

    def __getitem__(self, key):
        return self.columns[key]

    @property
    def t(self) -> np.ndarray:
        return self.columns["time"]

    def joint_error(self) -> np.ndarray:
        """q - q_ref, wrapped, (n, 3) rad."""
        e = np.stack([self.columns[f"q{i}"] - self.columns[f"q{i}_ref"] for i in (1, 2, 3)], axis=1)
        return wrap_angle(e)

    def rms_joint_error(self, t_from: float = 0.5) -> float:
        """RMS over time and joints of the joint tracking error after ``t_from`` s, rad."""
        e = self.joint_error()[self.t >= t_from - 1e-12]
        return float(np.sqrt(np.mean(e * e)))

    def max_dk_error(self) -> float:
        """Largest |DK pose - true pose| (m or rad, phi wrapped) over the run."""
        d = np.stack([self.columns["x"] - self.columns["x_true"], self.columns["y"] - self.columns["y_true"],
                      wrap_angle(self.columns["phi"] - self.columns["phi_true"])], axis=1)
        return float(np.max(np.abs(d)))

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.scenario.t_end / self.wall_seconds

    def metrics(self) -> dict:
        status = self.columns.get("dk_status")                       # None: run without flags
        return {"rms_joint_error_after_0.5s": self.rms_joint_error(0.5), "max_dk_vs_true": self.max_dk_error(),
                "dk_status_nonzero": None if status is None else int(np.count_nonzero(status)),
                "wall_seconds": self.wall_seconds, "realtime_factor": self.realtime_factor}


def _cell(value) -> str:
    """A CSV cell: the shortest text that reads back as the same float64 (``repr``), integers as such."""
    v = float(value)
    return str(int(v)) if v.is_integer() and abs(v) < 2**53 else repr(v)


def write_csv(result: ClosedLoopResult, path) -> Path:
    """Write the result's columns to ``path`` (CSV, LF line ends, a header row).

    Every value is written as the shortest decimal that reads back as the same float64 (``time``
    is ``t0 + k h`` exactly as the master stepped); integer-valued cells (the DK's status, region,
    flags as 0/1, whole times) without a decimal point.  Returns the path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(result.columns)
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(names)
        for row in zip(*(result.columns[n] for n in names)):
            w.writerow([_cell(v) for v in row])
    return path


def plot_closed_loop(result: ClosedLoopResult, out_dir) -> list[Path]:
    """PNG plots of a run in ``out_dir``: pose vs reference (``closed_loop_pose.png``), joint errors and
    torques (``closed_loop_joints_torques.png``), the DK's status (``closed_loop_dk_status.png``).
    Returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, draw in (("closed_loop_pose.png", _plot_pose), ("closed_loop_joints_torques.png", _plot_joints),
                       ("closed_loop_dk_status.png", _plot_status)):
        fig = draw(plt, result)
        fig.tight_layout()
        paths.append(out / name)
        fig.savefig(paths[-1])
        plt.close(fig)
    return paths


def _plot_pose(plt, result: ClosedLoopResult):
    c, t, sc = result.columns, result.t, result.scenario
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), dpi=110)
    axes[0].plot(c["x_ref"], c["y_ref"], "k:", lw=1.5, label="reference")
    axes[0].plot(c["x"], c["y"], "-", color="tab:blue", lw=1.0, label="DK FMU pose")
    axes[0].plot(c["x_true"], c["y_true"], "--", color="tab:orange", lw=0.8, label="true pose (plant)")
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(fontsize=8)
    for key, col in (("x", "tab:blue"), ("y", "tab:green"), ("phi", "tab:red")):
        ref = c["phi_ref"] if key == "phi" else c[f"{key}_ref"]
        axes[1].plot(t, c[key] - ref, color=col, label=f"{key} - {key}_ref [{'rad' if key == 'phi' else 'm'}]")
    axes[1].set_xlabel("t [s]")
    axes[1].set_ylabel("pose error [m] or [rad]")
    axes[1].legend(fontsize=8)
    axes[1].set_title("pose error (DK pose - reference)", fontsize=9)
    fig.suptitle(f"Closed loop (Fig. 2): computed torque on the circle, h = {sc.h * 1e3:g} ms, {sc.order}",
                 fontsize=10)
    return fig


def _plot_joints(plt, result: ClosedLoopResult):
    c, t = result.columns, result.t
    e = result.joint_error()
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), dpi=110, sharex=True)
    for i in range(3):
        axes[0].plot(t, e[:, i], label=f"q{i + 1} - q{i + 1}_ref")
        axes[1].plot(t, c[f"tau{i + 1}"], label=f"tau{i + 1}")
    axes[0].set_ylabel("joint error [rad]")
    axes[0].set_yscale("symlog", linthresh=1e-6)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"RMS joint error after 0.5 s: {result.rms_joint_error(0.5):.3g} rad", fontsize=9)
    axes[1].set_ylabel("torque [N m]")
    axes[1].set_xlabel("t [s]")
    axes[1].legend(fontsize=8)
    return fig


def _plot_status(plt, result: ClosedLoopResult):
    c, t = result.columns, result.t
    fig, axes = plt.subplots(3, 1, figsize=(8, 5.5), dpi=110, sharex=True)
    axes[0].step(t, c["dk_status"], where="post")
    axes[0].set_yticks(sorted(STATUS))
    axes[0].set_yticklabels([STATUS[k] for k in sorted(STATUS)], fontsize=7)
    axes[0].set_ylabel("status")
    axes[0].set_title("DK FMU: status, region used, real solutions, flags", fontsize=9)
    axes[1].step(t, c["region"], where="post", label="region")
    axes[1].step(t, c["n_real"], where="post", label="n_real")
    axes[1].set_ylabel("number")
    axes[1].legend(fontsize=8)
    axes[2].step(t, c["certain"], where="post", label="certain")
    axes[2].step(t, c["near_border"] * 0.66, where="post", label="near_border (x0.66)")
    axes[2].step(t, c["ambiguous"] * 0.33, where="post", label="ambiguous (x0.33)")
    axes[2].set_yticks([0, 0.33, 0.66, 1])
    axes[2].set_ylabel("flag (0 false)")
    axes[2].legend(fontsize=8, loc="center right")
    axes[2].set_xlabel("t [s]")
    return fig
