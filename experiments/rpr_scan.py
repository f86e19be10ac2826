"""An independent reference direct kinematics of the 3-RPR: a dense scan in phi, no polynomial.

For each phi on a fine grid, legs 1 and 2 (two circles) give the platform centre in closed form;
leg 3's residual changes sign at a solution, refined by bisection and Newton on the whole system.
:func:`solver.dk_all` (the sextic) is checked against it (``tests/test_manipulators.py``).
:func:`follow` is Newton from the previous pose along a joint path (the baseline the cusp loops
defeat when sampled coarsely).

A test oracle that also serves the cusp experiments: :mod:`experiments.rpr_cusps` starts its loops
from these solutions, and the 3-RPR FMU's reference path (:func:`experiments.rpr_suite.cusp_loop_path`)
depends on them to the last bit, so the module lives here, where the tests, the benchmarks and the
FMU build can all import it.
"""
from __future__ import annotations

import numpy as np

from solver.checks import as_array
from solver.rpr import RPRManipulator, _check_model, _E, _jac, _positive, _residual, _rho, _rot, _wrap

__all__ = ["dk_all_scan", "follow"]


def _leg12(model, r1, r2, phi):
    """Legs 1-2 closed: ``P = m + s sqrt(h2) n`` (``s = +-1``), real where ``h2 >= 0``."""
    c1 = model.base[0] - _rot(phi, model.platform[0])
    dv = model.base[1] - _rot(phi, model.platform[1]) - c1
    d2 = np.sum(dv * dv, axis=-1)
    a = 0.5 * (r1 ** 2 - r2 ** 2 + d2) / d2
    return c1 + a[..., None] * dv, dv @ _E.T, r1 ** 2 / d2 - a ** 2


def _branch(model, r, s, phi):
    """Pose ``P`` on branch ``s`` of legs 1-2, leg 3's residual (NaN off the branch) and ``h2``."""
    m, n, h2 = _leg12(model, r[..., 0], r[..., 1], phi)
    P = m + (s * np.sqrt(np.where(h2 >= 0, h2, np.nan)))[..., None] * n
    return P, np.sum((P + _rot(phi, model.platform[2]) - model.base[2]) ** 2, axis=-1) - r[..., 2] ** 2, h2


def _bisect(fun, a, b, iters=60, keep_a=False):
    """Vectorised bisection of ``fun > 0`` changing on [a, b] (either order); ``keep_a``: a's side."""
    fa = fun(a) > 0
    for _ in range(iters):
        c = 0.5 * (a + b)
        right = (fun(c) > 0) == fa
        a, b = np.where(right, c, a), np.where(right, b, c)
    return a if keep_a else 0.5 * (a + b)


def dk_all_scan(model: RPRManipulator, rho, n_phi: int = 3600, tol: float = 1e-9):
    """All real direct-kinematics solutions by a dense scan in phi (reference, no polynomial).

    For each phi of a uniform grid, legs 1 and 2 put ``P`` on two circles (branches ``s = +-1``
    where they meet) and leg 3's residual ``f`` is sampled along each branch.  A sign change of
    ``f`` in a cell gives a root (bisection in phi) and, deflated by it, a golden-section search for
    two more; a cell next to a local minimum of ``|f|`` is searched for a close pair the same way;
    cells where the branches join (the circles tangent) are rescanned on a sub-grid uniform in
    the circles' half-chord and halving towards the junction.  Roots are polished by Newton steps
    on the full system and deduplicated (1e-7 rad, 1e-7 of the geometry's size).  Measured on
    this module's geometry: all solutions of 20000 random poses; both solutions of a pair 1e-5 m
    from a fold (det J = 0); near cusps, pairs closer than ~1e-5 m may come back ~1e-7 m off or,
    at ~1e-6 m, unresolved (float64 residuals can no longer tell them apart).

    Parameters
    ----------
    model : RPRManipulator
    rho : array_like, shape (..., 3)
        Leg lengths, m.
    n_phi : int
        Number of phi samples over a turn (default 3600: 0.1 deg).
    tol : float
        Largest accepted ``max_i |F_i|``, m^2.

    Returns
    -------
    poses : ndarray, shape (..., 6, 3)
        The real solutions sorted by phi, NaN-padded; m, m, rad.
    count : ndarray of int, shape (...)
        Number of real solutions (0..6).
    """
    _check_model(model)
    rho, n_phi = _rho("rho", rho), _positive("n_phi", n_phi, int)
    lead, r = rho.shape[:-1], rho.reshape(-1, 3)
    step = 2.0 * np.pi / n_phi
    phi = -np.pi + step * np.arange(-1, n_phi + 1)                       # one cell more at each end
    found = _Candidates(model, r)
    items = np.arange(len(r))
    for s in (1.0, -1.0):
        _, f, h2 = _branch(model, r[:, None, :], s, phi)                # (items, n_phi + 2), NaN off branch
        found.scan(items, s, np.broadcast_to(phi, f.shape), f)
    _scan_junctions(found, phi, h2 >= 0)
    poses, count = _collect(model, r, found.cands, tol)
    return poses.reshape(lead + (6, 3)), count.reshape(lead)


