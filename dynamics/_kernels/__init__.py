"""Compiled (numba) kernels of :mod:`dynamics`: private, called only by the package's own modules.

* :mod:`.layout`: the named offsets of every packed argument array and the packers;
  status codes and what a kernel returns;
* :mod:`.rows`: one configuration at a time: linear algebra on 3x3 systems, the loop
  geometry, the body velocity rows, the task- and joint-space terms (``task_row``,
  ``joint_row``) and their batches;
* :mod:`.rk4`: the classic RK4 step, written once (:func:`.rk4.make_rk4_step`), compiled here
  around the task-space right-hand side and run as plain Python by :mod:`dynamics.integrate`;
* :mod:`.circle`: the circle reference of :class:`dynamics.trajectory.CircleTrajectory`;
* :mod:`.steps`: one communication step of the plant and of the computed-torque controller
  (what :mod:`dynamics.steppers` runs for the FMU slaves).

Every kernel refuses instead of raising: it returns :data:`.layout.OK` (0) or a refusal code
(:func:`.layout.refusal`: the status and the index of the refused row, step or phase), and the
Python caller raises :class:`dynamics.DynamicsError`.  numba caches the machine code next to each
file and checks only that file's time stamp: after editing one kernel file, delete
``dynamics/_kernels/__pycache__`` so that the files that call it are recompiled too.
"""
