r"""Direct kinematics of the planar 3-RRR: all six solutions of a joint vector, real and
complex, numbered 1..6 (:func:`dk_all`).

Conventions (``shared/CONVENTIONS.md``): pose ``X = (x, y, phi)`` in m, m, rad;
motor angles ``q = (q1, q2, q3)`` in rad measured from +x; leg ``i`` is
``M_i - D_i - A_i`` with ``D_i = M_i + l1_i (cos q_i, sin q_i)`` and
``A_i = P + R(phi) b_i``.  Every function takes arrays with any leading shape
``(...)`` and the single call runs through the same code.

Direct kinematics: the elimination (Bezout / Gosselin style)
------------------------------------------------------------
With ``u_i(phi) = R(phi) b_i - D_i`` the constraint of leg ``i`` reads

.. math::  F_i = |P + u_i|^2 - l_{2i}^2 = |P|^2 + 2 P\cdot u_i + \kappa_i = 0,
           \qquad \kappa_i = |u_i|^2 - l_{2i}^2 .

1. *Linear elimination of P.*  ``F_i - F_1`` (i = 2, 3) removes ``|P|^2``:
   ``r_i . P = h_i`` with ``r_i = u_i - u_1`` and ``h_i = -(kappa_i - kappa_1)/2``.
   Cramer's rule gives ``P = (N_x, N_y) / Delta`` with
   ``Delta = r_2 x r_3``, ``N_x = h_2 r_3y - h_3 r_2y``, ``N_y = r_2x h_3 - r_3x h_2``.
2. *The eliminant.*  Substituting into ``F_1`` and multiplying by ``Delta^2``:
   ``f(phi) = N_x^2 + N_y^2 + 2 Delta (N . u_1) + Delta^2 kappa_1 = 0``.
   ``u_i`` is affine in ``(cos phi, sin phi)`` and, on the circle
   ``cos^2 + sin^2 = 1``, ``kappa_i`` is too, so ``f`` is a trigonometric
   polynomial of degree 4 at most.  Its ``e^{+-4 i phi}`` terms vanish
   identically: the ``e^{i phi}`` part of every rotated vector is a multiple of
   the isotropic vector ``(1, -i)``, whose dot product with itself is zero.  So
   ``f`` has degree 3: seven harmonics, six roots in ``phi``.
3. *Coefficients by exact interpolation.*  ``f`` is evaluated at the eight
   angles ``phi_m = 2 pi m / 8``; a degree-3 trigonometric polynomial is fixed
   exactly by them (the discrete Fourier transform recovers its harmonics, the
   unused ``k = 4`` bin is zero up to rounding).
4. *The sextic.*  The half-angle substitution ``t = tan((phi - psi)/2)`` turns
   ``(1 + t^2)^3 f`` into a real polynomial of degree 6 in ``t``.  Its leading
   coefficient is ``f(psi + pi)``; the textbook choice ``psi = 0`` makes it
   vanish whenever ``phi = pi`` is a solution (a root at ``t = infinity``).  We
   choose ``psi`` per input so that ``psi + pi`` is the sample angle where
   ``|f|`` is largest: the leading coefficient is then as large as it can be
   among the samples and the degenerate case cannot occur (a leading
   coefficient of exactly zero would need ``f`` to vanish at all eight samples,
   i.e. ``f == 0``, a degenerate architecture).
5. *All roots* of the sextic by the Aberth-Ehrlich simultaneous iteration
   (a root is accepted when ``|g(t)|`` is below its rounding-error bound, i.e.
   it is exact for a polynomial within a few ulps of ``g``).  Then
   ``phi = psi + 2 atan(t)``, complex for complex roots, and ``P`` from step 1
   evaluated at that (complex) ``phi``.
6. *Real solutions.*  The sextic has real coefficients, so its complex roots
   come in conjugate pairs and a real input has 0, 2, 4 or 6 real solutions.
   A root whose ``phi`` has ``|Im phi| <= REAL_SNAP`` is tried as real (two
   close real roots come out of any root finder as a pair with an imaginary
   part of order sqrt(eps)): ``P`` from step 1, then up to ``NEWTON_STEPS``
   Newton steps on the three constraints ``F(X) = 0`` (analytic 3x3 solve; a
   step is kept only where it lowers the residual).  The root is real if the
   residual is then below ``REAL_RESIDUAL * min(l2)^2``.
7. *Degenerate cases.*  Where ``Delta`` vanishes at a real root the 2x2 solve
   of step 1 is singular (the tips of the three distal vectors ``A_i - D_i``
   are collinear) and the root is double: two solutions share ``phi``.  There
   ``P`` is taken from the line ``r . P = h`` of the better row and the circle
   ``F_1 = 0``; the two intersections go to the two copies of the root.  At a
   type-1 singularity two solutions merge; both copies are returned polished
   as far as the conditioning allows (error ~ eps / type1), never NaN.  Roots
   at infinity in the rotation (degenerate architectures only) give NaN in a
   complex slot, never in a real one.

The compiled kernel (:mod:`solver._kernels.direct_kinematics`) runs steps 2-7 for one
joint vector; a batch loops over it and a single call is a batch of one.

Numbering (paper eq. 15)
------------------------
The six solutions are numbered 1..6 by an ordering rule, see
:data:`solver.ordering.ORDERING_RULES`; slot ``k`` of the output holds solution number ``k+1``.
"""
from __future__ import annotations

