r"""Kinematics of the planar 3-RRR: inverse kinematics in 8 postures, all six
direct-kinematics solutions, the Jacobians of eq. 3 and singularity measures.

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

The compiled kernel (``solver/_dk_kernel.py``) runs steps 2-7 for one joint
vector; a batch loops over it and a single call is a batch of one.

Numbering (paper eq. 15)
------------------------
The six solutions are numbered 1..6 by an ordering rule, see
:data:`ORDERING_RULES`; slot ``k`` of the output holds solution number ``k+1``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._checks import SolverInputError, as_array, check_posture
from . import _dk_kernel as _kernel
from .manipulator import Manipulator

__all__ = [
    "DKSolutions", "SingularityMeasures", "ORDERING_RULES", "DEFAULT_RULE",
    "wrap_angle", "elbow_points", "platform_points", "constraints", "ik", "posture_of",
    "dk_all", "jacobians", "singularity_measures", "order_solutions",
]

#: Roots whose |Im phi| is below this are tried as real (double roots split).
REAL_SNAP = 1e-6
#: A snapped root stays real if its polished residual max|F_i| / l2_i^2 is below this.
REAL_RESIDUAL = 1e-11
#: Newton steps that polish each real root.
NEWTON_STEPS = 3
#: Batches of at least this many joint vectors use all cores.
PARALLEL_MIN = 2048

#: The ordering rules that number the six solutions 1..6 (paper eq. 15).
ORDERING_RULES = {
    "real-phi": "real solutions first, by phi ascending in (-pi, pi]; then the complex ones "
                "by (Re phi, Im phi) ascending",
    "real-x": "real solutions first, by x ascending; then the complex ones by (Re phi, Im phi)",
    "real-y": "real solutions first, by y ascending; then the complex ones by (Re phi, Im phi)",
    "aspect": "real solutions with det J >= 0 in slots 1-3 and with det J < 0 in slots 4-6, each "
              "by phi ascending; complex solutions by (Re phi, Im phi) fill the free slots, first "
              "class first (det J keeps its sign inside a basic region; each class holds at most "
              "three real solutions)",
    "literal": "all six by (Re phi, Im phi) ascending, Re phi wrapped to (-pi, pi], real and "
               "complex alike (the paper's 'arrange all imaginary and real solutions in an "
               "arbitrary order (e.g. increasing)')",
}
#: The rule used when none is given (chosen by the border-volume measurement, README).
DEFAULT_RULE = "aspect"


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


class SingularityMeasures(NamedTuple):
    """Closeness to the singularities of eq. 4.

    Attributes
    ----------
    det_J : ndarray, shape (...)
        ``det J`` (units m^5/rad), zero at the type-1 singularity of eq. 4.
    det_K : ndarray, shape (...)
        ``det K`` (units m^6/rad^3), zero at the type-2 singularity.
    type1 : ndarray, shape (...)
        Inverse condition number of J with its phi column scaled by the mean
        platform radius (dimensionless, in [0, 1]; 0 at the type-1 singularity).
    type2 : ndarray, shape (...)
        ``min_i |sin(beta_i)|``, beta_i the elbow angle of leg i (dimensionless,
        in [0, 1]; 0 when a leg is stretched or folded, the type-2 singularity).
    """

    det_J: np.ndarray
    det_K: np.ndarray
    type1: np.ndarray
    type2: np.ndarray


# ----------------------------------------------------------------------------- helpers
def wrap_angle(a):
    """Wrap angles (rad) to (-pi, pi]; works elementwise on any array."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _rot(c, s, b):
    """R(phi) b for cos/sin arrays ``c, s`` (...) and vectors ``b`` (..., 2)."""
    return np.stack([c * b[..., 0] - s * b[..., 1], s * b[..., 0] + c * b[..., 1]], axis=-1)


