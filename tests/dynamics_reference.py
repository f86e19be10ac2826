"""The numpy reference of every compiled dynamics kernel: the oracle of tests/test_dynamics_kernel.py.

These are the numpy implementations the kernels of ``dynamics/_kernels`` replaced, kept here
(not in the package) so that the runtime has one path: the kernels are compared against them on
many configurations, and the errors of the public functions against theirs.  Each ``<name>``
below takes the same arguments as ``dynamics.<name>`` and checks them the same way.  The
geometry and body motion come from :mod:`dynamics.geometry` (numpy); the body rows, the terms and
the solves are written out here with array operations.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from solver import Manipulator, SolverInputError, as_array, ik
from dynamics import (ASSEMBLY_TOL, ComputedTorqueGains, DynamicParameters, joint_velocity_jacobian, rk4_step,
                      task_space_rhs, total_energy, wrap)
from dynamics.geometry import KINEMATIC_ONLY, geometry, motion
from dynamics.parameters import row_constants


# ----------------------------------------------------------------------------- argument checks
def _check(params, model):
    if not isinstance(params, DynamicParameters):
        raise SolverInputError(f"params: expected a DynamicParameters, got {type(params).__name__}")
    if not isinstance(model, Manipulator):
        raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")


def _broadcast(**arrays):
    try:
        lead = np.broadcast_shapes(*(a.shape[:-1] for a in arrays.values()))
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in arrays.items())
        raise SolverInputError(f"{', '.join(arrays)}: leading dimensions do not broadcast: {shapes}") from None
    return [np.broadcast_to(a, lead + a.shape[-1:]) for a in arrays.values()]


def _ik(model, X, posture):
    q = ik(model, X, posture)
    bad = np.isnan(q[..., 0])
    if np.any(bad):
        raise SolverInputError(f"X: expected poses inside the tool space of posture {posture!r}, got "
                               f"{np.asarray(X)[bad][:3].tolist()} (no inverse-kinematics solution)")
    return q


def _task_args(params, model, X, posture, **more):
    _check(params, model)
    arrays = {"X": as_array("X", X)}
    arrays.update({k: as_array(k, v) for k, v in more.items()})
    out = _broadcast(**arrays)
    return out, _ik(model, out[0], posture)


def _joint_args(params, model, **arrays):
    _check(params, model)
    return _broadcast(**{k: as_array(k, v) for k, v in arrays.items()})


def _matT_vec(A, v):
    return np.einsum("...ji,...j->...i", A, v)


def _mat_vec(A, v):
    return np.einsum("...ij,...j->...i", A, v)


# ----------------------------------------------------------------------------- body rows and terms
def _velocity_rows(params, model, g):
    """Jacobian V (..., 21, 3) of the 21 body velocity rows w.r.t. dX, and the distal W (..., 3, 3)."""
    Jq = g.Jq
    lead = Jq.shape[:-2]
    one, zero = np.ones(lead + (3,)), np.zeros(lead + (3,))
    Pc = np.stack([np.stack([one[..., 0], zero[..., 0], -g.Rcy], -1),
                   np.stack([zero[..., 0], one[..., 0], g.Rcx], -1),
                   np.stack([zero[..., 0], zero[..., 0], one[..., 0]], -1)], axis=-2)
    rp = params.com_proximal
    prox_x = (-rp * g.sq)[..., None] * Jq
    prox_y = (rp * g.cq)[..., None] * Jq
    VAx = np.stack([one, zero, -g.Rby], -1)
    VAy = np.stack([zero, one, g.Rbx], -1)
    l1 = model.l1
    VDx = (-l1 * g.sq)[..., None] * Jq
    VDy = (l1 * g.cq)[..., None] * Jq
    dLx, dLy = VAx - VDx, VAy - VDy
    W = (g.Lx[..., None] * dLy - g.Ly[..., None] * dLx) / (model.l2 ** 2)[:, None]
    sd = (params.com_distal / model.l2)[:, None]
    V = np.concatenate([Pc, prox_x, prox_y, Jq, VDx + sd * dLx, VDy + sd * dLy, W], axis=-2)
    return V, W


def _friction_rows(params, g, W):
    """Jacobian (..., 9, 3) of the friction-carrying joint rates and their coefficients (9,)."""
    e3 = np.zeros(3)
    e3[2] = 1.0
    return np.concatenate([g.Jq, W - g.Jq, e3 - W], axis=-2), row_constants(params)["b"]


class TaskTerms(NamedTuple):
    MX: np.ndarray
    CX: np.ndarray
    GX: np.ndarray
    FX: np.ndarray
    Jq: np.ndarray


def task_terms(params, model, X, q, dX) -> TaskTerms:
    g = geometry(model, params.com_platform, X, q)
    V, W = _velocity_rows(params, model, g)
    c = row_constants(params)
    WV = c["w"][:, None] * V
    MX = np.swapaxes(V, -1, -2) @ WV
    mo = motion(params, model, g, dX)
    CX = _matT_vec(WV, mo.beta)
    GX = -_matT_vec(WV, np.broadcast_to(c["gamma"], mo.beta.shape))
    Vf, b = _friction_rows(params, g, W)
    FX = _matT_vec(Vf, b * _mat_vec(Vf, dX))
    return TaskTerms(MX, CX, GX, FX, g.Jq)


class JointTerms(NamedTuple):
    M: np.ndarray
    C: np.ndarray
    G: np.ndarray
    F: np.ndarray


def joint_terms(params, model, q, dq, X, check=True) -> JointTerms:
    g = geometry(model, params.com_platform, X, q)
    if check:
        res = np.max(np.abs(g.Lx ** 2 + g.Ly ** 2 - model.l2 ** 2) / model.l2 ** 2, axis=-1)
        if np.any(res > ASSEMBLY_TOL):
            raise SolverInputError(
                f"X: expected the pose of the joints q (direct kinematics), got loop residual "
                f"max|F_i|/l2^2 = {float(np.max(res)):.3g} > {ASSEMBLY_TOL:g}")
    Jx = np.linalg.inv(g.Jq)
    dX = _mat_vec(Jx, dq)
    V, W = _velocity_rows(params, model, g)
    c = row_constants(params)
    WV = c["w"][:, None] * V
    VJ = V @ Jx                                   # body rows w.r.t. dq
    M = np.swapaxes(VJ, -1, -2) @ (c["w"][:, None] * VJ)
    mo = motion(params, model, g, dX)
    ddX0 = -_mat_vec(Jx, mo.ddq0)                 # pose acceleration at ddq = 0
    beta_q = mo.beta + _mat_vec(V, ddX0)          # body accelerations at ddq = 0
    C = _matT_vec(Jx, _matT_vec(WV, beta_q))
    G = -_matT_vec(Jx, _matT_vec(WV, np.broadcast_to(c["gamma"], beta_q.shape)))
    Vf, b = _friction_rows(params, g, W)
    F = _matT_vec(Jx, _matT_vec(Vf, b * _mat_vec(Vf, dX)))
    return JointTerms(M, C, G, F)


# ----------------------------------------------------------------------------- the public terms
def forward_task(params, model, X, q, dX, tau):
    """``ddX`` of checked arrays, ``q`` given."""
    t = task_terms(params, model, X, q, dX)
    rhs = _matT_vec(t.Jq, tau) - t.FX - t.CX - t.GX
    return np.linalg.solve(t.MX, rhs[..., None])[..., 0]


def forward_joint(params, model, q, dq, X, tau, check=True):
    t = joint_terms(params, model, q, dq, X, check)
    return np.linalg.solve(t.M, (tau - t.C - t.G - t.F)[..., None])[..., 0]


def inverse_joint(params, model, q, dq, ddq, X, check=True):
    t = joint_terms(params, model, q, dq, X, check)
    return _mat_vec(t.M, ddq) + t.C + t.G + t.F


def mass_matrix_task(params, model, X, posture=1):
    (X,), q = _task_args(params, model, X, posture)
    return task_terms(params, model, X, q, np.zeros_like(X)).MX


def coriolis_task(params, model, X, dX, posture=1):
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return task_terms(params, model, X, q, dX).CX


def gravity_task(params, model, X, posture=1):
    (X,), q = _task_args(params, model, X, posture)
    return task_terms(params, model, X, q, np.zeros_like(X)).GX


def friction_task(params, model, X, dX, posture=1):
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return task_terms(params, model, X, q, dX).FX


def generalized_force_task(params, model, X, dX, tau, posture=1):
    (X, dX, tau), q = _task_args(params, model, X, posture, dX=dX, tau=tau)
    t = task_terms(params, model, X, q, dX)
    return _matT_vec(t.Jq, tau) - t.FX


def forward_dynamics_task(params, model, X, dX, tau, posture=1):
    (X, dX, tau), q = _task_args(params, model, X, posture, dX=dX, tau=tau)
    return forward_task(params, model, X, q, dX, tau)


def inverse_dynamics_task(params, model, X, dX, ddX, posture=1):
    (X, dX, ddX), q = _task_args(params, model, X, posture, dX=dX, ddX=ddX)
    t = task_terms(params, model, X, q, dX)
    f = _mat_vec(t.MX, ddX) + t.CX + t.GX + t.FX
    return np.linalg.solve(np.swapaxes(t.Jq, -1, -2), f[..., None])[..., 0]     # J_x^T f = J_q^{-T} f


def mass_matrix(params, model, q, X):
    q, X = _joint_args(params, model, q=q, X=X)
    return joint_terms(params, model, q, np.zeros_like(q), X).M


def coriolis(params, model, q, dq, X):
    q, dq, X = _joint_args(params, model, q=q, dq=dq, X=X)
    return joint_terms(params, model, q, dq, X).C


def gravity(params, model, q, X):
    q, X = _joint_args(params, model, q=q, X=X)
    return joint_terms(params, model, q, np.zeros_like(q), X).G


def friction(params, model, q, dq, X):
    q, dq, X = _joint_args(params, model, q=q, dq=dq, X=X)
    return joint_terms(params, model, q, dq, X).F


def forward_dynamics(params, model, q, dq, X, tau):
    q, dq, X, tau = _joint_args(params, model, q=q, dq=dq, X=X, tau=tau)
    return forward_joint(params, model, q, dq, X, tau)


def inverse_dynamics(params, model, q, dq, ddq, X):
    q, dq, ddq, X = _joint_args(params, model, q=q, dq=dq, ddq=ddq, X=X)
    return inverse_joint(params, model, q, dq, ddq, X)


def computed_torque(params, model, gains, q, dq, X, q_d, dq_d, ddq_d):
    """Reference of :func:`dynamics.computed_torque` (same arguments, checks and errors)."""
    _check(params, model)
    if not isinstance(gains, ComputedTorqueGains):
        raise SolverInputError(f"gains: expected a ComputedTorqueGains, got {type(gains).__name__}")
    q, dq, X, q_d, dq_d, ddq_d = _broadcast(
        q=as_array("q", q), dq=as_array("dq", dq), X=as_array("X", X), q_d=as_array("q_d", q_d),
        dq_d=as_array("dq_d", dq_d), ddq_d=as_array("ddq_d", ddq_d))
    return computed_torque_law(params, model, gains, q, dq, X, q_d, dq_d, ddq_d)


def computed_torque_law(params, model, gains, q, dq, X, q_d, dq_d, ddq_d):
    """The law on arrays that broadcast: the inverse dynamics at the commanded acceleration."""
    v = ddq_d + gains.kd * (dq_d - dq) + gains.kp * wrap(q_d - q)
    return inverse_joint(params, model, q, dq, v, X)


# ----------------------------------------------------------------------------- circle reference
def circle_task(traj, t):
    """Reference of :meth:`dynamics.CircleTrajectory.task`."""
    th, dth, ddth = traj.polar_angle(t)
    c, s, r = np.cos(th), np.sin(th), traj.radius
    zero = np.zeros_like(th)
    X = np.stack([traj.center[0] + r * c, traj.center[1] + r * s, np.full_like(th, traj.phi)], -1)
    dX = np.stack([-r * s * dth, r * c * dth, zero], -1)
    ddX = np.stack([-r * s * ddth - r * c * dth ** 2, r * c * ddth - r * s * dth ** 2, zero], -1)
    return X, dX, ddX


def circle_joint(traj, model, t):
    """Reference of :meth:`dynamics.CircleTrajectory.joint`."""
    if not isinstance(model, Manipulator):
        raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")
    X, dX, ddX = circle_task(traj, t)
    q = _ik(model, X, traj.posture)
    g = geometry(model, (0.0, 0.0), X, q)
    mo = motion(KINEMATIC_ONLY, model, g, dX)
    return q, mo.dq, _mat_vec(g.Jq, ddX) + mo.ddq0


# ----------------------------------------------------------------------------- the FMU slaves' steps
def plant_step(slave, t, dt):
    """The numpy step of an ``RRRPlant`` slave (generic RK4 loop on the task-space right-hand side,
    then its outputs); raises what the slave's step refuses."""
    rhs = task_space_rhs(slave._params, slave._model, int(slave.posture),
                         lambda t_, x_: np.array([slave.tau1, slave.tau2, slave.tau3]))
    n = int(slave.substeps)
    h = dt / n
    x = slave._x
    for k in range(n):
        x = rk4_step(rhs, t + k * h, x, h)
    slave._x = np.asarray(x, dtype=float)
    plant_outputs(slave)