from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from ._kernels import direct_kinematics as _dk
from ._kernels.choice import nearest as _nearest
from ._kernels.layout import RULE_ASPECT, pack_model
from ._kernels.ordering import number_batch
from .checks import SolverInputError, as_array
from .identity_cache import by_identity
from .kinematics import check_manipulator, wrap_angle
from .manipulator import Manipulator
from .ordering import DEFAULT_RULE, rule_code

__all__ = ["DKSolutions", "dk_all", "nearest_solution", "order_solutions", "kernel_constants", "REAL_SNAP", "REAL_RESIDUAL", "NEWTON_STEPS",
           "PARALLEL_MIN"]

#: Roots whose |Im phi| is below this are tried as real (double roots split).
REAL_SNAP = 1e-6
#: A snapped root stays real if its polished residual max|F_i| / l2_i^2 is below this.
REAL_RESIDUAL = 1e-11
#: Newton steps that polish each real root.
NEWTON_STEPS = 3
#: Batches of at least this many joint vectors use all cores.
PARALLEL_MIN = 2048


class DKSolutions(NamedTuple):
    """All six direct-kinematics solutions of a batch of joint vectors.

    Attributes
    ----------
    poses : ndarray, shape (..., 6, 3), complex128
        Solution ``k+1`` in slot ``k``: ``(x, y, phi)`` in m, m, rad.  Real
        solutions have zero imaginary parts and ``phi`` in (-pi, pi].
    real : ndarray, shape (..., 6), bool
        Which slots are real solutions.
    """

    poses: np.ndarray
    real: np.ndarray

    @property
    def n_real(self) -> np.ndarray:
        """Number of real solutions, shape (...), int."""
        return np.count_nonzero(self.real, axis=-1)

    def real_poses(self) -> list[np.ndarray]:
        """For a single joint vector: the real solutions as a float array (n, 3)."""
        if self.real.ndim != 1:
            raise SolverInputError(f"real_poses: expected a single joint vector, got batch shape "
                                   f"{self.real.shape[:-1]}")
        return self.poses[self.real].real


