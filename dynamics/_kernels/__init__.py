"""Compiled (numba) kernels of :mod:`dynamics`: private, called only by the package's own modules.

The kinematics is not here: the inverse kinematics, the leg rows (``L_i``, ``J_q``), the angle
wrap and the 3x3 algebra are the solver's kinematics core (:mod:`solver._kernels.kinematics`,
:mod:`solver._kernels.linalg`), which these kernels call.

* :mod:`.layout`: the named offsets of every packed argument array and the packers;
  status codes and what a kernel returns;
* :mod:`.base`: the core's inverse kinematics on the ``arm`` pack, finiteness, refusal codes, work arrays;
* :mod:`.rows`: one configuration at a time: the loop geometry table, the body velocity rows,
  the task- and joint-space terms (``task_row``, ``joint_row``) and their batches;
* :mod:`.control`: the computed-torque law (commanded acceleration, inverse dynamics at it);
* :mod:`.rk4`: the classic RK4 step, written once (:func:`.rk4.make_rk4_step`), compiled here
  around the task-space right-hand side and run as plain Python by :mod:`dynamics.integrate`;
* :mod:`.circle`: the circle reference of :class:`dynamics.trajectory.CircleTrajectory`;
* :mod:`.steps`: one communication step of the plant and of the computed-torque controller
  (what :mod:`dynamics.steppers` runs for the FMU slaves).

Every kernel refuses instead of raising: it returns :data:`.layout.OK` (0) or a refusal code
(:func:`.layout.refusal`: the status and the index of the refused row, step or phase), and the
Python caller raises :class:`dynamics.DynamicsError`.  numba caches the machine code; its stamp is
the content of every module here and in ``solver/_kernels`` (:mod:`solver._kernels.cache_stamp`),
so a change to any of them recompiles these kernels once.
"""
import os as _os

import solver._kernels as _solver_kernels
from solver._kernels.cache_stamp import stamp_by_content as _stamp_by_content

_stamp_by_content(_os.path.dirname(_os.path.abspath(__file__)),
                  depends_on=(_os.path.dirname(_os.path.abspath(_solver_kernels.__file__)),))