class _Candidates:
    """The roots found so far for items ``r`` (k, 3): (item indices, branches, phi) arrays, and the
    searches that add to them."""

    def __init__(self, model, r):
        self.model, self.r, self.cands = model, r, []

    def add(self, i, s, ph):
        self.cands.append((i, np.broadcast_to(s, i.shape), ph))

    def g(self, i, s, x, rt=None):                                        # leg 3's residual, / (x - rt)
        f = _branch(self.model, self.r[i], s, x)[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            return f if rt is None else f / (x - rt)

    def pair(self, i, s, a, b, rt=None):                                  # a close pair hidden in [a, b]?
        g = self.g
        sg, lo, hi = np.sign(g(i, s, a, rt)), a, b
        for _ in range(60):                                               # golden section: min of sg * g
            c, d = hi - 0.618034 * (hi - lo), lo + 0.618034 * (hi - lo)
            left = ~(sg * g(i, s, c, rt) > sg * g(i, s, d, rt))
            lo, hi = np.where(left, lo, c), np.where(left, d, hi)
        mid = 0.5 * (lo + hi)
        two = sg * g(i, s, mid, rt) <= 0                                  # two roots, or a double root:
        inner = np.minimum(np.abs(mid - a), np.abs(mid - b)) > 1e-3 * np.abs(b - a)
        tiny = ~two & inner & (rt is None) & (np.abs(g(i, s, mid)) <= 1e-12)   # a tangency (1e-12 m^2)
        r2 = None if rt is None else rt[two]
        for u, v in ((a, mid), (mid, b)):
            self.add(i[two], s, _bisect(lambda x: g(i[two], s, x, r2), u[two], v[two]))
        self.add(i[tiny], s, mid[tiny])

    def scan(self, i, s, x, f):                                           # samples f at x (rows: items i)
        ok, a, b = np.isfinite(f), x[:, :-1], x[:, 1:]
        both, change = ok[:, :-1] & ok[:, 1:], (f[:, :-1] > 0) != (f[:, 1:] > 0)
        e, j = np.nonzero(both & change)                                  # a sign change: a root, and
        ph = _bisect(lambda y: self.g(i[e], s, y), a[e, j], b[e, j])      # maybe two more in the cell
        self.add(i[e], s, ph)
        self.pair(i[e], s, a[e, j], b[e, j], ph)
        af = np.pad(np.where(ok, np.abs(f), np.inf), ((0, 0), (1, 1)), constant_values=np.inf)
        low = ok & (af[:, 1:-1] < af[:, :-2]) & (af[:, 1:-1] <= af[:, 2:])  # |f| at a local minimum:
        e, j = np.nonzero(both & ~change & (low[:, :-1] | low[:, 1:]))   # a pair in either cell?
        self.pair(i[e], s, a[e, j], b[e, j])


def _scan_junctions(found, phi, ok):
    """Cells of ``phi`` where the branches join (``ok``: h2 >= 0 per item and sample): find where by
    bisection, then scan both branches on a sub-grid uniform in the circles' half-chord and halving
    towards the junction; a root at the junction itself is added too."""
    model, r = found.model, found.r
    i, k = np.nonzero(ok[:, :-1] != ok[:, 1:])
    start = np.where(ok[i, k], phi[k], phi[k + 1])
    edge = _bisect(lambda x: _leg12(model, r[i, 0], r[i, 1], x)[2] >= 0, start,
                   np.where(ok[i, k], phi[k + 1], phi[k]), keep_a=True)
    tau = np.r_[np.linspace(1.0, 0.0, 33)[:-1] ** 2, 2.0 ** -np.arange(11, 53), 0.0]   # uniform in sqrt(h2),
    sub = edge[:, None] + (start - edge)[:, None] * tau                   # then halving towards the junction
    fe = [_branch(model, r[i][:, None, :], t, sub)[1] for t in (1.0, -1.0)]
    for t, fs in zip((1.0, -1.0), fe):
        found.scan(i, t, sub, fs)
    jn = (fe[0][:, -1] > 0) != (fe[1][:, -1] > 0)
    found.add(i[jn], 1.0, edge[jn])


def _collect(model, r, cands, tol):
    """Candidates polished, kept where the residual is at most ``tol``, deduplicated per item and
    sorted by phi: poses (k, 6, 3) NaN-padded and counts (k,)."""
    ci, cs, cp = (np.concatenate(c) for c in zip(*cands))
    X = _polish(model, np.column_stack([_branch(model, r[ci], cs, cp)[0], cp]), r[ci])
    res = np.max(np.abs(_residual(model, X, r[ci])), axis=-1)
    ci, X = ci[res <= tol], X[res <= tol]                                  # NaN residuals drop out too
    X[:, 2] = _wrap(X[:, 2])
    poses, count = np.full((len(r), 6, 3), np.nan), np.zeros(len(r), dtype=int)
    scale = float(np.max(np.abs(model.base)) + np.max(np.abs(model.platform)))
    for item in np.unique(ci):                                            # deduplicate per item
        out = []
        for x in sorted(X[ci == item], key=lambda x: x[2]):
            if all(max(np.max(np.abs(x[:2] - y[:2])) / scale, abs(_wrap(x[2] - y[2]))) > 1e-7 for y in out):
                out.append(x)
        count[item] = min(len(out), 6)
        poses[item, :count[item]] = np.array(out[:6])
    return poses, count


def _polish(model, X, rho, steps=2):
    """Newton steps on the full system, each kept only where it lowers the residual."""
    for _ in range(steps):
        F = _residual(model, X, rho)
        with np.errstate(all="ignore"):
            Y = X + np.linalg.solve(_jac(model, X), -F[..., None])[..., 0]
            better = np.max(np.abs(_residual(model, Y, rho)), -1) < np.max(np.abs(F), -1)
        X = np.where(better[..., None], Y, X)
    return X


def follow(model: RPRManipulator, rho_path, X0, iters: int = 20):
    """Follow one DK solution along joint values, Newton's method from the previous pose.

    Parameters
    ----------
    model : RPRManipulator
    rho_path : array_like, shape (N, 3)
        Leg lengths along the path, m; ``X0`` (3,) m, m, rad solves ``rho_path[0]``.
    iters : int
        Newton iterations per point at most (stops at a step below 1e-12).

    Returns
    -------
    poses : ndarray, shape (N, 3)
        The followed poses (phi continuous, not wrapped), m, m, rad; NaN after a singular J.
    converged : ndarray of bool, shape (N,)
        ``max_i |F_i| < 1e-9`` m^2 at each point.
    """
    _check_model(model)
    rho_path, X = _rho("rho_path", rho_path), as_array("X0", X0, (3,)).copy()
    poses, conv = np.full((len(rho_path), 3), np.nan), np.zeros(len(rho_path), dtype=bool)
    for n, rho in enumerate(rho_path):
        try:
            for _ in range(iters):
                dX = np.linalg.solve(_jac(model, X), -_residual(model, X, rho))
                X = X + dX
                if np.max(np.abs(dX)) < 1e-12:
                    break
        except np.linalg.LinAlgError:
            break
        poses[n], conv[n] = X, np.max(np.abs(_residual(model, X, rho))) < 1e-9
    return poses, conv
