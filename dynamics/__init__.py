"""Rigid-body dynamics, integration and computed-torque control of the 3-RRR (paper eqs. 5-7).

The package holds the math of the robot's motion: its dynamic parameters (:mod:`.parameters`),
the kinematics the dynamics needs (:mod:`.geometry`), the model terms in task and joint space
(:mod:`.model`), the energies (:mod:`.energy`), RK4 and the state-space forms (:mod:`.integrate`),
the reference circle (:mod:`.trajectory`), computed-torque control (:mod:`.control`), the FMU
slaves' per-step entry points (:mod:`.steppers`) and the one exception of a refused evaluation
(:mod:`.errors`); the compiled kernels are private (:mod:`._kernels`).  It may import numpy,
scipy, numba, python-control and :mod:`solver` (its public names; the kernels also call the
solver's kinematics core, :mod:`solver._kernels`, and its data cache) -- never fmpy,
pythonfmu, dask, :mod:`fmu_src` or :mod:`cosim` (the host side, where the co-simulation master
and the batch runner live).

>>> from dynamics import DynamicParameters, forward_dynamics_task
>>> from solver import Manipulator
>>> ddX = forward_dynamics_task(DynamicParameters(), Manipulator.paper(), [0.45, 0.3, -0.7], [0, 0, 0], [0.1, 0, 0])
"""
from .control import (ComputedTorqueController, ComputedTorqueGains, TrackingResult, computed_torque,
                      simulate_tracking, wrap)
from .energy import friction_power, kinetic_energy, potential_energy, total_energy
from .errors import DynamicsError
from .geometry import (ASSEMBLY_TOL, joint_accelerations, joint_velocity_jacobian, passive_joint_angles,
                       passive_joint_rates, pose_velocity_jacobian)
from .integrate import NearestPoseDK, joint_space_rhs, rk4, rk4_step, solve_reference, task_space_rhs
from .model import (coriolis, coriolis_task, forward_dynamics, forward_dynamics_task, friction, friction_task,
                    generalized_force_task, gravity, gravity_task, inverse_dynamics, inverse_dynamics_task,
                    mass_matrix, mass_matrix_task)
from .parameters import DynamicParameters, ParameterError
from .steppers import ControllerStepper, PlantStepper
from .trajectory import CircleTrajectory

__all__ = [
    # parameters and errors
    "DynamicParameters", "ParameterError", "DynamicsError", "ASSEMBLY_TOL",
    # kinematics used by the dynamics
    "joint_velocity_jacobian", "pose_velocity_jacobian", "joint_accelerations",
    "passive_joint_angles", "passive_joint_rates",
    # model terms, task space and joint space (eq. 5 and 7)
    "mass_matrix_task", "coriolis_task", "gravity_task", "friction_task",
    "generalized_force_task", "forward_dynamics_task", "inverse_dynamics_task",
    "mass_matrix", "coriolis", "gravity", "friction", "forward_dynamics", "inverse_dynamics",
    # energy
    "kinetic_energy", "potential_energy", "total_energy", "friction_power",
    # integration
    "rk4_step", "rk4", "solve_reference", "task_space_rhs", "joint_space_rhs", "NearestPoseDK",
    # trajectory and control
    "CircleTrajectory", "ComputedTorqueGains", "ComputedTorqueController", "computed_torque",
    "TrackingResult", "simulate_tracking", "wrap",
    # the FMU slaves' steps
    "PlantStepper", "ControllerStepper",
]