def _constants(model: Manipulator) -> dict:
    """Per-model constants, computed once and cached on the (frozen) model."""
    k = model.__dict__.get("_kin_constants")
    if k is not None:
        return k
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
    b = model.platform
    k = {
        "M": np.array(model.motors), "l1": np.array(model.l1), "l2sq": model.l2 ** 2,
        "b": np.array(b),
        "cos8": np.cos(phis), "sin8": np.sin(phis), "phis": phis, "T": T,
        "psi": wrap_angle(phis + np.pi),
        "scale": float(np.mean(model.platform_radius)),
    }
    object.__setattr__(model, "_kin_constants", k)
    return k


def _check_model(model) -> Manipulator:
    if not isinstance(model, Manipulator):
        raise SolverInputError(f"model: expected a Manipulator, got {type(model).__name__}")
    return model


def elbow_points(model: Manipulator, q) -> np.ndarray:
    """Elbow positions ``D_i = M_i + l1_i (cos q_i, sin q_i)``.

    Parameters
    ----------
    model : Manipulator
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray, shape (..., 3, 2)
        ``D_i`` in m.
    """
    _check_model(model)
    q = as_array("q", q)
    return _elbows(model, q)


def _elbows(model, q):
    return model.motors + model.l1[:, None] * np.stack([np.cos(q), np.sin(q)], axis=-1)


def platform_points(model: Manipulator, X) -> np.ndarray:
    """Platform joints ``A_i = P + R(phi) b_i``.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses ``(x, y, phi)``, m, m, rad.

    Returns
    -------
    ndarray, shape (..., 3, 2)
        ``A_i`` in m.
    """
    _check_model(model)
    X = as_array("X", X)
    return _platform(model, X)


def _platform(model, X):
    c, s = np.cos(X[..., 2])[..., None], np.sin(X[..., 2])[..., None]
    return X[..., None, :2] + _rot(c, s, model.platform)


def constraints(model: Manipulator, X, q) -> np.ndarray:
    """The loop constraints ``F_i(X, q) = |A_i - D_i|^2 - l2_i^2``.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad (broadcast against ``X``).

    Returns
    -------
    ndarray, shape (..., 3)
        ``F_i`` in m^2; zero where ``(X, q)`` is an assembled configuration.
    """
    _check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    L = _platform(model, X) - _elbows(model, q)
    return np.sum(L * L, axis=-1) - model.l2 ** 2


# ----------------------------------------------------------------------------- inverse kinematics
def ik(model: Manipulator, X, posture=1) -> np.ndarray:
    """Inverse kinematics in one posture (paper eq. 11, ``q = g_j(X)``).

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses ``(x, y, phi)``, m, m, rad.
    posture : int or array_like of int, shape broadcastable to (...)
        Posture index 1..8: ``j = 1 + sum_i [s_i < 0] 2^(i-1)`` with ``s_i`` the
        elbow sign of leg ``i`` (CONVENTIONS.md).  Posture 1 has all elbows positive.

    Returns
    -------
    ndarray, shape (..., 3)
        Motor angles in (-pi, pi], rad; NaN (the whole row) where a leg cannot
        reach its platform joint, i.e. the pose is outside the posture's tool space.

    Raises
    ------
    SolverInputError
        Wrong shape, non-finite pose, posture outside 1..8.
    """
    _check_model(model)
    X = as_array("X", X)
    j = check_posture(posture)
    try:
        bits = (np.asarray(j)[..., None] - 1) >> np.arange(3) & 1
        bits = np.broadcast_to(bits, X.shape)
    except ValueError:
        raise SolverInputError(f"posture: expected a shape broadcastable to {X.shape[:-1]}, "
                               f"got {np.shape(posture)}") from None
    Xf = np.ascontiguousarray(np.broadcast_to(X, bits.shape).reshape(-1, 3))
    out = np.empty(Xf.shape)
    _kernel.ik_batch(Xf, np.ascontiguousarray(bits.reshape(-1, 3), dtype=np.float64), model.motors,
                     model.l1, model.l2, model.platform, out)
    return out.reshape(bits.shape)


