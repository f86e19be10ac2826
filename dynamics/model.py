r"""Rigid-body dynamics of the planar 3-RRR (paper eqs. 5-7).

The constant data are split pinocchio-style: :class:`solver.Manipulator` is the
geometry, :class:`DynamicParameters` the inertial, friction and gravity data;
every algorithm below is a plain function of ``(params, model, state...)``.

Bodies
------
* proximal link ``i``: rotates about the motor ``M_i`` with the motor angle
  ``q_i``; centre of mass at ``M_i + r_p,i (cos q_i, sin q_i)``;
* motor rotor ``i``: rotates with ``q_i`` (inertia reflected to the link side);
* distal link ``i``: planar motion from the elbow ``D_i`` to the platform joint
  ``A_i``; centre of mass at ``D_i + (r_d,i / l2_i) (A_i - D_i)``, angle
  ``psi_i = atan2(A_i - D_i)``;
* platform: centre of mass at ``P + R(phi) c`` with ``c`` in the platform frame.

Derivation (minimal coordinates ``X = (x, y, phi)``)
----------------------------------------------------
Write ``L_i = A_i - D_i``, ``e_i = (cos q_i, sin q_i)``, ``n_i = (-sin q_i, cos q_i)``,
``A_i = P + R(phi) b_i`` and ``v_A = dP + dphi E R b_i`` (``E`` the +90 deg rotation).
Differentiating ``|L_i|^2 = l2_i^2`` once and twice:

.. math::

   \dot q_i = \frac{L_i\cdot v_{A_i}}{l_{1i}\, L_i\cdot n_i}, \qquad
   \ddot q_i = \frac{L_i\cdot a_{A_i} + l_{1i}\dot q_i^2\, L_i\cdot e_i + |\dot L_i|^2}
                    {l_{1i}\, L_i\cdot n_i}

(the first is ``dq = -K^{-1} J dX`` of eq. 3; ``J_q = -K^{-1} J`` below).  The
distal link turns at ``omega_i = (L_i x dL_i) / l2_i^2`` and accelerates at
``alpha_i = (L_i x ddL_i) / l2_i^2``; its centre of mass, an affine combination of
``D_i`` and ``A_i``, moves at ``(1 - s) v_D + s v_A``.  So every body velocity
is linear in ``dX`` and every body acceleration is affine in ``ddX``:

.. math::  v_b = V_b(X)\,\dot X, \qquad a_b = V_b(X)\,\ddot X + \beta_b(X, \dot X),

where ``beta_b`` (the velocity-product acceleration) follows from the formulas
above with ``ddX = 0``: no numerical differentiation anywhere.  Stacking the 21
scalar rows (2 translations and 1 rotation of the platform and of each of the
six links; the rotor rides on the proximal rotation row) with weights ``w``
(masses and centroidal inertias), the principle of virtual power (Kane) gives

.. math::

   M_X \ddot X + C_X \dot X + G_X + F_X = J_q^T \tau, \quad
   M_X = V^T W V, \quad C_X\dot X = V^T W \beta, \quad
   G_X = -V^T W \gamma, \quad F_X = V_f^T B V_f \dot X,

``gamma`` the gravity acceleration of each translation row (zero for
rotations), ``V_f`` the Jacobian of the 9 joint rates that carry viscous
friction (3 motors, 3 elbows, 3 platform joints), ``B`` their coefficients.
This is exact for planar rigid bodies (there is no gyroscopic term in the plane).

Joint-space form (eq. 5)
------------------------
With ``J_x = dX/dq = J_q^{-1}`` and, at ``ddq = 0``, ``ddX_0 = -J_x ddq_0(X, dX)``
(``ddq_0`` the velocity-product part of the joint acceleration above),
multiplying the task-space equation by ``J_x^T`` (``J_x^T J_q^T = I``) gives

.. math::

   \tau = M(q)\ddot q + C(q, \dot q)\dot q + G(q) + F(q, \dot q), \quad
   M = J_x^T M_X J_x, \quad C\dot q = J_x^T (M_X \ddot X_0 + C_X \dot X),
   \quad G = J_x^T G_X, \quad F = J_x^T F_X.

``M``, ``C``, ``G`` are functions of the active joints only in principle; in
practice they need the pose ``X`` that the direct kinematics delivers (paper
Fig. 2 and 3), so every joint-space function takes ``(q, X)`` as inputs and
checks that they assemble.

Shapes and units
----------------
Poses ``X`` (..., 3) in m, m, rad; motor angles ``q`` (..., 3) in rad; rates
per second, accelerations per second squared; torques ``tau`` (..., 3) in N m.
Task-space generalised forces are ``(F_x, F_y, torque)`` in N, N, N m.
All functions broadcast over leading batch dimensions.  Near a type-2
singularity (``det K = 0``, a leg stretched or folded) ``J_q`` is unbounded and
near a type-1 singularity (``det J = 0``) ``J_x`` is; neither is guarded.

Implementation
--------------
The inertia, Coriolis, gravity and friction terms and the forward and inverse
dynamics, in task and in joint space, run compiled kernels
(:mod:`dynamics._kernel`, numba) that evaluate the formulas above for one
configuration at a time with scalar code, a batch as a loop over the same row
function and a single configuration as a batch of one (a few microseconds per
call instead of ~200).  The numpy implementation of the same formulas is kept
as the reference (the ``_reference_*`` functions); the kernels are tested
against it to 1e-12 relative (``tests/test_dynamics_kernel.py``), and any input
a kernel refuses (non-finite, outside the tool space, loop not closed, singular)
is handed to the reference, so the errors are those documented below.  The
energies and the kinematic helpers are numpy only; the plant FMU's per-step
outputs (``q``, ``dq = J_q dX`` and the total energy of a task-space state) have
their own compiled kernel (:func:`dynamics._kernel.plant_outputs`, tested
against :func:`total_energy` and :func:`joint_velocity_jacobian`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import NamedTuple

import numpy as np

from solver import Manipulator, ik
from solver._checks import SolverInputError, as_array

from . import _kernel as _k

__all__ = [
    "DynamicParameters", "ParameterError",
    # kinematics used by the dynamics
    "joint_velocity_jacobian", "pose_velocity_jacobian", "joint_accelerations",
    "passive_joint_angles", "passive_joint_rates",
    # task space
    "mass_matrix_task", "coriolis_task", "gravity_task", "friction_task",
    "generalized_force_task", "forward_dynamics_task", "inverse_dynamics_task",
    # joint space (eq. 5 and 7)
    "mass_matrix", "coriolis", "gravity", "friction", "forward_dynamics", "inverse_dynamics",
    # energy
    "kinetic_energy", "potential_energy", "total_energy", "friction_power",
]

#: A joint-space call refuses ``(q, X)`` whose loop residual max_i |F_i| / l2_i^2
#: exceeds this (the pose does not belong to the joints).
ASSEMBLY_TOL = 1e-6


class ParameterError(ValueError):
    """A dynamic parameter is invalid (wrong shape, non-finite, negative mass...)."""


# ----------------------------------------------------------------------------- parameters
# Where the default numbers come from (all SI):
#: Density of aluminium alloy 6061, kg/m^3.
ALUMINIUM_DENSITY = 2700.0
#: Links: round aluminium tube, 25 mm outer diameter, 2 mm wall, 0.6 m long (Table 1).
TUBE_OUTER, TUBE_WALL, LINK_LENGTH = 0.025, 0.002, 0.6
_TUBE_AREA = math.pi / 4.0 * (TUBE_OUTER ** 2 - (TUBE_OUTER - 2 * TUBE_WALL) ** 2)   # 1.445e-4 m^2
_LINK_MASS = ALUMINIUM_DENSITY * _TUBE_AREA * LINK_LENGTH                             # 0.2341 kg
_LINK_INERTIA = _LINK_MASS * LINK_LENGTH ** 2 / 12.0                                  # 7.023e-3 kg m^2
#: Platform: aluminium plate, equilateral triangle of side 0.3 m (Table 1), 6 mm thick.
PLATE_SIDE, PLATE_THICKNESS = 0.3, 0.006
_PLATE_MASS = ALUMINIUM_DENSITY * math.sqrt(3.0) / 4.0 * PLATE_SIDE ** 2 * PLATE_THICKNESS   # 0.6313 kg
_PLATE_INERTIA = _PLATE_MASS * PLATE_SIDE ** 2 / 12.0                                 # 4.735e-3 kg m^2
#: Motor: 200 W class AC servo, rotor inertia 0.2 kg cm^2 (typical datasheet value of that
#: class), through a 10:1 gear; reflected to the link side N^2 J_m.
ROTOR_INERTIA, GEAR_RATIO = 0.2e-4, 10.0
_ROTOR_REFLECTED = GEAR_RATIO ** 2 * ROTOR_INERTIA                                     # 2.0e-3 kg m^2


def _vector(name: str, value, shape: tuple[int, ...], *, lower: float | None = None,
            strict: bool = False, unit: str = "") -> np.ndarray:
    """Freeze ``value`` as a read-only float array of ``shape`` or raise ParameterError."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: expected numbers of shape {shape}{unit}, got {value!r}") from exc
    if arr.ndim == 0 and shape:
        arr = np.full(shape, float(arr))
    if arr.shape != shape:
        raise ParameterError(f"{name}: expected shape {shape} (or a scalar){unit}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name}: expected finite numbers{unit}, got {arr.tolist()}")
    if lower is not None:
        bad = arr <= lower if strict else arr < lower
        if np.any(bad):
            what = "positive" if strict else "non-negative"
            raise ParameterError(f"{name}: expected {what} values{unit}, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class DynamicParameters:
    """Inertial, friction and gravity data of a 3-RRR (constant, like the geometry).

    Per-leg fields take a scalar (same for the three legs) or shape (3,).  The
    defaults are estimates for Table 1's geometry (0.6 m links, 0.3 m platform
    side), computed in this module from stated assumptions:

    * links: aluminium tube (density 2700 kg/m^3), 25 mm outer diameter, 2 mm
      wall, 0.6 m long: mass 0.2341 kg, slender-rod centroidal inertia
      ``m l^2 / 12 = 7.023e-3`` kg m^2, centre of mass at mid-length 0.3 m
      (joint hardware neglected);
    * platform: 6 mm aluminium plate, equilateral triangle of side 0.3 m:
      mass 0.6313 kg, polar inertia about the centroid ``m a^2 / 12 =
      4.735e-3`` kg m^2, centre of mass at the tool point (the centroid);
    * motors: a 200 W class AC servo with rotor inertia 0.2 kg cm^2 (order of
      magnitude of such datasheets) behind a 10:1 gear, reflected to the link
      side ``N^2 J_m = 2.0e-3`` kg m^2 (gear inertia neglected);
    * viscous friction: 0.02 N m s/rad at each motor (reflected, an
      order-of-magnitude estimate for a small geared servo), 1e-3 N m s/rad at
      each passive ball-bearing joint; both to be identified on a real robot;
    * gravity (0, 0): the robot moves in a horizontal plane.

    Parameters
    ----------
    mass_proximal : float or array_like (3,)
        Mass of proximal link ``M_i D_i``, kg (> 0).
    inertia_proximal : float or array_like (3,)
        Its centroidal moment of inertia about the z axis, kg m^2 (>= 0).
    com_proximal : float or array_like (3,)
        Distance of its centre of mass from the motor axis along ``M_i -> D_i``, m.
    mass_distal, inertia_distal : float or array_like (3,)
        Same for distal link ``D_i A_i``, kg and kg m^2.
    com_distal : float or array_like (3,)
        Distance of its centre of mass from the elbow along ``D_i -> A_i``, m.
    mass_platform : float
        Platform mass, kg (> 0).
    inertia_platform : float
        Platform moment of inertia about its centre of mass, kg m^2 (>= 0).
    com_platform : array_like (2,)
        Platform centre of mass in the platform frame, relative to the tool point ``P``, m.
    rotor_inertia : float or array_like (3,)
        Motor rotor (and gear) inertia reflected to the link side, kg m^2 (>= 0).
    friction_active : float or array_like (3,)
        Viscous friction at the motors (reflected), N m s/rad (>= 0).
    friction_elbow : float or array_like (3,)
        Viscous friction at the passive elbow joints ``D_i`` (relative rate
        ``psi_i - q_i``), N m s/rad (>= 0).
    friction_platform : float or array_like (3,)
        Viscous friction at the passive platform joints ``A_i`` (relative rate
        ``phi - psi_i``), N m s/rad (>= 0).
    gravity : array_like (2,)
        Gravity acceleration in the plane of motion, m/s^2; ``(0, 0)`` for a
        horizontal robot, ``(0, -9.81)`` for a vertical one with +y up.

    Raises
    ------
    ParameterError
        (a ValueError) naming the field, its value and the expectation.
    """

    mass_proximal: np.ndarray = _LINK_MASS
    inertia_proximal: np.ndarray = _LINK_INERTIA
    com_proximal: np.ndarray = LINK_LENGTH / 2.0
    mass_distal: np.ndarray = _LINK_MASS
    inertia_distal: np.ndarray = _LINK_INERTIA
    com_distal: np.ndarray = LINK_LENGTH / 2.0
    mass_platform: float = _PLATE_MASS
    inertia_platform: float = _PLATE_INERTIA
    com_platform: np.ndarray = (0.0, 0.0)
    rotor_inertia: np.ndarray = _ROTOR_REFLECTED
    friction_active: np.ndarray = 0.02
    friction_elbow: np.ndarray = 1e-3
    friction_platform: np.ndarray = 1e-3
    gravity: np.ndarray = field(default=(0.0, 0.0))

    _SPEC = {  # field: (shape, lower bound, strict, unit)
        "mass_proximal": ((3,), 0.0, True, " in kg"),
        "inertia_proximal": ((3,), 0.0, False, " in kg m^2"),
        "com_proximal": ((3,), None, False, " in m"),
        "mass_distal": ((3,), 0.0, True, " in kg"),
        "inertia_distal": ((3,), 0.0, False, " in kg m^2"),
        "com_distal": ((3,), None, False, " in m"),
        "mass_platform": ((), 0.0, True, " in kg"),
        "inertia_platform": ((), 0.0, False, " in kg m^2"),
        "com_platform": ((2,), None, False, " in m"),
        "rotor_inertia": ((3,), 0.0, False, " in kg m^2"),
        "friction_active": ((3,), 0.0, False, " in N m s/rad"),
        "friction_elbow": ((3,), 0.0, False, " in N m s/rad"),
        "friction_platform": ((3,), 0.0, False, " in N m s/rad"),
        "gravity": ((2,), None, False, " in m/s^2"),
    }

    def __post_init__(self):
        for f in fields(self):
            shape, lower, strict, unit = self._SPEC[f.name]
            arr = _vector(f.name, getattr(self, f.name), shape, lower=lower, strict=strict, unit=unit)
            object.__setattr__(self, f.name, float(arr) if shape == () else arr)

    # -------------------------------------------------------------- helpers
    def with_scaled_masses(self, factor: float, *, rotor: bool = False) -> "DynamicParameters":
        """A copy with every link and platform mass (and centroidal inertia) times ``factor``.

        Models a uniformly denser or lighter structure of the same shape, e.g.
        ``factor = 1.2`` for "masses off by +20 %".  Centres of mass, friction and
        gravity are unchanged; the rotor inertia too unless ``rotor`` is true
        (it is a motor datasheet value, not part of the structure).

        Parameters
        ----------
        factor : float
            Positive scale factor.
        rotor : bool
            Also scale ``rotor_inertia``.

        Raises
        ------
        ParameterError
            ``factor`` not a positive finite number.
        """
        if not (isinstance(factor, (int, float, np.floating, np.integer)) and np.isfinite(factor)
                and factor > 0):
            raise ParameterError(f"factor: expected a positive finite number, got {factor!r}")
        keys = ["mass_proximal", "inertia_proximal", "mass_distal", "inertia_distal",
                "mass_platform", "inertia_platform"] + (["rotor_inertia"] if rotor else [])
        return replace(self, **{k: np.asarray(getattr(self, k)) * float(factor) for k in keys})

    def to_dict(self) -> dict:
        """JSON-ready description (floats and lists of floats)."""
        return {f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
                for f in fields(self)}

    @classmethod
    def from_dict(cls, data: dict) -> "DynamicParameters":
        """Inverse of :meth:`to_dict`; missing keys take the defaults, unknown keys are refused."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ParameterError(f"parameters: unknown keys {unknown}, expected a subset of {sorted(names)}")
        return cls(**data)

    def __eq__(self, other):
        if not isinstance(other, DynamicParameters):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None

    @property
    def total_mass(self) -> float:
        """Mass of all moving bodies, kg."""
        return float(np.sum(self.mass_proximal) + np.sum(self.mass_distal) + self.mass_platform)


# ----------------------------------------------------------------------------- argument checks
def _check(params, model):
    if not isinstance(params, DynamicParameters):
        raise SolverInputError(f"params: expected a DynamicParameters, got {type(params).__name__}")
    if not isinstance(model, Manipulator):
        raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")


def _check_model(model):
    if not isinstance(model, Manipulator):
        raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")


def _broadcast(**arrays):
    """Broadcast the leading dimensions of (..., k) arrays, naming them on failure."""
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


# ----------------------------------------------------------------------------- kinematics core
class _Geom(NamedTuple):
    """Configuration-dependent quantities of ``(X, q)``; per-leg arrays are (..., 3)."""

    cq: np.ndarray      # cos q_i
    sq: np.ndarray      # sin q_i
    Lx: np.ndarray      # L_i = A_i - D_i
    Ly: np.ndarray
    Rbx: np.ndarray     # R(phi) b_i
    Rby: np.ndarray
    Rcx: np.ndarray     # R(phi) c, platform centre of mass offset, (...)
    Rcy: np.ndarray
    den: np.ndarray     # l1_i L_i . n_i  (= -K_ii / 2)
    Jq: np.ndarray      # dq/dX = -K^-1 J, (..., 3, 3)


def _geometry(model, com_platform, X, q) -> _Geom:
    c, s = np.cos(X[..., 2]), np.sin(X[..., 2])
    b = model.platform
    c1, s1 = c[..., None], s[..., None]
    Rbx = c1 * b[:, 0] - s1 * b[:, 1]
    Rby = s1 * b[:, 0] + c1 * b[:, 1]
    cq, sq = np.cos(q), np.sin(q)
    l1 = model.l1
    Lx = X[..., 0:1] + Rbx - model.motors[:, 0] - l1 * cq
    Ly = X[..., 1:2] + Rby - model.motors[:, 1] - l1 * sq
    den = l1 * (Ly * cq - Lx * sq)
    Jq = np.stack([Lx, Ly, Ly * Rbx - Lx * Rby], axis=-1) / den[..., None]
    Rcx = c * com_platform[0] - s * com_platform[1]
    Rcy = s * com_platform[0] + c * com_platform[1]
    return _Geom(cq, sq, Lx, Ly, Rbx, Rby, Rcx, Rcy, den, Jq)


def _assembly_check(model, g: _Geom):
    res = np.max(np.abs(g.Lx ** 2 + g.Ly ** 2 - model.l2 ** 2) / model.l2 ** 2, axis=-1)
    if np.any(res > ASSEMBLY_TOL):
        raise SolverInputError(
            f"X: expected the pose of the joints q (direct kinematics), got loop residual "
            f"max|F_i|/l2^2 = {float(np.max(res)):.3g} > {ASSEMBLY_TOL:g}")


def _constants(params) -> dict:
    """Per-parameter constant vectors, computed once and cached on the (frozen) parameters.

    ``w`` (21,): weights of the velocity rows -- platform (x, y, rot), proximal
    x3 / y3 / rot3 (rotor included), distal x3 / y3 / rot3; ``gamma`` (21,): gravity
    acceleration of each row (zero on rotation rows); ``b`` (9,): viscous
    coefficients of the motors, elbows and platform joints; ``m`` (7,): masses of
    the platform, proximal and distal links.
    """
    k = params.__dict__.get("_constants")
    if k is None:
        gx, gy = params.gravity
        z3, o3 = np.zeros(3), np.ones(3)
        k = {
            "w": np.concatenate([[params.mass_platform, params.mass_platform, params.inertia_platform],
                                 params.mass_proximal, params.mass_proximal,
                                 params.inertia_proximal + params.rotor_inertia,
                                 params.mass_distal, params.mass_distal, params.inertia_distal]),
            "gamma": np.concatenate([[gx, gy, 0.0], gx * o3, gy * o3, z3, gx * o3, gy * o3, z3]),
            "b": np.concatenate([params.friction_active, params.friction_elbow, params.friction_platform]),
            "m": np.concatenate([[params.mass_platform], params.mass_proximal, params.mass_distal]),
        }
        for v in k.values():
            v.setflags(write=False)
        object.__setattr__(params, "_constants", k)
    return k


def _velocity_rows(params, model, g: _Geom):
    """Jacobian V (..., 21, 3) of the 21 body velocity rows w.r.t. dX, and the distal W (..., 3, 3)."""
    Jq = g.Jq
    lead = Jq.shape[:-2]
    one, zero = np.ones(lead + (3,)), np.zeros(lead + (3,))
    # platform centre of mass
    Pc = np.stack([np.stack([one[..., 0], zero[..., 0], -g.Rcy], -1),
                   np.stack([zero[..., 0], one[..., 0], g.Rcx], -1),
                   np.stack([zero[..., 0], zero[..., 0], one[..., 0]], -1)], axis=-2)
    rp = params.com_proximal
    prox_x = (-rp * g.sq)[..., None] * Jq
    prox_y = (rp * g.cq)[..., None] * Jq
    # platform joints A_i and elbows D_i
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


class _Motion(NamedTuple):
    """Velocities and velocity-product accelerations (ddX = 0) for a given dX."""

    v: np.ndarray        # (..., 21) body velocity rows
    beta: np.ndarray     # (..., 21) body accelerations at ddX = 0
    dq: np.ndarray       # (..., 3) motor rates
    ddq0: np.ndarray     # (..., 3) motor accelerations at ddX = 0
    omega: np.ndarray    # (..., 3) distal link angular rates


def _motion(params, model, g: _Geom, dX) -> _Motion:
    # dq, ddq0 and omega are pure kinematics; only the centre-of-mass rows read params.
    dx, dy, dphi = dX[..., 0:1], dX[..., 1:2], dX[..., 2:3]
    dq = np.einsum("...ij,...j->...i", g.Jq, dX)
    l1, l2sq = model.l1, model.l2 ** 2
    vAx, vAy = dx - dphi * g.Rby, dy + dphi * g.Rbx
    vDx, vDy = -l1 * g.sq * dq, l1 * g.cq * dq
    dLx, dLy = vAx - vDx, vAy - vDy
    w2 = dphi * dphi
    aAx, aAy = -w2 * g.Rbx, -w2 * g.Rby
    dq2 = dq * dq
    ddq0 = (g.Lx * aAx + g.Ly * aAy + l1 * dq2 * (g.Lx * g.cq + g.Ly * g.sq) + dLx * dLx + dLy * dLy) / g.den
    aDx = l1 * (-g.sq * ddq0 - g.cq * dq2)
    aDy = l1 * (g.cq * ddq0 - g.sq * dq2)
    ddLx, ddLy = aAx - aDx, aAy - aDy
    omega = (g.Lx * dLy - g.Ly * dLx) / l2sq
    alpha = (g.Lx * ddLy - g.Ly * ddLx) / l2sq
    rp, sd = params.com_proximal, params.com_distal / model.l2
    w = dphi[..., 0]
    v = np.concatenate([
        np.stack([dx[..., 0] - w * g.Rcy, dy[..., 0] + w * g.Rcx, w], -1),
        -rp * g.sq * dq, rp * g.cq * dq, dq,
        vDx + sd * dLx, vDy + sd * dLy, omega], axis=-1)
    w2 = w2[..., 0]
    beta = np.concatenate([
        np.stack([-w2 * g.Rcx, -w2 * g.Rcy, np.zeros_like(w2)], -1),
        rp * (-g.sq * ddq0 - g.cq * dq2), rp * (g.cq * ddq0 - g.sq * dq2), ddq0,
        aDx + sd * ddLx, aDy + sd * ddLy, alpha], axis=-1)
    return _Motion(v, beta, dq, ddq0, omega)


def _friction_rows(params, g: _Geom, W):
    """Jacobian (..., 9, 3) of the friction-carrying joint rates and their coefficients (9,)."""
    e3 = np.zeros(3)
    e3[2] = 1.0
    return np.concatenate([g.Jq, W - g.Jq, e3 - W], axis=-2), _constants(params)["b"]


def _matT_vec(A, v):
    return np.einsum("...ji,...j->...i", A, v)


def _mat_vec(A, v):
    return np.einsum("...ij,...j->...i", A, v)


class _TaskTerms(NamedTuple):
    MX: np.ndarray     # (..., 3, 3)
    CX: np.ndarray     # (..., 3)  C_X dX
    GX: np.ndarray     # (..., 3)
    FX: np.ndarray     # (..., 3)
    Jq: np.ndarray     # (..., 3, 3)
    motion: _Motion


def _task_terms(params, model, X, q, dX) -> _TaskTerms:
    g = _geometry(model, params.com_platform, X, q)
    V, W = _velocity_rows(params, model, g)
    w = _constants(params)["w"]
    WV = w[:, None] * V
    MX = np.swapaxes(V, -1, -2) @ WV
    mo = _motion(params, model, g, dX)
    CX = _matT_vec(WV, mo.beta)
    GX = -_matT_vec(WV, np.broadcast_to(_constants(params)["gamma"], mo.beta.shape))
    Vf, b = _friction_rows(params, g, W)
    FX = _matT_vec(Vf, b * _mat_vec(Vf, dX))
    return _TaskTerms(MX, CX, GX, FX, g.Jq, mo)


class _JointTerms(NamedTuple):
    M: np.ndarray      # (..., 3, 3)
    C: np.ndarray      # (..., 3)  C(q, dq) dq
    G: np.ndarray      # (..., 3)
    F: np.ndarray      # (..., 3)
    Jx: np.ndarray     # (..., 3, 3)
    dX: np.ndarray     # (..., 3)


def _joint_terms(params, model, q, dq, X, check=True) -> _JointTerms:
    g = _geometry(model, params.com_platform, X, q)
    if check:
        _assembly_check(model, g)
    Jx = np.linalg.inv(g.Jq)
    dX = _mat_vec(Jx, dq)
    V, W = _velocity_rows(params, model, g)
    w = _constants(params)["w"]
    WV = w[:, None] * V
    VJ = V @ Jx                                   # body rows w.r.t. dq
    M = np.swapaxes(VJ, -1, -2) @ (w[:, None] * VJ)
    mo = _motion(params, model, g, dX)
    ddX0 = -_mat_vec(Jx, mo.ddq0)                 # pose acceleration at ddq = 0
    beta_q = mo.beta + _mat_vec(V, ddX0)          # body accelerations at ddq = 0
    C = _matT_vec(Jx, _matT_vec(WV, beta_q))
    G = -_matT_vec(Jx, _matT_vec(WV, np.broadcast_to(_constants(params)["gamma"], beta_q.shape)))
    Vf, b = _friction_rows(params, g, W)
    F = _matT_vec(Jx, _matT_vec(Vf, b * _mat_vec(Vf, dX)))
    return _JointTerms(M, C, G, F, Jx, dX)


# ----------------------------------------------------------------------------- compiled fast path
# Every public dynamics function below runs one compiled kernel of :mod:`dynamics._kernel` over a
# batch of rows; a single configuration (float64 arrays of shape (3,)) is a batch of one and skips
# the numpy argument checks, which the kernel replaces by its own (finite inputs, inverse
# kinematics, loop closure, non-singular matrices).  Whatever the kernel refuses goes to the numpy
# reference (``_reference_*`` below), which raises the documented error or gives its answer.
_F8 = np.dtype(np.float64)


def _single(arrays, n=3) -> bool:
    """True if every array is a float64 ndarray of shape ``(n,)`` (the single-configuration path).

    Memory layout is not checked: numba compiles (once, then caches) a variant
    of a kernel for read-only or strided arguments when it first meets one.
    """
    for a in arrays:
        if type(a) is not np.ndarray or a.shape != (n,) or a.dtype is not _F8:
            return False
    return True


def _rows(a, n):
    """A fresh C-contiguous float64 copy of ``a`` (..., k) as ``(n, k)`` rows."""
    return np.array(a, dtype=np.float64, order="C").reshape(n, a.shape[-1])


def _posture_bits(posture) -> int:
    """``posture - 1`` (the elbow bits) for a plain integer posture 1..8, else -1."""
    if (type(posture) is int or isinstance(posture, np.integer)) and 1 <= posture <= 8:
        return int(posture) - 1
    return -1


def _kernel_model(model) -> np.ndarray:
    """The packed geometry of :mod:`dynamics._kernel`, cached on the (frozen) model."""
    G = model.__dict__.get("_dynamics_kernel_pack")
    if G is None:
        G = _k.pack_model(model.motors, model.l1, model.l2, model.platform)
        object.__setattr__(model, "_dynamics_kernel_pack", G)
    return G


def _kernel_params(params) -> np.ndarray:
    """The packed parameters of :mod:`dynamics._kernel`, cached on the (frozen) parameters."""
    P = params.__dict__.get("_kernel_pack")
    if P is None:
        c = _constants(params)
        P = _k.pack_params(params.com_proximal, params.com_distal, c["w"], c["b"], params.gravity,
                           params.com_platform)
        object.__setattr__(params, "_kernel_pack", P)
    return P


def _plant_pack(params, model) -> np.ndarray:
    """Packed constants ``K = (G, P)`` (58,) of :func:`dynamics._kernel.plant_step` (the plant FMU)."""
    return np.concatenate([_kernel_model(model), _kernel_params(params)])


def _out(mode, lead, n):
    """Result array ``lead + (3, 3)`` (mass matrices) or ``lead + (3,)`` and its (n, k) row view."""
    k = 9 if mode == _k.MASS else 3
    out = np.empty(lead + ((3, 3) if k == 9 else (3,)))
    return out, out.reshape(n, k)


def _task_eval(params, model, mode, bits, X, dX, U, q=None, single=None):
    """Task-space kernel on arrays ``(..., 3)`` that broadcast; None if the kernel refuses.

    ``q`` is read when ``bits < 0``, else computed by the kernel's inverse
    kinematics; ``single``: whether the caller has seen a single configuration.
    """
    if single is None:
        single = _single((X, dX, U)) and (bits >= 0 or _single((q,)))
    if single:
        lead, n = (), 1
        X, dX, U = X.reshape(1, 3), dX.reshape(1, 3), U.reshape(1, 3)
        q = np.empty((1, 3)) if bits >= 0 else q.reshape(1, 3)
    else:
        try:
            arrs = np.broadcast_arrays(X, dX, U, *(() if bits >= 0 else (q,)))
        except ValueError:
            return None
        lead = arrs[0].shape[:-1]
        if arrs[0].shape[-1:] != (3,):
            return None
        n = math.prod(lead)
        X, dX, U = (_rows(a, n) for a in arrs[:3])
        q = np.empty((n, 3)) if bits >= 0 else _rows(arrs[3], n)
    out, rows = _out(mode, lead, n)
    st = _k.task_batch(_kernel_model(model), _kernel_params(params), X, dX, U, q, bits, mode, rows)
    return out if st == _k.OK else None


def _task_kernel(params, model, mode, posture, **arrays):
    """A public task-space function: ``arrays`` are its arguments in order, ``X`` first.

    Checks as the reference does (:func:`_task_args`) unless it is a single
    configuration; None if the kernel refuses (the caller then runs the reference).
    """
    _check(params, model)
    bits = _posture_bits(posture)
    vals = tuple(arrays.values())
    q = None
    single = bits >= 0 and _single(vals)
    if not single:
        vals = tuple(_broadcast(**{k: as_array(k, v) for k, v in arrays.items()}))
        if bits < 0:
            q = _ik(model, vals[0], posture)
    X = vals[0]
    dX = vals[1] if len(vals) > 1 else X       # unused by the modes without it
    U = vals[2] if len(vals) > 2 else X
    return _task_eval(params, model, mode, bits, X, dX, U, q, single)


def _joint_eval(params, model, mode, q, dq, X, U, check=True, single=None):
    """Joint-space kernel on arrays ``(..., 3)`` that broadcast; None if the kernel refuses.

    ``single``: whether the caller has seen a single configuration.
    """
    if single is None:
        single = _single((q, dq, X, U))
    if single:
        lead, n = (), 1
        q, dq, X, U = q.reshape(1, 3), dq.reshape(1, 3), X.reshape(1, 3), U.reshape(1, 3)
    else:
        try:
            arrs = np.broadcast_arrays(q, dq, X, U)
        except ValueError:
            return None
        lead = arrs[0].shape[:-1]
        if arrs[0].shape[-1:] != (3,):
            return None
        n = math.prod(lead)
        q, dq, X, U = (_rows(a, n) for a in arrs)
    out, rows = _out(mode, lead, n)
    st = _k.joint_batch(_kernel_model(model), _kernel_params(params), q, dq, X, U,
                        ASSEMBLY_TOL if check else math.inf, mode, rows)
    return out if st == _k.OK else None


def _joint_kernel(params, model, mode, **arrays):
    """A public joint-space function: ``arrays`` are its arguments in order (``q``, ``dq``, ``X``
    and ``tau`` or ``ddq``); checks as :func:`_joint_args` unless it is a single configuration."""
    _check(params, model)
    single = _single(arrays.values())
    if not single:
        arrays = dict(zip(arrays, _joint_args(params, model, **arrays)))
    q = arrays["q"]
    return _joint_eval(params, model, mode, q, arrays.get("dq", q), arrays["X"],
                       arrays.get("tau", arrays.get("ddq", q)), True, single)


# ----------------------------------------------------------------------------- public kinematics
def joint_velocity_jacobian(model: Manipulator, X, q) -> np.ndarray:
    """``J_q = dq/dX = -K^{-1} J`` (eq. 3 solved for the motor rates).

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles of the same configurations, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``dq = J_q dX``; columns x, y in rad/m, column phi dimensionless.
    """
    _check_model(model)
    X, q = _broadcast(X=as_array("X", X), q=as_array("q", q))
    return _geometry(model, (0.0, 0.0), X, q).Jq


def pose_velocity_jacobian(model: Manipulator, X, q) -> np.ndarray:
    """``J_x = dX/dq = -J^{-1} K``, the inverse of :func:`joint_velocity_jacobian`.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``dX = J_x dq``; rows x, y in m/rad, row phi dimensionless.  Unbounded
        at a type-1 singularity (``det J = 0``).
    """
    return np.linalg.inv(joint_velocity_jacobian(model, X, q))


def joint_accelerations(model: Manipulator, X, q, dX, ddX) -> np.ndarray:
    """Motor accelerations of a platform motion (exact second-order velocity model).

    ``ddq = J_q ddX + ddq_0(X, dX)`` with ``ddq_0`` from differentiating the
    loop constraints twice (module docstring).

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Configuration (pose m, m, rad; motor angles rad).
    dX : array_like, shape (..., 3)
        Pose rates, m/s, m/s, rad/s.
    ddX : array_like, shape (..., 3)
        Pose accelerations, m/s^2, m/s^2, rad/s^2.

    Returns
    -------
    ndarray, shape (..., 3)
        ``ddq`` in rad/s^2.
    """
    _check_model(model)
    X, q, dX, ddX = _broadcast(X=as_array("X", X), q=as_array("q", q), dX=as_array("dX", dX),
                               ddX=as_array("ddX", ddX))
    params = _KINEMATIC_ONLY
    g = _geometry(model, params.com_platform, X, q)
    mo = _motion(params, model, g, dX)
    return _mat_vec(g.Jq, ddX) + mo.ddq0


def passive_joint_angles(model: Manipulator, X, q) -> np.ndarray:
    """Angles of the six passive joints (the ``q^u`` of eq. 6).

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Pose (m, m, rad) and motor angles (rad) of assembled configurations.

    Returns
    -------
    ndarray, shape (..., 6)
        ``(psi_i - q_i)`` for the elbows ``D_i`` (i = 1..3), then ``(phi - psi_i)``
        for the platform joints ``A_i``, with ``psi_i`` the direction of
        ``A_i - D_i``; rad, wrapped to (-pi, pi].
    """
    _check_model(model)
    X, q = _broadcast(X=as_array("X", X), q=as_array("q", q))
    g = _geometry(model, (0.0, 0.0), X, q)
    psi = np.arctan2(g.Ly, g.Lx)
    rel = np.concatenate([psi - q, X[..., 2:3] - psi], axis=-1)
    return np.pi - np.mod(np.pi - rel, 2.0 * np.pi)


def passive_joint_rates(model: Manipulator, X, q, dX) -> np.ndarray:
    """Rates of the six passive joints of :func:`passive_joint_angles`, rad/s.

    Parameters
    ----------
    model : Manipulator
    X, q : array_like, shape (..., 3)
        Configuration.
    dX : array_like, shape (..., 3)
        Pose rates, m/s, m/s, rad/s.

    Returns
    -------
    ndarray, shape (..., 6)
        ``(omega_i - dq_i)`` then ``(dphi - omega_i)``, ``omega_i`` the distal link rates.
    """
    _check_model(model)
    X, q, dX = _broadcast(X=as_array("X", X), q=as_array("q", q), dX=as_array("dX", dX))
    params = _KINEMATIC_ONLY
    mo = _motion(params, model, _geometry(model, params.com_platform, X, q), dX)
    return np.concatenate([mo.omega - mo.dq, dX[..., 2:3] - mo.omega], axis=-1)


_KINEMATIC_ONLY = DynamicParameters()   # only the geometry-related code paths read it


# ----------------------------------------------------------------------------- task space
def _task_args(params, model, X, posture, **more):
    _check(params, model)
    arrays = {"X": as_array("X", X)}
    arrays.update({k: as_array(k, v) for k, v in more.items()})
    out = _broadcast(**arrays)
    q = _ik(model, out[0], posture)
    return out, q


def mass_matrix_task(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Task-space inertia ``M_X(X)``: kinetic energy ``T = 1/2 dX^T M_X dX``.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    posture : int
        Posture 1..8 (gives the motor angles by inverse kinematics).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Symmetric positive definite; kg (x, y block), kg m (coupling), kg m^2 (phi).

    Raises
    ------
    SolverInputError
        Wrong shapes, non-finite input, a pose outside the posture's tool space.
    """
    out = _task_kernel(params, model, _k.MASS, posture, X=X)
    return _reference_mass_matrix_task(params, model, X, posture) if out is None else out


def coriolis_task(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Task-space Coriolis and centrifugal force ``C_X(X, dX) dX`` (exact, analytic).

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    dX : array_like, shape (..., 3)
        Pose rates, m/s, m/s, rad/s.

    Returns
    -------
    ndarray, shape (..., 3)
        N, N, N m; quadratic in ``dX``.
    """
    out = _task_kernel(params, model, _k.CORIOLIS, posture, X=X, dX=dX)
    return _reference_coriolis_task(params, model, X, dX, posture) if out is None else out


def gravity_task(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Task-space gravity force ``G_X = dV/dX`` (``V`` the potential energy).

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X : array_like, shape (..., 3)
        Poses, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3)
        N, N, N m (zero when ``params.gravity`` is zero).
    """
    out = _task_kernel(params, model, _k.GRAVITY, posture, X=X)
    return _reference_gravity_task(params, model, X, posture) if out is None else out


def friction_task(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Task-space viscous friction force ``F_X = V_f^T B V_f dX`` (opposes the motion).

    ``dX . F_X`` is the power dissipated in the 9 joints (:func:`friction_power`).

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and rate (m/s, m/s, rad/s).

    Returns
    -------
    ndarray, shape (..., 3)
        N, N, N m.
    """
    out = _task_kernel(params, model, _k.FRICTION, posture, X=X, dX=dX)
    return _reference_friction_task(params, model, X, dX, posture) if out is None else out


def generalized_force_task(params: DynamicParameters, model: Manipulator, X, dX, tau,
                           posture=1) -> np.ndarray:
    """Generalised force of the motor torques and friction, ``J_q^T tau - F_X``.

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and its rate.
    tau : array_like, shape (..., 3)
        Motor torques, N m.

    Returns
    -------
    ndarray, shape (..., 3)
        N, N, N m.
    """
    out = _task_kernel(params, model, _k.GENERALIZED, posture, X=X, dX=dX, tau=tau)
    return _reference_generalized_force_task(params, model, X, dX, tau, posture) if out is None else out


def forward_dynamics_task(params: DynamicParameters, model: Manipulator, X, dX, tau,
                          posture=1) -> np.ndarray:
    """Platform acceleration ``ddX = M_X^{-1} (J_q^T tau - F_X - C_X dX - G_X)``.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and rate (m/s, m/s, rad/s).
    tau : array_like, shape (..., 3)
        Motor torques, N m.
    posture : int
        Posture 1..8.

    Returns
    -------
    ndarray, shape (..., 3)
        ``ddX`` in m/s^2, m/s^2, rad/s^2.
    """
    out = _task_kernel(params, model, _k.FORWARD, posture, X=X, dX=dX, tau=tau)
    return _reference_forward_dynamics_task(params, model, X, dX, tau, posture) if out is None else out


def _forward_task(params, model, X, q, dX, tau):
    """``ddX`` of checked arrays (``q`` given), compiled; the numpy reference where the kernel refuses."""
    out = _task_eval(params, model, _k.FORWARD, -1, X, dX, tau, q)
    return _reference_forward_task(params, model, X, q, dX, tau) if out is None else out


def inverse_dynamics_task(params: DynamicParameters, model: Manipulator, X, dX, ddX,
                          posture=1) -> np.ndarray:
    """Motor torques of a platform motion, ``tau = J_x^T (M_X ddX + C_X dX + G_X + F_X)``.

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X, dX, ddX : array_like, shape (..., 3)
        Pose, rate and acceleration (m, rad; per s; per s^2).

    Returns
    -------
    ndarray, shape (..., 3)
        ``tau`` in N m.
    """
    out = _task_kernel(params, model, _k.INVERSE, posture, X=X, dX=dX, ddX=ddX)
    return _reference_inverse_dynamics_task(params, model, X, dX, ddX, posture) if out is None else out


# ----------------------------------------------------------------------------- joint space
def _joint_args(params, model, **arrays):
    _check(params, model)
    return _broadcast(**{k: as_array(k, v) for k, v in arrays.items()})


def mass_matrix(params: DynamicParameters, model: Manipulator, q, X) -> np.ndarray:
    """Joint-space inertia ``M(q) = J_x^T M_X J_x`` of eq. 5.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    q : array_like, shape (..., 3)
        Motor angles, rad.
    X : array_like, shape (..., 3)
        The pose of ``q`` given by the direct kinematics, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Symmetric positive definite, kg m^2.

    Raises
    ------
    SolverInputError
        Wrong shapes, non-finite input, or ``X`` not assembled with ``q``
        (loop residual above :data:`ASSEMBLY_TOL`).
    """
    out = _joint_kernel(params, model, _k.MASS, q=q, X=X)
    return _reference_mass_matrix(params, model, q, X) if out is None else out


def coriolis(params: DynamicParameters, model: Manipulator, q, dq, X) -> np.ndarray:
    """Coriolis and centrifugal torques ``C(q, dq) dq`` of eq. 5 (exact, analytic).

    Parameters
    ----------
    q, dq : array_like, shape (..., 3)
        Motor angles (rad) and rates (rad/s).
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3)
        N m; quadratic in ``dq``.
    """
    out = _joint_kernel(params, model, _k.CORIOLIS, q=q, dq=dq, X=X)
    return _reference_coriolis(params, model, q, dq, X) if out is None else out


def gravity(params: DynamicParameters, model: Manipulator, q, X) -> np.ndarray:
    """Gravity torques ``G(q)`` of eq. 5.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    q : array_like, shape (..., 3)
        Motor angles, rad.
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3)
        N m (zero when ``params.gravity`` is zero).
    """
    out = _joint_kernel(params, model, _k.GRAVITY, q=q, X=X)
    return _reference_gravity(params, model, q, X) if out is None else out


def friction(params: DynamicParameters, model: Manipulator, q, dq, X) -> np.ndarray:
    """Viscous friction of all nine joints seen at the motors, ``F = J_x^T F_X``.

    Equals ``friction_active * dq`` plus the passive joints' share.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    q, dq : array_like, shape (..., 3)
        Motor angles (rad) and rates (rad/s).
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3)
        N m; linear in ``dq``.
    """
    out = _joint_kernel(params, model, _k.FRICTION, q=q, dq=dq, X=X)
    return _reference_friction(params, model, q, dq, X) if out is None else out


def forward_dynamics(params: DynamicParameters, model: Manipulator, q, dq, X, tau) -> np.ndarray:
    """Motor accelerations of eq. 7, ``ddq = M^{-1} (tau - C dq - G - F)``.

    Parameters
    ----------
    params : DynamicParameters
    model : Manipulator
    q, dq : array_like, shape (..., 3)
        Motor angles (rad) and rates (rad/s).
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics (the DK FMU in the co-simulation), m, m, rad.
    tau : array_like, shape (..., 3)
        Motor torques, N m.

    Returns
    -------
    ndarray, shape (..., 3)
        ``ddq`` in rad/s^2.
    """
    out = _joint_kernel(params, model, _k.FORWARD, q=q, dq=dq, X=X, tau=tau)
    return _reference_forward_dynamics(params, model, q, dq, X, tau) if out is None else out


def _forward_joint(params, model, q, dq, X, tau, check=True):
    """``ddq`` of checked arrays, compiled; the numpy reference where the kernel refuses."""
    out = _joint_eval(params, model, _k.FORWARD, q, dq, X, tau, check)
    return _reference_forward_joint(params, model, q, dq, X, tau, check) if out is None else out


def inverse_dynamics(params: DynamicParameters, model: Manipulator, q, dq, ddq, X) -> np.ndarray:
    """Motor torques of eq. 5, ``tau = M ddq + C dq + G + F``.

    Parameters
    ----------
    q, dq, ddq : array_like, shape (..., 3)
        Motor angles (rad), rates (rad/s), accelerations (rad/s^2).
    X : array_like, shape (..., 3)
        Pose of ``q`` from the direct kinematics, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3)
        ``tau`` in N m.
    """
    out = _joint_kernel(params, model, _k.INVERSE, q=q, dq=dq, ddq=ddq, X=X)
    return _reference_inverse_dynamics(params, model, q, dq, ddq, X) if out is None else out


def _inverse_joint(params, model, q, dq, ddq, X, check=True):
    """``tau`` of checked arrays, compiled; the numpy reference where the kernel refuses."""
    out = _joint_eval(params, model, _k.INVERSE, q, dq, X, ddq, check)
    return _reference_inverse_joint(params, model, q, dq, ddq, X, check) if out is None else out


# ----------------------------------------------------------------------------- numpy reference
# The functions above run the compiled kernels of :mod:`dynamics._kernel`; these are the numpy
# implementations of the same formulas they replaced.  They stay as the reference the kernels are
# tested against (tests/test_dynamics_kernel.py), and every fast function hands its call to its
# reference when the kernel refuses it (non-finite input, pose outside the tool space, loop not
# closed, singular matrix), so that errors and edge cases are exactly the reference's.
def _reference_forward_task(params, model, X, q, dX, tau):
    """numpy reference of :func:`_forward_task`."""
    t = _task_terms(params, model, X, q, dX)
    rhs = _matT_vec(t.Jq, tau) - t.FX - t.CX - t.GX
    return np.linalg.solve(t.MX, rhs[..., None])[..., 0]


def _reference_forward_joint(params, model, q, dq, X, tau, check=True):
    """numpy reference of :func:`_forward_joint`."""
    t = _joint_terms(params, model, q, dq, X, check)
    return np.linalg.solve(t.M, (tau - t.C - t.G - t.F)[..., None])[..., 0]


def _reference_inverse_joint(params, model, q, dq, ddq, X, check=True):
    """numpy reference of :func:`_inverse_joint`."""
    t = _joint_terms(params, model, q, dq, X, check)
    return _mat_vec(t.M, ddq) + t.C + t.G + t.F


def _reference_mass_matrix_task(params, model, X, posture=1):
    """numpy reference of :func:`mass_matrix_task` (same arguments, checks and errors)."""
    (X,), q = _task_args(params, model, X, posture)
    return _task_terms(params, model, X, q, np.zeros_like(X)).MX


def _reference_coriolis_task(params, model, X, dX, posture=1):
    """numpy reference of :func:`coriolis_task` (same arguments, checks and errors)."""
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return _task_terms(params, model, X, q, dX).CX


def _reference_gravity_task(params, model, X, posture=1):
    """numpy reference of :func:`gravity_task` (same arguments, checks and errors)."""
    (X,), q = _task_args(params, model, X, posture)
    return _task_terms(params, model, X, q, np.zeros_like(X)).GX


def _reference_friction_task(params, model, X, dX, posture=1):
    """numpy reference of :func:`friction_task` (same arguments, checks and errors)."""
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return _task_terms(params, model, X, q, dX).FX


def _reference_generalized_force_task(params, model, X, dX, tau, posture=1):
    """numpy reference of :func:`generalized_force_task` (same arguments, checks and errors)."""
    (X, dX, tau), q = _task_args(params, model, X, posture, dX=dX, tau=tau)
    t = _task_terms(params, model, X, q, dX)
    return _matT_vec(t.Jq, tau) - t.FX


def _reference_forward_dynamics_task(params, model, X, dX, tau, posture=1):
    """numpy reference of :func:`forward_dynamics_task` (same arguments, checks and errors)."""
    (X, dX, tau), q = _task_args(params, model, X, posture, dX=dX, tau=tau)
    return _reference_forward_task(params, model, X, q, dX, tau)


def _reference_inverse_dynamics_task(params, model, X, dX, ddX, posture=1):
    """numpy reference of :func:`inverse_dynamics_task` (same arguments, checks and errors)."""
    (X, dX, ddX), q = _task_args(params, model, X, posture, dX=dX, ddX=ddX)
    t = _task_terms(params, model, X, q, dX)
    f = _mat_vec(t.MX, ddX) + t.CX + t.GX + t.FX
    # J_x^T f = J_q^{-T} f
    return np.linalg.solve(np.swapaxes(t.Jq, -1, -2), f[..., None])[..., 0]


def _reference_mass_matrix(params, model, q, X):
    """numpy reference of :func:`mass_matrix` (same arguments, checks and errors)."""
    q, X = _joint_args(params, model, q=q, X=X)
    return _joint_terms(params, model, q, np.zeros_like(q), X).M


def _reference_coriolis(params, model, q, dq, X):
    """numpy reference of :func:`coriolis` (same arguments, checks and errors)."""
    q, dq, X = _joint_args(params, model, q=q, dq=dq, X=X)
    return _joint_terms(params, model, q, dq, X).C


def _reference_gravity(params, model, q, X):
    """numpy reference of :func:`gravity` (same arguments, checks and errors)."""
    q, X = _joint_args(params, model, q=q, X=X)
    return _joint_terms(params, model, q, np.zeros_like(q), X).G


def _reference_friction(params, model, q, dq, X):
    """numpy reference of :func:`friction` (same arguments, checks and errors)."""
    q, dq, X = _joint_args(params, model, q=q, dq=dq, X=X)
    return _joint_terms(params, model, q, dq, X).F


def _reference_forward_dynamics(params, model, q, dq, X, tau):
    """numpy reference of :func:`forward_dynamics` (same arguments, checks and errors)."""
    q, dq, X, tau = _joint_args(params, model, q=q, dq=dq, X=X, tau=tau)
    return _reference_forward_joint(params, model, q, dq, X, tau)


def _reference_inverse_dynamics(params, model, q, dq, ddq, X):
    """numpy reference of :func:`inverse_dynamics` (same arguments, checks and errors)."""
    q, dq, ddq, X = _joint_args(params, model, q=q, dq=dq, ddq=ddq, X=X)
    return _reference_inverse_joint(params, model, q, dq, ddq, X)


# ----------------------------------------------------------------------------- energy
def _positions(params, model, X, q):
    """Positions (..., 7, 2) of the platform, proximal and distal centres of mass."""
    g = _geometry(model, params.com_platform, X, q)
    Pc = np.stack([X[..., 0] + g.Rcx, X[..., 1] + g.Rcy], -1)[..., None, :]
    e = np.stack([g.cq, g.sq], -1)
    prox = model.motors + params.com_proximal[:, None] * e
    D = model.motors + model.l1[:, None] * e
    dist = D + (params.com_distal / model.l2)[:, None] * np.stack([g.Lx, g.Ly], -1)
    return np.concatenate([Pc, prox, dist], axis=-2)


def kinetic_energy(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Kinetic energy of the seven bodies and the rotors.

    Computed body by body (``1/2 m v^2 + 1/2 I omega^2``) from the body velocities,
    not from ``M_X``.

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and rate (m/s, m/s, rad/s).

    Returns
    -------
    ndarray, shape (...)
        J.
    """
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return _kinetic(params, model, X, q, dX)


