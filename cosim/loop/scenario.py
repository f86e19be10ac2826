"""A closed-loop run's parameters: :class:`Scenario` (the FMUs' parameters and the master's)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver import PAPER_CIRCLE
from solver.checks import Bound, check_number

__all__ = ["ORDERS", "Scenario", "robot_scenario"]

#: The master algorithms of :meth:`cosim.ClosedLoop.run` (see :mod:`cosim.loop.master`).
ORDERS = ("gauss-seidel", "jacobi", "omsimulator")


#: The scalar fields and what each may be (:func:`solver.checks.check_number`).
BOUNDS = {"t_end": Bound(unit="s"), "h": Bound(unit="s"), "bandwidth": Bound(unit="rad/s"), "damping": Bound(),
          "plant_mass_scale": Bound(), "controller_mass_scale": Bound(), "period": Bound(unit="s"),
          "radius": Bound(unit="m"), "ramp_time": Bound(open=False, unit="s"),
          "plant_substeps": Bound(integer=True)}


@dataclass(frozen=True)
class Scenario:
    """Everything a closed-loop run depends on (parameters of the three FMUs and of the master).

    The field annotations are the fields' types (the batch's sweep parsing reads them).

    Attributes
    ----------
    t_end : float
        Simulated time, s.
    h : float
        Communication (and control) step, s.
    order : {"gauss-seidel", "jacobi", "omsimulator"}
        Master algorithm (see :mod:`cosim.loop.master`).
    posture : int
        Posture of the robot, its DK map and its reference.
    bandwidth, damping : float
        Requested closed-loop error dynamics (rad/s, 1).
    plant_mass_scale, controller_mass_scale : float
        Factors on the default masses of the plant (the real robot) and of the controller's model.
    tracker_mode : {"default", "paper"}
        Mode of the DK FMU's tracker.
    period, ramp_time : float
        Circle: seconds per revolution at cruise speed, duration of the start from rest.
    center, radius, phi : circle geometry (m, m, rad); default :data:`solver.PAPER_CIRCLE`.
    plant_substeps : int
        RK4 steps of the plant per communication step.
    """

    t_end: float = 2.5
    h: float = 1e-3
    order: str = "gauss-seidel"
    posture: int = 1
    bandwidth: float = 50.0
    damping: float = 1.0
    plant_mass_scale: float = 1.0
    controller_mass_scale: float = 1.0
    tracker_mode: str = "default"
    period: float = 2.0
    ramp_time: float = 0.5
    center: tuple[float, float] = field(default=tuple(PAPER_CIRCLE["center"]))
    radius: float = PAPER_CIRCLE["radius"]
    phi: float = PAPER_CIRCLE["phi"]
    plant_substeps: int = 1

    def __post_init__(self):
        if self.order not in ORDERS:
            raise ValueError(f"order: expected one of {ORDERS}, got {self.order!r}")
        if self.tracker_mode not in ("default", "paper"):
            raise ValueError(f"tracker_mode: expected 'default' or 'paper', got {self.tracker_mode!r}")
        for key, bound in BOUNDS.items():
            check_number(key, getattr(self, key), bound, ValueError)
        if self.h > self.t_end:
            raise ValueError(f"h: expected a step no longer than t_end = {self.t_end}, got {self.h}")

    @property
    def n_steps(self) -> int:
        return int(round(self.t_end / self.h))

    @property
    def start_pose(self) -> np.ndarray:
        """The circle's first point (polar angle 0), m, m, rad."""
        return np.array([self.center[0] + self.radius, self.center[1], self.phi])


def robot_scenario(robot, **changes) -> Scenario:
    """The default scenario of a robot description (:class:`solver.robot.Robot`; None: the paper's,
    :class:`Scenario`'s defaults): its home posture and reference circle (:func:`solver.robot.default_circle`:
    about its home pose, the orientation held), the other fields as ``changes`` or the defaults."""
    if robot is None:
        return Scenario(**changes)
    from solver.robot import default_circle

    circle = default_circle(robot)
    fields = {"posture": robot.home_posture, "center": tuple(circle["center"]), "radius": circle["radius"],
              "phi": circle["phi"]}
    return Scenario(**{**fields, **changes})
