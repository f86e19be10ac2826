"""Direct kinematics of the planar 3-RRR parallel manipulator with basic regions.

The package holds the paper's kinematics (inverse kinematics in 8 postures, all six
direct-kinematics solutions, the Jacobians J and K, singularity measures), procedure 1
(the map tensor, its file and its cache), procedures 2-3 (the tracker) and the baselines
it must beat.  It may import numpy, scipy and numba (and tqdm, only when a progress bar
is drawn): never fmpy, pythonfmu, dask, :mod:`dynamics` or :mod:`fmu_src`.  The
experiments (suites, sensor streams, figures, reference oracles) live apart in the
top-level package ``experiments``, which imports this one and never the other way round
(the paper's figures: ``python -m experiments figures``).
Compiled kernels live in the private :mod:`solver._kernels`; other packages use the
names below.

Modules, one concept each: ``checks`` (argument checking), ``manipulator`` (geometry),
``kinematics`` (IK, J and K, singularity measures), ``direct_kinematics`` (all six DK
solutions), ``ordering`` (their numbering rules), ``grid`` (the map grid over the tool
space), ``maptensor`` (procedures 1 and 2), ``mapfile`` (the map file format),
``mapcache`` (the one map cache), ``cache`` (:func:`cache_dir`, the root of every disk
cache), ``shared_kernels`` (the generic-CPU kernels an FMU build compiled serve this process too),
``lean_compile`` (a kernel a caller needs compiled in its callers only), ``precompile`` (a tracker's
kernels compiled before its map exists), ``progress`` (phase lines and progress bars of long work), ``tracker``
(procedure 3) with ``tracking``, ``tracker_state``, ``start``, ``encoder_grid`` and ``stuck``, ``baselines``,
``sensors`` (the encoder model: the tracker's joint tolerance and stuck threshold; its speed bound
from the planned motion),
``trajectories`` (shared tool-space paths), ``manipulators`` and ``rpr`` (the 3-RPR).
"""
from .cache import CACHE_ENV, cache_dir
from . import lean_compile as _lean_compile
from . import shared_kernels as _shared_kernels
from .checks import GeometryError, SolverInputError, as_array, check_posture
from .direct_kinematics import DKSolutions, dk_all, order_solutions
from .grid import DEFAULT_STEP, default_bounds, default_grid, grid_shape
from .kinematics import (SingularityMeasures, constraints, elbow_points, ik, ik_pose, jacobians, platform_points,
                         posture_of, singularity_measures, wrap_angle)
from .manipulator import HOME_POSE, Manipulator
from .mapcache import cached_map, map_path
from .mapfile import FORMAT_VERSION, MapTensorFileError
from .maptensor import MapTensor, label_poses
from .ordering import DEFAULT_RULE, ORDERING_RULES
from .start import START_TOLERANCE, StartInfo, UncertainStartWarning
from .options import TrackerOptions
from .tracker import Tracker
from .tracker_state import CERTIFICATES, STATUS, TRUST, StepInfo, TrackerError, TrackerState, TrackResult
from .trajectories import PAPER_CIRCLE, circle_path

__version__ = "0.1.0"

__all__ = [
    "Manipulator", "HOME_POSE", "GeometryError", "SolverInputError", "as_array", "check_posture",
    "ik", "ik_pose", "posture_of", "dk_all", "DKSolutions", "order_solutions", "ORDERING_RULES", "DEFAULT_RULE",
    "jacobians", "singularity_measures", "SingularityMeasures", "constraints", "elbow_points", "platform_points",
    "wrap_angle", "PAPER_CIRCLE", "circle_path",
    "MapTensor", "MapTensorFileError", "FORMAT_VERSION", "label_poses", "default_bounds", "default_grid",
    "grid_shape", "DEFAULT_STEP", "cached_map", "map_path", "cache_dir", "CACHE_ENV",
    "Tracker", "TrackerOptions", "TrackerState", "StepInfo", "TrackResult", "TrackerError", "STATUS", "CERTIFICATES", "TRUST",
    "StartInfo", "UncertainStartWarning", "START_TOLERANCE", "__version__",
]

_shared_kernels.install()      # the generic kernels an FMU build compiled serve this process too
_lean_compile.install()        # a kernel a caller needs is compiled in its callers, not for itself too
