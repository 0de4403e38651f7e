"""A small primal-dual interior-point method for structured conic programs.

Solves::

    minimise    c'x
    subject to  A x = b
                G x + s = h,   s in  R^m_+  x  S^{n_1}_+  x ... x  S^{n_p}_+

with Nesterov-Todd scaling and Mehrotra's predictor-corrector, following the algorithm of
CVXOPT's ``conelp`` (Vandenberghe 2010, "The CVXOPT linear and quadratic cone program solvers")
without the self-dual embedding: the G-SfT programs are always feasible and bounded.

Why not a general-purpose sparse solver: in G-SfT every observation couples to the same ~84
lifted unknowns, so the reduced KKT matrix ``G' W^-1 W^-T G`` is a small dense matrix that is a
sum of per-observation rank-3 terms. A generic sparse LDL forms it entry by entry; the problem
object given to :func:`solve_conic` forms it with a handful of dense matrix products instead
(see ``sdp.KnownPoseIPM``), which is several times faster at 1,000+ observations.

Symmetric matrices are stored as "svec" vectors: the upper triangle, column by column,
off-diagonal entries scaled by ``sqrt(2)`` (Clarabel's ``PSDTriangleConeT`` layout), so that
``svec(X) . svec(Y) = trace(X Y)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ._lapack import lapack

__all__: list[str] = []

_LAPACK = lapack()  # SciPy's routines, without the 0.27 s import of scipy.linalg (see _lapack)
_gesvd, _potrf, _potrs = _LAPACK.dgesvd, _LAPACK.dpotrf, _LAPACK.dpotrs
_syevr, _trtrs = _LAPACK.dsyevr, _LAPACK.dtrtrs


# -- svec algebra ---------------------------------------------------------------------------------
def _triu_colmajor(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of every svec entry (upper triangle, column by column)."""
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    mask = ii <= jj
    return ii.T[mask.T], jj.T[mask.T]


_TRIU_CACHE: dict[int, tuple[np.ndarray, ...]] = {}


def _triu(n: int) -> tuple[np.ndarray, ...]:
    """Row, column and scale of every svec entry, the flat indices ``i n + j``, ``j n + i``
    into an ``n x n`` matrix (``take`` with flat indices is several times faster than 2-D
    fancy indexing on these small matrices) and, for every flat position of the matrix, the
    svec entry it holds."""
    if n not in _TRIU_CACHE:  # pure function of n: a memo, not state
        i, j = _triu_colmajor(n)
        entry = np.empty(n * n, dtype=np.intp)
        entry[i * n + j] = entry[j * n + i] = np.arange(len(i))
        _TRIU_CACHE[n] = (i, j, np.where(i == j, 1.0, np.sqrt(2.0)), i * n + j, j * n + i, entry)
    return _TRIU_CACHE[n]


def svec(X: np.ndarray) -> np.ndarray:
    """Scaled upper-triangle vector of a symmetric matrix."""
    s, ij = _triu(X.shape[0])[2:4]
    return X.ravel().take(ij) * s


