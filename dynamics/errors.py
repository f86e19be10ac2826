"""The one exception of a refused dynamics evaluation, and the messages that say what and where.

Every dynamics term, right-hand side, trajectory point and stepper runs a compiled kernel
(:mod:`dynamics._kernels`).  A kernel never raises: it refuses (a non-finite input, a pose outside
the posture's tool space, a pose that does not close the loops of the joints, a singular matrix or
a non-finite result) and returns a refusal code; the caller raises :class:`DynamicsError` with a
message built here from the caller's own arguments.  Wrong shapes, types and postures are argument
errors, raised before any kernel runs (:class:`solver.SolverInputError`).
"""
from __future__ import annotations

import numpy as np

from solver import SolverInputError, as_array, ik

from ._kernels.layout import BAD_INPUT, NOT_ASSEMBLED, OUTSIDE, SINGULAR, refusal

__all__ = ["DynamicsError"]

#: the ``reason`` of a :class:`DynamicsError` for each kernel status
REASONS = {BAD_INPUT: "non-finite", OUTSIDE: "outside", NOT_ASSEMBLED: "not-assembled", SINGULAR: "singular"}


class DynamicsError(SolverInputError):
    """A dynamics kernel refused its input; the message names the argument and the values.

    A :class:`solver.SolverInputError` (so a ``ValueError``): callers that catch those keep working.

    Attributes
    ----------
    reason : str
        ``"non-finite"`` (an input is NaN or infinite), ``"outside"`` (a pose outside the
        posture's tool space), ``"not-assembled"`` (the pose does not close the loops of the
        joints, see :data:`dynamics.ASSEMBLY_TOL`) or ``"singular"`` (a singular ``J_q``, ``J_x``,
        ``M`` or ``M_X``, or a non-finite result).
    where : tuple, int, str or None
        The index of the refused configuration in a batch, the RK4 step of a plant step, the part
        of a controller step (``"reference"`` or ``"measurement"``), or None (a single configuration).
    """

    def __init__(self, message: str, reason: str = "singular", where=None):
        super().__init__(message)
        self.reason = reason
        self.where = where

    def __reduce__(self):
        return type(self), (str(self), self.reason, self.where)


def outside_text(posture, poses) -> str:
    """The message of poses (a list) outside the tool space of ``posture``."""
    return (f"X: expected poses inside the tool space of posture {posture!r}, got {poses} "
            f"(no inverse-kinematics solution)")


def outside_poses(model, X, posture, index=None):
    """Up to three poses of ``X`` (..., 3) without inverse kinematics (solver's IK), as a list;
    the pose at flat ``index`` if solver's IK reaches them all (a kernel at the border)."""
    X = np.asarray(X)
    bad = np.isnan(ik(model, X, posture)[..., 0])
    if np.any(bad):
        return X[bad][:3].tolist()
    return [X.reshape(-1, 3)[index or 0].tolist()]


def refused(code: int, arrays: dict, *, model=None, posture=None, lead=()) -> DynamicsError:
    """The :class:`DynamicsError` of a kernel's refusal ``code`` on the caller's ``arrays``.

    Parameters
    ----------
    code : int
        The kernel's return value (not OK).
    arrays : dict
        The arguments by name, in the caller's order, as given (a single configuration) or
        broadcast to ``lead + (3,)``; ``X`` (and ``q``) name the pose (and joints).
    model, posture
        The geometry and posture (for the inverse kinematics of the message).
    lead : tuple
        Leading (batch) shape; ``()`` for a single configuration.
    """
    status, index = refusal(code)
    where = tuple(int(i) for i in np.unravel_index(index, lead)) if lead else None
    if status == BAD_INPUT:
        message = ", ".join(arrays) + ": expected finite numbers"
        for name, value in arrays.items():
            try:
                as_array(name, value)
            except SolverInputError as exc:
                message = str(exc)
                break
    elif status == OUTSIDE:
        message = outside_text(posture, outside_poses(model, arrays["X"], posture, index))
    elif status == NOT_ASSEMBLED:
        from .geometry import ASSEMBLY_TOL, assembly_residual
        residual = assembly_residual(model, np.asarray(arrays["X"]), np.asarray(arrays["q"]))
        message = (f"X: expected the pose of the joints q (direct kinematics), got loop residual "
                   f"max|F_i|/l2^2 = {residual:.3g} > {ASSEMBLY_TOL:g}")
    else:
        values = ", ".join(f"{name} = {np.reshape(a, (-1, np.shape(a)[-1]))[index if lead else 0].tolist()}"
                           for name, a in arrays.items())
        message = (f"{', '.join(arrays)}: expected a configuration away from singularities, got a singular "
                   f"matrix or a non-finite result at {values}")
    if where is not None:
        message += f" (first refused at index {where})"
    return DynamicsError(message, REASONS.get(status, "singular"), where)