def posture_of(model: Manipulator, X, q) -> np.ndarray:
    """The posture index 1..8 of configurations ``(X, q)``.

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    ndarray of int, shape (...)
        ``1 + sum_i [s_i < 0] 2^(i-1)`` with ``s_i`` the sign of the z-component of
        ``(D_i - M_i) x (A_i - D_i)``; a leg exactly stretched or folded (``s_i = 0``)
        counts as positive, as the formula says.
    """
    _check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    D = _elbows(model, q)
    a, b = D - model.motors, _platform(model, X) - D
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return 1 + np.sum((cross < 0) << np.arange(3), axis=-1)


# ----------------------------------------------------------------------------- direct kinematics
_RULE_CODES = {"real-phi": 0, "literal": 1, "real-x": 2, "real-y": 3, "aspect": 4}


def _order(X, real, rule):
    comp = {"real-x": 0, "real-y": 1}.get(rule, 2)
    key = np.where(real, X[..., comp].real, X[..., 2].real)
    re = np.where(np.isfinite(key), key, np.inf)
    phi = X[..., 2]
    im = np.where(real, 0.0, np.where(np.isfinite(phi.imag), phi.imag, np.inf))
    if rule == "literal":
        return np.lexsort((im, re), axis=-1)
    return np.lexsort((im, re, ~real), axis=-1)


