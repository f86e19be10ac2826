"""The variable-table rows the two DK FMUs share (``RRRDirectKinematics``, ``RPRDirectKinematics``).

Their outputs and sensor options are the same; only the joint inputs, their unit and the initial
pose differ.  Each slave's ``VARIABLES`` lists its own rows and these.
"""
from __future__ import annotations

from fmu_src.table_slave import Var
from solver.start import START_TOLERANCE

#: The value of ``x_bound``, ``y_bound``, ``phi_bound`` when the pose is not certain (no bound): the
#: tracker's inf is not a value every FMI tool (nor this slave's output check) accepts.
NO_BOUND = -1.0

__all__ = ["initial_pose", "sensor_parameters", "dk_outputs", "bound_rows", "NO_BOUND"]


def initial_pose(pose, point: str = "the platform centre") -> tuple:
    """The table rows of the initial pose ``x0, y0, phi0`` (start values ``pose``, m, m, rad)."""
    return (
        Var("x0", "Real", "parameter", "fixed", start=float(pose[0]), unit="m",
            description=f"initial pose: x of {point}"),
        Var("y0", "Real", "parameter", "fixed", start=float(pose[1]), unit="m",
            description=f"initial pose: y of {point}"),
        Var("phi0", "Real", "parameter", "fixed", start=float(pose[2]), unit="rad",
            description="initial pose: platform orientation"),
    )


def sensor_parameters(joint_unit: str) -> tuple:
    """The table rows of the sensor options (joint_tolerance in ``joint_unit``, the two speed bounds)."""
    return (
        Var("joint_tolerance", "Real", "parameter", "fixed", start=0.0, unit=joint_unit, min=0.0,
            description="bound on the joints' measurement error (encoders: about 3 noise sigmas plus half a "
                        "step); 0: exact joints.  certain is then a proof for every joint path within it"),
        Var("speed_bound_linear", "Real", "parameter", "fixed", start=0.0, unit="m/s", min=0.0,
            description="with joint_tolerance: bound on the platform's speed, for re-acquisition and the "
                        "speed gate; 0: none (then also speed_bound_angular = 0)"),
        Var("speed_bound_angular", "Real", "parameter", "fixed", start=0.0, unit="rad/s", min=0.0,
            description="with joint_tolerance: bound on the platform's angular speed; 0: none"),
    )


def dk_outputs(deps: tuple, point: str = "platform centre", start_tolerance=START_TOLERANCE,
               geometry_tolerance: float = 0.0) -> tuple:
    """The table rows of the DK outputs, each depending on the joint inputs ``deps``, then
    ``stuck_after`` and :func:`bound_rows` (added last: the other rows keep their value references);
    ``start_tolerance``: the start values (m, m, rad) of the start tolerance parameters;
    ``geometry_tolerance``: the start value (m) of that parameter (the robot description's)."""
    return (
        Var("x", "Real", "output", unit="m", depends_on=deps, description=f"{point} x"),
        Var("y", "Real", "output", unit="m", depends_on=deps, description=f"{point} y"),
        Var("phi", "Real", "output", unit="rad", depends_on=deps,
            description="platform orientation, wrapped to (-pi, pi]"),
        Var("region", "Integer", "output", depends_on=deps,
            description="number 1..6 of the DK solution returned (map's ordering rule); 0 none"),
        Var("near_border", "Boolean", "output", depends_on=deps,
            description="procedure 2 saw more than one region label near the previous pose"),
        Var("n_real", "Integer", "output", depends_on=deps,
            description="number of real DK solutions of q (0, 2, 4 or 6)"),
        Var("ambiguous", "Boolean", "output", depends_on=deps,
            description="the choice of solution is not certain"),
        Var("status", "Integer", "output", depends_on=deps,
            description="0 ok, 1 unreachable (pose held), 2 singular, 3 rejected: an outlier the tracker's "
                        "gate refused (pose held, doStep ok) or an input the FMU refused (doStep discarded), "
                        "4 diverged"),
        Var("cond", "Real", "output", unit="1", depends_on=deps,
            description="|det J| / prod |rows of J| at the pose (0 singular, 1 best)"),
        Var("certain", "Boolean", "output", depends_on=deps,
            description="the tracker vouches for the pose (certificates back to a proved start)"),
        Var("uncertain_since", "Real", "output", "discrete", unit="s", depends_on=deps,
            description="time of the step since which the tracker cannot vouch for the pose; -1 while certain"),
        Var("stuck_after", "Integer", "parameter", "fixed", start=0, min=0,
            description="with joint_tolerance: identical readings in a row that mark a joint stuck (refused, "
                        "state rolled back to before them); 0: off, for noisy encoders see the readme"),
        *bound_rows(deps, start_tolerance, geometry_tolerance),
    )


def bound_rows(deps: tuple, start_tolerance=START_TOLERANCE, geometry_tolerance: float = 0.0) -> tuple:
    """The rows of the pose bound, ``trust``, the start tolerance and the step budget (after
    ``stuck_after``: the rows before keep their value references)."""
    no = f"; {NO_BOUND:g}: no bound (not certain)"
    return (
        Var("x_bound", "Real", "output", unit="m", depends_on=deps,
            description="half-width in x of a proven box about the pose (certain steps: every joint path within "
                        "joint_tolerance)" + no),
        Var("y_bound", "Real", "output", unit="m", depends_on=deps,
            description="half-width in y of the proven box about the pose" + no),
        Var("phi_bound", "Real", "output", unit="rad", depends_on=deps,
            description="half-width in phi of the proven box about the pose" + no),
        Var("trust", "Integer", "output", depends_on=deps,
            description="what a controller can act on: 2 certain (the pose within the bounds), 1 possible (the "
                        "branch along the measured joints known, not proved over joint_tolerance), 0 lost"),
        Var("start_tolerance_linear", "Real", "parameter", "fixed", start=float(start_tolerance[0]), unit="m",
            description="> 0: how far x0 and y0 may be from the robot's position; the start is the DK solution "
                        "of the joints at t0 within it, certain when proved the only one"),
        Var("start_tolerance_angular", "Real", "parameter", "fixed", start=float(start_tolerance[2]), unit="rad",
            description="> 0: how far phi0 may be from the robot's orientation"),
        Var("step_budget_share", "Real", "parameter", "fixed", start=0.0, unit="1", min=0.0, max=1.0,
            description="share of each doStep's communication step the tracker may spend (e.g. 0.5 for a real-time "
                        "loop); past it the step returns its choice, not certain (out_of_budget), and the proof goes "
                        "on at the next steps.  0: no budget (results then do not depend on the machine's timing)"),
        Var("out_of_budget", "Boolean", "output", depends_on=deps,
            description="the step is not certain because its budget (step_budget_share) ran out first"),
        Var("geometry_tolerance", "Real", "parameter", "fixed", start=float(geometry_tolerance), unit="m", min=0.0,
            description="the robot as built: half-width of every length and coordinate of its geometry (at most a "
                        "tenth of the shortest link); certain and the bounds then hold for every robot within it. "
                        "0: for the model's geometry only"),
    )
