"""RPRDirectKinematics: direct kinematics of the cuspidal planar 3-RPR with basic regions, FMI 2.0 Co-Simulation.

Leg lengths (rho1, rho2, rho3) in m in, platform pose (x, y, phi) out: the same tracker and the same
slave as ``RRRDirectKinematics`` (certificates, sensor options, FMI state table), with the 3-RPR's
map tensor embedded in ``resources/maps/`` and one posture.  Variables, equations and the reference
run: ``fmu_src/RPRDirectKinematics.md``.  Built by ``python build_fmu.py --manipulator 3rpr``.
"""
# first: a host without the packages this FMU imports learns which and how to install them
from fmu_src.requirements import require
from fmu_src.wrapper_refs import hold_globals

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation
require(__file__)

import numpy as np  # noqa: E402
from pythonfmu import DefaultExperiment  # noqa: E402

from fmu_src.RRRDirectKinematics import RRRDirectKinematics  # noqa: E402
from fmu_src.dk_variables import dk_outputs, initial_pose, sensor_parameters  # noqa: E402
from fmu_src.table_slave import Var  # noqa: E402
from solver.rpr import RPR_HOME_POSE, RPRManipulator, ik  # noqa: E402

# Build constant: the robot (build_fmu.py --robot FILE of a 3-RPR: name, description digest, geometry as
# RPRManipulator.to_dict(), start pose; None: Zein, Wenger and Chablat's 3-RPR at RPR_HOME_POSE).  The
# tracker's model is the one the embedded map carries; this gives the start values and the description.
BUILD_ROBOT = None
_MODEL = RPRManipulator.from_dict(BUILD_ROBOT["geometry"]) if BUILD_ROBOT else RPRManipulator.zein_wenger_chablat()
_START = tuple(float(v) for v in BUILD_ROBOT["start"]) if BUILD_ROBOT else tuple(RPR_HOME_POSE)
_HOME_RHO = [float(v) for v in ik(_MODEL, np.array(_START))]
_DEPS = ("rho1", "rho2", "rho3")
_ABOUT = ("" if BUILD_ROBOT is None else
          f"; robot: the 3-RPR {BUILD_ROBOT['name']!r} (robot description sha256 {BUILD_ROBOT['digest']})")


class RPRDirectKinematics(RRRDirectKinematics):
    """Direct kinematics of the cuspidal 3-RPR (Zein, Wenger and Chablat's geometry) by the tracker."""

    description = ("Direct kinematics of the cuspidal planar 3-RPR parallel manipulator with basic regions: "
                   "leg lengths -> platform pose (tracker + embedded map tensor)" + _ABOUT)
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-2)
    JOINTS = _DEPS
    posture = 1                                   # a 3-RPR has one posture (not a parameter)

    VARIABLES = (
        Var("rho1", "Real", "input", start=_HOME_RHO[0], unit="m", description="length of leg 1 (A1 to B1)"),
        Var("rho2", "Real", "input", start=_HOME_RHO[1], unit="m", description="length of leg 2 (A2 to B2)"),
        Var("rho3", "Real", "input", start=_HOME_RHO[2], unit="m", description="length of leg 3 (A3 to B3)"),
        *initial_pose(_START, "the platform point P (= B1)"),
        Var("mode", "Integer", "parameter", "fixed", start=0, min=0, max=1,
            description="tracker mode: 0 default (RK4 continuation + map), 1 paper (procedures 2-3 as written)"),
        *sensor_parameters("m"),
        *dk_outputs(_DEPS, point="platform point P (= B1),",
                    geometry_tolerance=float(BUILD_ROBOT.get("geometry_tolerance", 0.0)) if BUILD_ROBOT else 0.0),
    )