def order_solutions(poses, real, rule: str = DEFAULT_RULE, model: Manipulator | None = None,
                    q=None) -> DKSolutions:
    """Renumber solutions by an ordering rule (see :data:`ORDERING_RULES`).

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
    if rule not in ORDERING_RULES:
        raise SolverInputError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
    flat_p, flat_r = poses.reshape(-1, 6, 3), real.reshape(-1, 6)
    perm = _order(flat_p, flat_r, "real-phi" if rule == "aspect" else rule)
    if rule == "aspect":
        if model is None or q is None:
            raise SolverInputError("model, q: rule 'aspect' needs the model and the joints")
        qf = as_array("q", q).reshape(-1, 3)
        sp = np.take_along_axis(flat_p, perm[..., None], axis=1)
        sr = np.take_along_axis(flat_r, perm, axis=1)
        J, _ = _jacobians(model, np.where(sr[..., None], sp.real, 0.0), qf[:, None, :])
        pos = sr & (np.linalg.det(J) >= 0)
        neg = sr & ~pos
        cls = np.where(pos, 0, np.where(neg, 1, 2))
        # stable: real-phi order inside each class; complex fill the free slots of class 0, then 1
        new = np.empty_like(perm)
        for n in range(len(perm)):
            p_i, n_i, c_i = [list(np.nonzero(cls[n] == c)[0]) for c in range(3)]
            if len(p_i) > 3 or len(n_i) > 3:
                seq = p_i + n_i + c_i
            else:
                seq = p_i + c_i[:3 - len(p_i)] + n_i + c_i[3 - len(p_i):]
            new[n] = perm[n][seq]
        perm = new
    return DKSolutions(np.take_along_axis(flat_p, perm[..., None], axis=1).reshape(poses.shape),
                       np.take_along_axis(flat_r, perm, axis=1).reshape(real.shape))


def dk_all(model: Manipulator, q, rule: str = DEFAULT_RULE) -> DKSolutions:
    """All six direct-kinematics solutions, real and complex, numbered 1..6.

    Parameters
    ----------
    model : Manipulator
    q : array_like, shape (..., 3)
        Motor angles, rad.  Angles differing by multiples of 2 pi are the same input.
    rule : str
        The ordering rule that numbers the solutions (:data:`ORDERING_RULES`);
        default :data:`DEFAULT_RULE`.

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
    :mod:`solver._dk_kernel`.  Batches of :data:`PARALLEL_MIN` or more joint
    vectors run on all cores.
    """
    _check_model(model)
    q = as_array("q", q)
    code = _RULE_CODES.get(rule) if isinstance(rule, str) else None
    if code is None:
        raise SolverInputError(f"rule: expected one of {sorted(ORDERING_RULES)}, got {rule!r}")
    k = _constants(model)
    lead = q.shape[:-1]
    flat = np.ascontiguousarray(q.reshape(-1, 3))
    n = flat.shape[0]
    poses = np.empty((n, 6, 3), dtype=np.complex128)
    real = np.empty((n, 6), dtype=np.bool_)
    run = _kernel.dk_parallel if n >= PARALLEL_MIN else _kernel.dk_serial
    run(flat, k["M"], k["l1"], k["l2sq"], k["b"], k["cos8"], k["sin8"], k["T"], k["psi"], code,
        REAL_SNAP, REAL_RESIDUAL * float(np.min(k["l2sq"])), NEWTON_STEPS, poses, real)
    return DKSolutions(poses.reshape(lead + (6, 3)), real.reshape(lead + (6,)))


# ----------------------------------------------------------------------------- Jacobians
def jacobians(model: Manipulator, X, q) -> tuple[np.ndarray, np.ndarray]:
    """The matrices J and K of the velocity model ``J dX/dt + K dq/dt = 0`` (eq. 3).

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    J : ndarray, shape (..., 3, 3)
        ``dF/dX``: row ``i`` is ``2 (L_x, L_y, L . dR/dphi b_i)`` with
        ``L = A_i - D_i``; units m (columns x, y) and m^2/rad (column phi).
    K : ndarray, shape (..., 3, 3)
        ``dF/dq``, diagonal, ``K_ii = -2 L . dD_i/dq_i``, m^2/rad.
    """
    _check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    return _jacobians(model, X, q)


def _jacobians(model, X, q):
    c, s = np.cos(X[..., 2])[..., None], np.sin(X[..., 2])[..., None]
    Rb = _rot(c, s, model.platform)                                   # (..., 3, 2)
    D = _elbows(model, q)
    L = X[..., None, :2] + Rb - D
    dRb = np.stack([-Rb[..., 1], Rb[..., 0]], axis=-1)
    J = 2.0 * np.concatenate([L, np.sum(L * dRb, axis=-1, keepdims=True)], axis=-1)
    dD = model.l1[:, None] * np.stack([-np.sin(q), np.cos(q)], axis=-1)
    kd = -2.0 * np.sum(L * dD, axis=-1)
    K = kd[..., :, None] * np.eye(3)
    return J, K


def singularity_measures(model: Manipulator, X, q) -> SingularityMeasures:
    """Closeness of configurations to the type-1 and type-2 singularities (eq. 4).

    Parameters
    ----------
    model : Manipulator
    X : array_like, shape (..., 3)
        Poses, m, m, rad.
    q : array_like, shape (..., 3)
        Motor angles, rad.

    Returns
    -------
    SingularityMeasures
        ``det_J``, ``det_K`` and the normalised measures ``type1``, ``type2``
        (shape (...), 0 at the singularity, 1 far from it).
    """
    _check_model(model)
    X, q = as_array("X", X), as_array("q", q)
    J, K = _jacobians(model, X, q)
    Js = J * np.array([1.0, 1.0, 1.0 / _constants(model)["scale"]])
    sv = np.linalg.svd(Js, compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        type1 = np.where(sv[..., 0] > 0, sv[..., -1] / sv[..., 0], 0.0)
    # |K_ii| = 2 l1 l2 |sin beta_i|
    type2 = np.min(np.abs(np.diagonal(K, axis1=-2, axis2=-1)) / (2.0 * model.l1 * model.l2), axis=-1)
    return SingularityMeasures(np.linalg.det(J), np.linalg.det(K), type1, type2)
