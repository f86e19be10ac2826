"""RRRDirectKinematics3: the DK FMU of the planar 3-RRR for FMI 3.0 Co-Simulation (pythonfmu3).

Joint angles in as the array ``q`` (Float64[3], rad), platform pose out as the array ``pose``
(Float64[3]: x, y in m, phi in rad): the FMI 2.0 slave :class:`RRRDirectKinematics` (the tracker on
the embedded map tensors) behind :class:`fmu_src.fmi3_adapter.Fmi3Adapter`, so both FMUs run the same
slave logic and state.  Variables, FMI 3.0 features used and not used: ``fmu_src/RRRDirectKinematics3.md``
(also ``documentation/index.md`` inside the FMU).  Built by ``python build_fmu.py --fmi 3``.

Module-level code: imports and the class (pythonfmu3's C wrapper imports this module by name and
finds the class by the text ``class <name>(... Fmi3Slave)``).
"""
# fmu_src may already be imported from another FMU's resources (the FMI 2.0 DK FMU bundles no FMI 3.0
# module): look in this FMU's copy too, after that one
import fmu_src
from pathlib import Path

if str(Path(__file__).with_name("fmu_src")) not in fmu_src.__path__:
    fmu_src.__path__.append(str(Path(__file__).with_name("fmu_src")))

from pythonfmu3 import Fmi3Slave

from fmu_src.fmi3_adapter import Fmi3Adapter, Row3
from fmu_src.requirements import MissingRequirements, require
from fmu_src.wrapper_refs import hold_globals

hold_globals(globals())   # as in every slave script (fmu_src/wrapper_refs.py)

# first: a host without the packages this FMU imports learns which and how to install them.  The
# module must import even then: pythonfmu3 0.3.4's wrapper crashes the host process (SIGSEGV) when the
# slave module fails to import, while an exception of the constructor is a clean failed instantiation
# (the class raises it, Fmi3Adapter.MISSING)
try:
    require(__file__)
    from fmu_src.RRRDirectKinematics import RRRDirectKinematics, _home_joints
except MissingRequirements as exc:
    _MISSING, RRRDirectKinematics = exc, None
else:
    _MISSING = None

# Build constants: start values of the parameters ``posture`` and ``mode`` (build_fmu.py --fmi 3
# --posture/--mode rewrites them in the staged copy, as the FMI 2.0 build does in its script).
BUILD_POSTURE = 1
BUILD_MODE = "default"
# the robot (build_fmu.py --fmi 3 --robot: as the FMI 2.0 DK slave's BUILD_ROBOT); None: the paper's
BUILD_ROBOT = None
_WHY = {v.name: v.description for v in RRRDirectKinematics._table} if RRRDirectKinematics else {}


def _robot_start() -> dict:
    """The core's start values of a robot build: its start pose, the joints there in BUILD_POSTURE, its
    start tolerance and geometry tolerance ({} for the paper's robot: the core's own)."""
    if BUILD_ROBOT is None or RRRDirectKinematics is None:
        return {}
    from solver import Manipulator, ik

    pose = [float(v) for v in BUILD_ROBOT["start"]]
    q = ik(Manipulator.from_dict(BUILD_ROBOT["geometry"]), pose, BUILD_POSTURE)
    lin, _, ang = BUILD_ROBOT["start_tolerance"]
    return {**dict(zip(("x0", "y0", "phi0"), pose)), **dict(zip(("q1", "q2", "q3"), (float(v) for v in q))),
            "start_tolerance_linear": float(lin), "start_tolerance_angular": float(ang),
            "geometry_tolerance": float(BUILD_ROBOT.get("geometry_tolerance", 0.0))}


def _row(name, kind, causality, unit=None):
    """A scalar row of the FMI 2.0 variable ``name`` (its description)."""
    return Row3(name, kind, causality, (name,), unit, _WHY.get(name, ""))


class RRRDirectKinematics3(Fmi3Adapter, Fmi3Slave):
    """Direct kinematics of the 3-RRR (paper Table 1) by the basic-regions tracker, FMI 3.0 arrays."""

    CORE = RRRDirectKinematics
    MISSING = _MISSING
    # the start values of this build (the FMI 2.0 slave's are those of its own build constants)
    START = {**dict(zip(("q1", "q2", "q3"), _home_joints(BUILD_POSTURE))), "posture": BUILD_POSTURE,
             "mode": RRRDirectKinematics.MODES.index(BUILD_MODE), **_robot_start()} if RRRDirectKinematics else {}
    if BUILD_ROBOT is not None:
        description = (f"Direct kinematics of the planar 3-RRR parallel manipulator with basic regions: joint angles "
                       f"-> platform pose (tracker + embedded map tensor); robot: the 3-RRR {BUILD_ROBOT['name']!r} "
                       f"(robot description sha256 {BUILD_ROBOT['digest']})")
    ROWS = (
        Row3("time", "Float64", "independent", description="simulation time"),
        Row3("q", "Float64", "input", ("q1", "q2", "q3"), "rad",
             "motor angles theta_1..theta_3 of legs 1..3 (from +x)"),
        Row3("pose0", "Float64", "parameter", ("x0", "y0", "phi0"), None,
             "initial pose: x, y of the platform centre (m), orientation phi (rad)"),
        _row("posture", "Int32", "parameter"),
        _row("mode", "Int32", "parameter"),
        _row("joint_tolerance", "Float64", "parameter", "rad"),
        _row("speed_bound_linear", "Float64", "parameter", "m/s"),
        _row("speed_bound_angular", "Float64", "parameter", "rad/s"),
        _row("stuck_after", "Int32", "parameter"),
        _row("start_tolerance_linear", "Float64", "parameter", "m"),
        _row("start_tolerance_angular", "Float64", "parameter", "rad"),
        _row("step_budget_share", "Float64", "parameter", "1"),
        Row3("pose", "Float64", "output", ("x", "y", "phi"), None,
             "platform pose: x, y of the platform centre (m), orientation phi (rad) wrapped to (-pi, pi]"),
        _row("region", "Int32", "output"),
        _row("near_border", "Boolean", "output"),
        _row("n_real", "Int32", "output"),
        _row("ambiguous", "Boolean", "output"),
        _row("status", "Int32", "output"),
        _row("cond", "Float64", "output", "1"),
        _row("certain", "Boolean", "output"),
        _row("uncertain_since", "Float64", "output", "s"),
        Row3("pose_bound", "Float64", "output", ("x_bound", "y_bound", "phi_bound"), None,
             "half-widths of a proven box about the pose: x, y (m), phi (rad); -1 each: no bound (not certain)"),
        _row("trust", "Int32", "output"),
        _row("out_of_budget", "Boolean", "output"),
        _row("geometry_tolerance", "Float64", "parameter", "m"),
    )