def _kernel_constants(model: Manipulator) -> MappingProxyType:
    """What the DK kernel needs of a model (the explicit data of :func:`kernel_constants`).

    Keys: ``pack`` (the model pack of :mod:`solver._kernels.layout`), ``sample_to_sextic``
    (8, 8, 7), and the geometry and sample arrays it was packed from (``M``, ``l1``,
    ``l2sq``, ``b``, ``cos8``, ``sin8``, ``psi``, ``phis``).
    """
    m = np.arange(8)
    phis = 2.0 * np.pi * m / 8.0
    # T[j] maps the 8 samples f(phi_m) to the coefficients (t^6 ... t^0) of
    # g(t) = (1 + t^2)^3 f(psi + 2 atan t) with psi = phi_j + pi.
    # f(phi) = sum_k a_k e^{i k phi}, a_k = 1/8 sum_m f_m e^{-i k phi_m};
    # (1 + t^2)^3 e^{i k theta} = (1 + i t)^{3 + k} (1 - i t)^{3 - k}, theta = 2 atan t.
    basis = np.zeros((7, 7), dtype=complex)  # basis[k + 3] = coefficients, highest first
    for kk in range(-3, 4):
        p = np.array([1.0 + 0j])
        for _ in range(3 + kk):
            p = np.convolve(p, [1j, 1.0])
        for _ in range(3 - kk):
            p = np.convolve(p, [-1j, 1.0])
        basis[kk + 3] = p
    T = np.zeros((8, 8, 7))
    for j in range(8):
        psi = phis[j] + np.pi
        for mm in range(8):
            w = np.array([np.exp(1j * kk * (psi - phis[mm])) / 8.0 for kk in range(-3, 4)])
            T[j, mm] = (w @ basis).real
    M, l1, l2sq = model.circle_legs()                # every leg a circle constraint (the interface)
    k = {"M": M, "l1": l1, "l2sq": l2sq, "b": np.array(model.platform), "cos8": np.cos(phis),
         "sin8": np.sin(phis), "phis": phis, "sample_to_sextic": T, "psi": wrap_angle(phis + np.pi)}
    rpr = model.kind == "3-RPR"                      # the joints are the radii: residuals scale with the platform
    scale = float(np.max(model.platform_radius)) ** 2 if rpr else float(np.min(l2sq))
    k["pack"] = pack_model(M, l1, l2sq, k["b"], k["cos8"], k["sin8"], k["psi"], REAL_SNAP, REAL_RESIDUAL * scale,
                           NEWTON_STEPS)
    return MappingProxyType(k)


#: ``kernel_constants(model)``: the DK kernel's data of a model (:func:`_kernel_constants`), a read-only
#: mapping built once per model object and kept beside it (:func:`solver.identity_cache.by_identity`:
#: the model is frozen, so its data stays valid while it lives; nothing is stored on the model).
kernel_constants = by_identity(_kernel_constants)


def dk_all(model: Manipulator, q, rule: str = DEFAULT_RULE) -> DKSolutions:
    """All six direct-kinematics solutions, real and complex, numbered 1..6.

    Parameters
    ----------
    model : Manipulator
    q : array_like, shape (..., 3)
        Motor angles, rad.  Angles differing by multiples of 2 pi are the same input.
    rule : str
        The ordering rule that numbers the solutions (:data:`solver.ORDERING_RULES`);
        default :data:`solver.DEFAULT_RULE`.

    Returns
    -------
    DKSolutions
        ``poses`` (..., 6, 3) complex128 and ``real`` (..., 6) bool; slot ``k``
        holds solution number ``k+1``.  Real solutions satisfy the constraints
        to machine precision and have ``phi`` in (-pi, pi].

    Raises
    ------
    SolverInputError
        ``q`` of the wrong shape or with non-finite entries; an unknown ``rule``.

    Notes
    -----
    The elimination is derived in the module docstring; the compiled kernel is
    :mod:`solver._kernels.direct_kinematics`.  Batches of :data:`PARALLEL_MIN` or more joint
    vectors run on all cores.
    """
    check_manipulator(model)
    q = as_array("q", q)
    code = rule_code(rule)
    k = kernel_constants(model)
    lead = q.shape[:-1]
    flat = np.ascontiguousarray(q.reshape(-1, 3))
    n = flat.shape[0]
    poses = np.empty((n, 6, 3), dtype=np.complex128)
    real = np.empty((n, 6), dtype=np.bool_)
    run = _dk.dk_parallel if n >= PARALLEL_MIN else _dk.dk_serial
    run(flat, k["pack"], k["sample_to_sextic"], code, poses, real)
    return DKSolutions(poses.reshape(lead + (6, 3)), real.reshape(lead + (6,)))


