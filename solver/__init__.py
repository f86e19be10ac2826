"""Direct kinematics of the planar 3-RRR parallel manipulator with basic regions.

The package implements the paper's kinematics (section 2 and 5), procedure 1
(the map tensor), procedures 2-3 (the tracker) and the baselines.  It depends
on numpy and scipy only: no FMI code lives here.

Public entry points
-------------------
Manipulator                    frozen geometry; ``Manipulator.paper()`` is Table 1
ik, posture_of                 inverse kinematics in 8 postures
dk_all                         all six direct-kinematics solutions (the sextic)
jacobians, singularity_measures  J and K of eq. 3, closeness to eq. 4's singularities
"""
from ._checks import GeometryError, SolverInputError
from .kinematics import (DEFAULT_RULE, ORDERING_RULES, DKSolutions, SingularityMeasures,
                         constraints, dk_all, elbow_points, ik, jacobians, order_solutions,
                         platform_points, posture_of, singularity_measures, wrap_angle)
from .manipulator import Manipulator
from .trajectories import PAPER_CIRCLE, circle_path

__version__ = "0.1.0"

__all__ = [
    "Manipulator", "GeometryError", "SolverInputError",
    "ik", "posture_of", "dk_all", "DKSolutions", "order_solutions", "ORDERING_RULES",
    "DEFAULT_RULE", "jacobians", "singularity_measures", "SingularityMeasures",
    "constraints", "elbow_points", "platform_points", "wrap_angle", "__version__",
    "PAPER_CIRCLE", "circle_path",
]