def plant_outputs(slave):
    """The outputs of an ``RRRPlant`` slave's state, by numpy (solver's IK, J_q, the energy)."""
    X, dX = slave._x[:3], slave._x[3:]
    q = ik(slave._model, X, int(slave.posture))
    dq = joint_velocity_jacobian(slave._model, X, q) @ dX
    slave.q1, slave.q2, slave.q3 = (float(v) for v in q)
    slave.dq1, slave.dq2, slave.dq3 = (float(v) for v in dq)
    slave.x_true, slave.y_true, slave.phi_true = (float(v) for v in X)
    slave.energy = float(total_energy(slave._params, slave._model, X, dX, int(slave.posture)))


def controller_step(slave, t, dt):
    """The numpy step of a ``ComputedTorqueController`` slave at ``t``."""
    traj, model = slave._traj, slave._model
    X_d, _, _ = circle_task(traj, t)
    q_d, dq_d, ddq_d = circle_joint(traj, model, t)
    slave.x_ref, slave.y_ref, slave.phi_ref_out = (float(v) for v in X_d)
    slave.q1_ref, slave.q2_ref, slave.q3_ref = (float(v) for v in q_d)
    q = np.array([slave.q1, slave.q2, slave.q3])
    dq = np.array([slave.dq1, slave.dq2, slave.dq3])
    X = np.array([slave.x, slave.y, slave.phi])
    q_X = q + wrap(ik(model, X, int(slave.posture)) - q)        # q_X next to q (2 pi turns)
    gains = slave._gains
    v = ddq_d + gains.kd * (dq_d - dq) + gains.kp * wrap(q_d - q)
    tau = inverse_joint(slave._params, model, q_X, dq, v, X)
    slave.tau1, slave.tau2, slave.tau3 = (float(v) for v in tau)