#: No label masks: :func:`nearest_solution` chooses among all real solutions.
_NO_MASK = np.zeros(7, dtype=np.bool_)


def nearest_solution(model: Manipulator, q, X_ref, weights) -> np.ndarray:
    """The real DK solution of one joint vector nearest to a reference pose (eq. 19 distance).

    The rule of the tracker's choice and of the ``nearest`` baseline (one compiled definition,
    :func:`solver._kernels.choice.nearest`): all six solutions by :func:`dk_all`, then the real
    one minimising ``sqrt(w_x dx^2 + w_y dy^2 + w_phi dphi^2)`` with ``dphi`` wrapped.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    q : array_like, shape (3,)
        Joints, rad (m for a 3-RPR).
    X_ref : ndarray, shape (3,), float64
        Reference pose, m, m, rad.
    weights : ndarray, shape (3,), float64
        Eq. 19 weights ``(w_x, w_y, w_phi)``, 1, 1 and m^2/rad^2.

    Returns
    -------
    ndarray, shape (3,)
        The nearest real solution (m, m, rad), or NaN (3,) if ``q`` has no real solution.
    """
    sol = dk_all(model, q)
    if sol.real.ndim != 1:
        raise SolverInputError(f"q: expected one joint vector (3,), got shape {np.shape(q)}")
    k, _ = _nearest(sol.poses, sol.real, X_ref, weights, _NO_MASK, _NO_MASK, _NO_MASK, False)
    return sol.poses[k].real.copy() if k >= 0 else np.full(3, np.nan)


def order_solutions(poses, real, rule: str = DEFAULT_RULE, model: Manipulator | None = None,
                    q=None):
    """Renumber solutions by an ordering rule (see :data:`solver.ORDERING_RULES`).

    Parameters
    ----------
    poses : array_like, shape (..., 6, 3), complex
    real : array_like, shape (..., 6), bool
    rule : str
    model : Manipulator, optional
        Needed by rule ``"aspect"`` (the sign of det J).
    q : array_like, shape (..., 3), optional
        Joints of each solution set; needed by rule ``"aspect"``.

    Returns
    -------
    DKSolutions
    """
    poses = np.asarray(poses, dtype=complex)
    real = np.asarray(real, dtype=bool)
    if poses.shape[-2:] != (6, 3) or real.shape != poses.shape[:-1]:
        raise SolverInputError(f"poses, real: expected shapes (..., 6, 3) and (..., 6), got "
                               f"{poses.shape} and {real.shape}")
    code = rule_code(rule)
    flat_p = np.ascontiguousarray(poses.reshape(-1, 6, 3))
    flat_r = np.ascontiguousarray(real.reshape(-1, 6))
    n = len(flat_p)
    if code == RULE_ASPECT:
        if model is None or q is None:
            raise SolverInputError("model, q: rule 'aspect' needs the model and the joints")
        qf = np.ascontiguousarray(as_array("q", q).reshape(-1, 3))
        if len(qf) != n:
            raise SolverInputError(f"q: expected one joint vector per solution set ({n}), got {len(qf)}")
        check_manipulator(model)
        M, l1, _ = model.circle_legs()
        b = np.array(model.platform)
    else:
        qf, M, l1, b = np.zeros((n, 3)), np.zeros((3, 2)), np.zeros(3), np.zeros((3, 2))
    out_p, out_r = np.empty_like(flat_p), np.empty_like(flat_r)
    number_batch(flat_p, flat_r, code, qf, M, l1, b, out_p, out_r)
    return DKSolutions(out_p.reshape(poses.shape), out_r.reshape(real.shape))