def smat(x: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`svec`."""
    tab = _triu(n)
    s, entry = tab[2], tab[5]
    # one take of every matrix entry's svec entry (a zero fill and two scatters cost twice)
    return (x / s).take(entry).reshape(n, n)


_SKRON_CACHE: dict[int, tuple[np.ndarray, ...]] = {}


def skron(T: np.ndarray) -> np.ndarray:
    """Matrix ``P`` with ``P @ svec(X) == svec(T @ X @ T)`` for symmetric ``T``.

    ``P[(i, j), (k, l)] = (T_ik T_jl + T_il T_jk) * scale`` over the svec pairs: four ``take``
    of the small ``T`` with precomputed flat indices and one fused multiply-add, no loop.
    """
    n = T.shape[0]
    if n not in _SKRON_CACHE:  # index tables depend on n only
        i, j, s = _triu(n)[:3]
        scale = (s[:, None] / s[None, :]) * np.where(i == j, 0.5, 1.0)[None, :]
        flat = [(a[:, None] * n + b[None, :]).ravel() for a, b in ((i, i), (j, j), (i, j), (j, i))]
        _SKRON_CACHE[n] = (*flat, scale.ravel())
    ik, jl, il, jk, scale = _SKRON_CACHE[n]
    t = T.ravel()
    P = t.take(ik) * t.take(jl)
    P += t.take(il) * t.take(jk)
    P *= scale
    nt = n * (n + 1) // 2
    return P.reshape(nt, nt)


_SKRON_TRIU_CACHE: dict[int, tuple[np.ndarray, ...]] = {}


def skron_triu(T: np.ndarray) -> np.ndarray:
    """The upper triangle of :func:`skron` ``(T)`` (symmetric), in ``np.triu_indices(nt)``
    order: half the work, for a Cholesky factorisation that reads one triangle."""
    n = T.shape[0]
    if n not in _SKRON_TRIU_CACHE:
        skron(np.eye(n))  # fills _SKRON_CACHE[n]
        nt = n * (n + 1) // 2
        rows, cols = np.triu_indices(nt)
        flat = rows * nt + cols
        _SKRON_TRIU_CACHE[n] = tuple(a.take(flat) for a in _SKRON_CACHE[n])
    ik, jl, il, jk, scale = _SKRON_TRIU_CACHE[n]
    t = T.ravel()
    P = t.take(ik) * t.take(jl)
    P += t.take(il) * t.take(jk)
    P *= scale
    return P


# -- problem protocol -----------------------------------------------------------------------------
class ConicProblem(Protocol):
    """What :func:`solve_conic` needs from a problem: data and structured operators."""

    c: np.ndarray  # (n_x,)
    b: np.ndarray  # (n_eq,)
    h: np.ndarray  # (n_lp + sum svec sizes,)
    n_lp: int
    psd_sizes: tuple[int, ...]

    def G(self, x: np.ndarray) -> np.ndarray: ...

    def Gt(self, u: np.ndarray) -> np.ndarray: ...

    def A(self, x: np.ndarray) -> np.ndarray: ...

    def At(self, y: np.ndarray) -> np.ndarray: ...

    def kkt_factor(self, d_lp: np.ndarray, psd_T: list[np.ndarray]):
        """Prepare to solve ``[H A'; A 0] (x, y) = (bx, by)`` with
        ``H = G' D G``, ``D = diag(d_lp) (+) (X -> T X T for each PSD block)``;
        returns a callable ``(bx, by) -> (x, y, G x)`` (``G x`` too: the solver needs it
        next, and a structured solve has most of it at hand), valid until the next call
        (the problem may keep its buffers: the solver uses each factorisation in its own
        iteration only)."""
        ...


@dataclass(frozen=True)
class ConicSolution:
    """Primal-dual solution and solver statistics."""

    x: np.ndarray
    y: np.ndarray
    s: np.ndarray
    z: np.ndarray
    status: str  # "solved", "solved_reduced" or "failed"
    iterations: int
    primal_objective: float
    dual_objective: float
    gap: float
    residual: float  # largest relative primal/dual residual


# -- cone operations (LP part, then PSD blocks) ---------------------------------------------------
class _Cones:
    def __init__(self, n_lp: int, psd_sizes: tuple[int, ...]) -> None:
        self.n_lp = n_lp
        self.sizes = psd_sizes
        self.slices = []
        off = n_lp
        for n in psd_sizes:
            nt = n * (n + 1) // 2
            self.slices.append(slice(off, off + nt))
            off += nt
        self.dim = off
        self.degree = n_lp + sum(psd_sizes)
        self._e = np.zeros(self.dim)  # the identity element of the cone product
        self._e[:n_lp] = 1.0
        for n, sl in zip(psd_sizes, self.slices, strict=True):
            self._e[sl] = svec(np.eye(n))

    def identity(self) -> np.ndarray:
        return self._e.copy()

    def min_eig(self, u: np.ndarray) -> float:
        vals = [np.min(u[: self.n_lp])] if self.n_lp else []
        for n, sl in zip(self.sizes, self.slices, strict=True):
            vals.append(_min_eigval(smat(u[sl], n)))
        return float(min(vals))


def _min_eigval(X: np.ndarray) -> float:
    """Smallest eigenvalue of a small symmetric matrix (LAPACK ``syevr`` for that one
    eigenvalue: a quarter of the time of ``numpy.linalg.eigvalsh`` at n = 18)."""
    w, _, _, _, info = _syevr(X, compute_v=0, range="I", il=1, iu=1)
    if info != 0:
        raise np.linalg.LinAlgError("syevr did not converge")
    return float(w[0])


def _chol(X: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor; ``LinAlgError`` when not numerically positive definite
    (LAPACK directly: ``numpy.linalg.cholesky`` costs 10x more at n = 18)."""
    L, info = _potrf(X, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError("matrix not positive definite")
    return L


@dataclass
class _Scaling:
    """Nesterov-Todd scaling: ``W z = W^-T s = lambda``."""

    w: np.ndarray  # LP: sqrt(s / z)
    lam_lp: np.ndarray  # LP: sqrt(s z)
    R: list[np.ndarray]  # PSD: W'(X) = R X R'
    Rti: list[np.ndarray]  # PSD: R^-T
    lam_psd: list[np.ndarray]  # PSD: eigenvalues of the scaled point (diagonal)
    w_inv: np.ndarray  # LP: 1 / w
    d_lp: np.ndarray  # LP: w^-2, the diagonal of (W'W)^-1
    T: list[np.ndarray]  # PSD: (W'W)^-1 (X) = T X T, T = R^-T R^-1
    # PSD, for the products with lambda and the step length (computed once per scaling):
    lam_half: list[np.ndarray]  # (lam_i + lam_j) / 2 per svec entry
    isq_outer: list[np.ndarray]  # lam_i^-1/2 lam_j^-1/2, (n, n)


def _nt_scaling(cones: _Cones, s: np.ndarray, z: np.ndarray) -> _Scaling:
    m = cones.n_lp
    w = np.sqrt(s[:m] / z[:m])
    lam = np.sqrt(s[:m] * z[:m])
    Rs, Rtis, lams, halves, outers = [], [], [], [], []
    for n, sl in zip(cones.sizes, cones.slices, strict=True):
        Ls = _chol(smat(s[sl], n))
        Lz = _chol(smat(z[sl], n))
        U, lmb, Vt, info = _gesvd(Lz.T @ Ls)
        if info != 0:
            raise np.linalg.LinAlgError("SVD did not converge")
        isq = 1.0 / np.sqrt(lmb)
        Rs.append(Ls @ Vt.T * isq)
        Rtis.append(Lz @ U * isq)
        lams.append(lmb)
        i, j = _triu(n)[:2]
        halves.append(0.5 * (lmb.take(i) + lmb.take(j)))
        outers.append(isq[:, None] * isq[None, :])
    w_inv = 1.0 / w
    T = [Ri @ Ri.T for Ri in Rtis]
    return _Scaling(w, lam, Rs, Rtis, lams, w_inv, w_inv * w_inv, T, halves, outers)


def _apply(cones: _Cones, sc: _Scaling, u: np.ndarray, kind: str) -> np.ndarray:
    """Apply a scaling operator to a cone vector.

    kind: "Wt" (W'), "W" (W), "Winvt" (W^-T), "D" ((W'W)^-1).
    """
    m = cones.n_lp
    out = np.empty_like(u)
    scale = sc.w if kind in ("Wt", "W") else sc.w_inv if kind == "Winvt" else sc.d_lp
    np.multiply(scale, u[:m], out=out[:m])
    for n, sl, R, Rti, T in zip(cones.sizes, cones.slices, sc.R, sc.Rti, sc.T, strict=True):
        X = smat(u[sl], n)
        if kind == "Wt":
            Y = R @ X @ R.T
        elif kind == "W":
            Y = R.T @ X @ R
        elif kind == "Winvt":
            Y = Rti.T @ X @ Rti
        else:
            Y = T @ X @ T
        out[sl] = svec(Y)
    return out


def _lam_prod(cones: _Cones, sc: _Scaling, u: np.ndarray, divide: bool) -> np.ndarray:
    """``lambda o u`` (divide=False) or ``lambda \\ u`` (divide=True) in the scaled space."""
    m = cones.n_lp
    out = np.empty_like(u)
    # into the output (a temporary and its copy cost a 7K-long pass more at K observations)
    (np.divide if divide else np.multiply)(u[:m], sc.lam_lp, out=out[:m])
    for sl, half in zip(cones.slices, sc.lam_half, strict=True):
        # elementwise with (lam_i + lam_j) / 2: the same in svec coordinates, no smat/svec
        out[sl] = u[sl] / half if divide else u[sl] * half
    return out


def _sprod(cones: _Cones, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Jordan product ``a o b`` (elementwise; (XY + YX)/2 for matrices)."""
    m = cones.n_lp
    out = np.empty_like(a)
    np.multiply(a[:m], b[:m], out=out[:m])
    for n, sl in zip(cones.sizes, cones.slices, strict=True):
        X, Y = smat(a[sl], n), smat(b[sl], n)
        XY = X @ Y
        out[sl] = svec(0.5 * (XY + XY.T))
    return out


def _lam_sq(cones: _Cones, sc: _Scaling) -> np.ndarray:
    out = np.empty(cones.dim)
    np.multiply(sc.lam_lp, sc.lam_lp, out=out[: cones.n_lp])  # lam**2 is this product
    for n, sl, lam in zip(cones.sizes, cones.slices, sc.lam_psd, strict=True):
        i, j = _triu(n)[:2]
        out[sl] = np.where(i == j, lam.take(i) ** 2, 0.0)  # svec(diag(lam^2))
    return out


def _max_step(cones: _Cones, sc: _Scaling, dt: np.ndarray) -> float:
    """Largest ``a`` with ``lambda + a * dt`` in the cone (``dt`` in the scaled space)."""
    m = cones.n_lp
    worst = 0.0
    if m:
        worst = max(worst, -float(np.min(dt[:m] / sc.lam_lp)))  # max(-x) = -min(x) exactly
    for n, sl, isq_outer in zip(cones.sizes, cones.slices, sc.isq_outer, strict=True):
        X = smat(dt[sl], n) * isq_outer
        worst = max(worst, -_min_eigval(X))
    return np.inf if worst <= 0 else 1.0 / worst


def _kkt3(prob, cones, sc, solve, rhs):
    """Solve ``A'dy + G'dz = bx``, ``A dx = by``, ``G dx - W'W dz = bz`` through the reduced
    factorisation ``solve`` of ``[G'(W'W)^-1 G  A'; A  0]``."""
    bx, by, bz = rhs
    dx, dy, Gdx = solve(bx + prob.Gt(_apply(cones, sc, bz, "D")), by)
    dz = _apply(cones, sc, Gdx - bz, "D")
    return dx, dy, dz, Gdx


def _newton(prob, cones, sc, solve, res, rs):
    """Search direction: ``lambda o (W dz + W^-T ds) = rs`` plus the linearised residuals.

    (Iterative refinement on the full linear system was tried and measured not to help: at
    the stall the reduced matrix's Cholesky error is not small, and refinement diverges.)
    """
    rx, ry, rz = res
    rhs = (-rx, -ry, -rz - _apply(cones, sc, _lam_prod(cones, sc, rs, divide=True), "Wt"))
    dx, dy, dz, Gdx = _kkt3(prob, cones, sc, solve, rhs)
    ds = -rz - Gdx
    return dx, dy, ds, dz


# -- the solver -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Point:
    """A primal-dual iterate: ``x``, ``y`` (equalities), slack ``s`` and cone dual ``z``."""

    x: np.ndarray
    y: np.ndarray
    s: np.ndarray
    z: np.ndarray


@dataclass(frozen=True)
class _Stats:
    """Residuals and objectives of an iterate."""

    rx: np.ndarray  # dual residual c + A'y + G'z
    ry: np.ndarray  # primal equality residual A x - b
    rz: np.ndarray  # primal cone residual G x + s - h
    gap: float  # s . z
    pcost: float
    dcost: float
    pres: float  # relative primal residual
    dres: float  # relative dual residual

    @property
    def rel_gap(self) -> float:
        return self.gap / max(abs(self.pcost), abs(self.dcost), 1e-12)


def _starting_point(prob: ConicProblem, cones: _Cones) -> _Point:
    """CVXOPT's start: least-squares primal and dual points with W = I, shifted inside."""
    e = cones.identity()
    ident = [np.eye(n) for n in cones.sizes]
    solve = prob.kkt_factor(np.ones(cones.n_lp), ident)
    x, _, Gx = solve(prob.Gt(prob.h), prob.b)
    s = prob.h - Gx
    _, y, z = solve(-prob.c, np.zeros_like(prob.b))  # z = G xd
    for v in (s, z):
        a = cones.min_eig(v)
        if a <= 0:
            v += (1.0 - a) * e
    return _Point(x, y, s, z)


def _stats(prob: ConicProblem, p: _Point, norms: tuple[float, float, float]) -> _Stats:
    nrm_c, nrm_b, nrm_h = norms
    rx = prob.c + prob.At(p.y) + prob.Gt(p.z)
    ry = prob.A(p.x) - prob.b
    rz = prob.G(p.x) + p.s - prob.h
    pres = max(math.sqrt(ry @ ry) / nrm_b, math.sqrt(rz @ rz) / nrm_h)
    dres = math.sqrt(rx @ rx) / nrm_c
    pcost, dcost = float(prob.c @ p.x), float(-prob.b @ p.y - prob.h @ p.z)
    return _Stats(rx, ry, rz, float(p.s @ p.z), pcost, dcost, pres, dres)


def _step(prob, cones, p: _Point, st: _Stats, step_fraction, verbose):
    """Mehrotra predictor-corrector direction at ``p`` and its step length."""
    e = cones._e
    mu = st.gap / cones.degree
    sc = _nt_scaling(cones, p.s, p.z)
    solve = prob.kkt_factor(sc.d_lp, sc.T)
    lam2 = _lam_sq(cones, sc)
    res = (st.rx, st.ry, st.rz)
    dx, dy, ds, dz = _newton(prob, cones, sc, solve, res, -lam2)
    ds_t = _apply(cones, sc, ds, "Winvt")
    dz_t = _apply(cones, sc, dz, "W")
    a_aff = min(1.0, _max_step(cones, sc, ds_t), _max_step(cones, sc, dz_t))
    s_aff = p.s + a_aff * ds
    z_aff = p.z + a_aff * dz
    sigma = min(1.0, max(0.0, float(s_aff @ z_aff) / st.gap)) ** 3
    rs = -lam2 + sigma * mu * e - _sprod(cones, ds_t, dz_t)
    dx, dy, ds, dz = _newton(prob, cones, sc, solve, res, rs)
    ds_t = _apply(cones, sc, ds, "Winvt")
    dz_t = _apply(cones, sc, dz, "W")
    a_max = min(_max_step(cones, sc, ds_t), _max_step(cones, sc, dz_t))
    alpha = min(1.0, step_fraction * a_max)
    if verbose:
        print(f"      a_aff {a_aff:.3g} sigma {sigma:.3g} alpha {alpha:.3g}")
    return _Point(dx, dy, ds, dz), alpha


def solve_conic(
    prob: ConicProblem,
    *,
    tol_gap_rel: float = 1e-6,
    tol_gap_abs: float = 1e-8,
    tol_feas: float = 1e-8,
    max_iter: int = 60,
    step_fraction: float = 0.95,
    verbose: bool = False,
    start: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> ConicSolution:
    """Solve a :class:`ConicProblem`; see the module docstring.

    Stops when the relative primal and dual residuals are below ``tol_feas`` and the duality gap
    is below ``tol_gap_abs`` or ``tol_gap_rel`` relative to the objective: status
    ``"solved"``. When the iterations stall first (the scaled KKT system loses accuracy close to
    a rank-deficient optimum) the best iterate is returned with status ``"solved_reduced"`` if
    its residuals are below 1e-6 and its relative gap below 1e-4, else ``"failed"``.
    """
    cones = _Cones(prob.n_lp, tuple(prob.psd_sizes))
    norms = tuple(max(1.0, float(np.linalg.norm(v))) for v in (prob.c, prob.b, prob.h))
    p = _starting_point(prob, cones) if start is None else _Point(*start)
    status = "max_iter"
    it = 0
    best = None  # (merit, point, stats) of the best iterate so far
    stall = 0
    for it in range(max_iter + 1):
        st = _stats(prob, p, norms)
        if verbose:
            print(
                f"{it:3d} pcost {st.pcost: .9e} dcost {st.dcost: .9e} gap {st.gap:.2e} "
                f"pres {st.pres:.2e} dres {st.dres:.2e}"
            )
        if max(st.pres, st.dres) < tol_feas and (st.gap < tol_gap_abs or st.rel_gap < tol_gap_rel):
            status = "solved"
            break
        merit = max(
            st.pres / tol_feas,
            st.dres / tol_feas,
            min(st.gap / tol_gap_abs, st.rel_gap / tol_gap_rel),
        )
        # Close to a rank-deficient optimum the scaled KKT system loses accuracy and the
        # iterates stop improving: then return the best one instead of wandering off. (The
        # comparison is with the best *earlier* iterate: comparing after the update counted
        # every improving endgame iteration as a stall and stopped 3 iterations in.)
        endgame = max(st.pres, st.dres) < 1e-6 and st.rel_gap < 1e-3
        stall = stall + 1 if endgame and best is not None and merit >= 0.9 * best[0] else 0
        if best is None or merit < best[0]:
            best = (merit, p, st)
        if it == max_iter or stall >= 3:
            _, p, st = best
            break
        try:
            d, alpha = _step(prob, cones, p, st, step_fraction, verbose)
        except np.linalg.LinAlgError:  # s or z numerically singular: as close as it gets
            alpha = 0.0
        # A blocked step once the reduced tolerances hold is where the scaled KKT system has
        # lost its accuracy: the iterations after it wander (measured: 3-11 more iterations,
        # whose count depended on BLAS rounding, for a gap at most a few times smaller).
        blocked = alpha < 0.1 and max(st.pres, st.dres) < 1e-6 and st.rel_gap < 1e-4
        if alpha < 1e-10 or blocked:
            _, p, st = best
            break
        p = _Point(p.x + alpha * d.x, p.y + alpha * d.y, p.s + alpha * d.s, p.z + alpha * d.z)
    if status != "solved":
        # Clarabel's "AlmostSolved" analogue: reduced tolerances that the rounding and the local
        # refinement downstream comfortably absorb.
        reduced = max(st.pres, st.dres) < 1e-6 and (st.gap < 1e-6 or st.rel_gap < 1e-4)
        status = "solved_reduced" if reduced else "failed"
    return ConicSolution(
        x=p.x,
        y=p.y,
        s=p.s,
        z=p.z,
        status=status,
        iterations=it,
        primal_objective=st.pcost,
        dual_objective=st.dcost,
        gap=st.gap,
        residual=max(st.pres, st.dres),
    )


def dense_kkt_factor(H: np.ndarray, A: np.ndarray, work: np.ndarray | None = None):
    """Factor ``[H A'; A 0]`` for a small dense positive definite ``H`` of which only the lower
    triangle is read (pass a Fortran-ordered ``H`` to spare LAPACK a copy); returns
    ``(bx, by) -> (x, y)``.

    ``work``, a C-ordered float array of ``H``'s shape, receives the scaled matrix and its
    Cholesky factor instead of a fresh array (at M = 32 a fresh 6.5 MB array per iteration
    costs page faults); the returned solve then holds it and is valid until ``work`` is reused.

    ``H`` is symmetrically Jacobi-scaled (near the optimum its entries span many orders of
    magnitude) and factored by Cholesky; the equalities are eliminated through the small
    Schur complement ``A H^-1 A'``, also by Cholesky (``A`` has full row rank). Half the work
    of an LU of the whole indefinite matrix. Should rounding make either factor fail, the
    whole scaled matrix is factored by LU instead.
    """
    dH = np.diag(H)
    dsc = 1.0 / np.sqrt(np.maximum(dH, 1e-12 * max(1.0, float(np.max(dH)))))
    # dsc_i dsc_j is symmetric bit for bit (a product commutes), so a Fortran-ordered H is
    # scaled through its C-ordered transpose: one contiguous pass, no mixed-order iteration
    outer = np.multiply.outer(dsc, dsc, out=work)
    Hc = H.T if H.flags.f_contiguous else H
    Hs = np.multiply(Hc, outer, out=outer)  # in place: one 242 kB temporary fewer at n = 174
    Hs = Hs.T if H.flags.f_contiguous else Hs
    As = A * dsc[None, :]
    # LAPACK directly: scipy's cho_factor / cho_solve wrappers cost more than the work here.
    # With Hs = L L' and Y = L^-1 As', the Schur complement is Y'Y (one triangular solve
    # with the m right-hand sides instead of two, and positive semidefinite by construction).
    L, info = _potrf(Hs, lower=1, clean=0, overwrite_a=1)
    if info == 0:
        Y, info = _trtrs(L, As.T, lower=1)
        if info == 0:
            S, info = _potrf(Y.T @ Y, lower=1, clean=0, overwrite_a=1)
    if info != 0:  # not numerically positive definite
        return _lu_kkt_factor(H, A, dsc)

    def solve(bx: np.ndarray, by: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w, _ = _trtrs(L, dsc * bx, lower=1)
        y, _ = _potrs(S, Y.T @ w - by, lower=1)
        u, _ = _trtrs(L, w - Y @ y, lower=1, trans=1)
        return dsc * u, y

    return solve


def _lu_kkt_factor(H: np.ndarray, A: np.ndarray, dsc: np.ndarray):
    """LU of the Jacobi-scaled ``[H A'; A 0]`` (the fallback of :func:`dense_kkt_factor`; the
    lower triangle of ``H`` is read)."""
    n, m = H.shape[0], A.shape[0]
    K = np.zeros((n + m, n + m))
    H = np.tril(H) + np.tril(H, -1).T
    K[:n, :n] = H * dsc[:, None] * dsc[None, :]
    K[:n, n:] = (A * dsc[None, :]).T
    K[n:, :n] = K[:n, n:].T
    import scipy.linalg as sla  # a rare path: its import cost only where it runs

    lu = sla.lu_factor(K, check_finite=False)

    def solve(bx: np.ndarray, by: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sol = sla.lu_solve(lu, np.concatenate([dsc * bx, by]), check_finite=False)
        return dsc * sol[:n], sol[n:]

    return solve