def _kinetic(params, model, X, q, dX):
    mo = _motion(params, model, _geometry(model, params.com_platform, X, q), dX)
    return 0.5 * np.sum(_constants(params)["w"] * mo.v * mo.v, axis=-1)


def potential_energy(params: DynamicParameters, model: Manipulator, X, posture=1) -> np.ndarray:
    """Gravitational potential energy ``-sum_b m_b g . p_b`` (zero with all masses at the origin).

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X : array_like, shape (..., 3)
        Poses, m, m, rad.

    Returns
    -------
    ndarray, shape (...)
        J.
    """
    (X,), q = _task_args(params, model, X, posture)
    return _potential(params, model, X, q)


def _potential(params, model, X, q):
    m = _constants(params)["m"]
    p = _positions(params, model, X, q)
    return -np.sum(m * (p @ params.gravity), axis=-1)


def total_energy(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Kinetic plus potential energy, J, shape (...).

    Parameters
    ----------
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and rate (m/s, m/s, rad/s).
    posture : int
        Posture 1..8.
    """
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    return _kinetic(params, model, X, q, dX) + _potential(params, model, X, q)


def friction_power(params: DynamicParameters, model: Manipulator, X, dX, posture=1) -> np.ndarray:
    """Power dissipated by viscous friction in the nine joints.

    ``sum b_a dq^2 + sum b_e (omega - dq)^2 + sum b_p (dphi - omega)^2``, with
    ``omega`` the distal link rates.

    Parameters
    ----------
    params, model, posture
        As in :func:`mass_matrix_task`.
    X, dX : array_like, shape (..., 3)
        Pose (m, m, rad) and rate (m/s, m/s, rad/s).

    Returns
    -------
    ndarray, shape (...)
        W (>= 0).
    """
    (X, dX), q = _task_args(params, model, X, posture, dX=dX)
    mo = _motion(params, model, _geometry(model, params.com_platform, X, q), dX)
    rates = np.concatenate([mo.dq, mo.omega - mo.dq, dX[..., 2:3] - mo.omega], axis=-1)
    return np.sum(_constants(params)["b"] * rates * rates, axis=-1)
