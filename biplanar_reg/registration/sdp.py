"""The known-pose G-SfT semidefinite program, compiled once and re-solved with new data.

Problem (all coordinates already centred and scaled to unit object size by the caller)::

    minimise    eps * tr(Delta) + sum_j a_j * || (V_j - C_j) x d_j ||_1
    subject to  V_j = R mean_j + sum_i (w_i R) P_ij + t        (linear in Delta, t)
                rotation rows of Delta (see ``lifting.rotation_constraints``)
                Delta PSD

It is written for Clarabel's conic form ``min q'x  s.t.  A x + s = b, s in cones`` with the
variables ``x = (svec Delta, t, V_1..V_K, e_1..e_K)``: the world points ``V_j`` are explicit
(3 equality rows each, ``4 + 3M`` non-zeros per row) and ``e_j`` bounds ``|(V_j - C_j) x d_j|``
component-wise (two inequality rows each, three non-zeros per row); one more inequality row per
observation keeps its point in front of the ray origin, ``(V_j - C_j) . d_j >= min_depth``.
Keeping the points explicit keeps the constraint matrix sparse (about ``K * (9M + 30)``
non-zeros instead of ``K * (18M + 30)`` for the substituted form), which is what keeps the KKT
factorisation affordable.

The sparsity pattern depends only on ``(K, M)``, so :class:`KnownPoseSDP` assembles it once and
each :meth:`KnownPoseSDP.solve` only refreshes the numbers (Clarabel's ``update``, which skips the
symbolic factorisation). Explicit zeros are kept so that the pattern never changes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import clarabel
import numpy as np

from ..errors import SolverFailure
from .ipm import dense_kkt_factor, skron_triu, smat, svec
from .lifting import (
    gram_size,
    point_map_pattern,
    rotation_constraints,
    svec_index,
    svec_size,
    svec_to_matrix,
)
from .rays import RayObservations

__all__ = ["KnownPoseData", "KnownPoseSDP", "KnownPoseIPM"]


@dataclass(frozen=True)
class KnownPoseData:
    """The data of one known-pose SDP, in normalised units (centred on the object, scaled to
    unit model size): what every backend (:class:`KnownPoseIPM`, :class:`KnownPoseSDP`,
    ``cvxpy_program.known_pose_program``) and every G-SfT-P view block solves.

    Attributes
    ----------
    D : (K, 3 + 3M) array
        Per-observation model data (``lifting.point_map_values``): the observed point's mean
        coordinates, then its displacement in each mode (object frame, centred and scaled).
    rays : RayObservations
        The rays in the normalised frame (``RayObservations.normalised``; unit directions).
    obs_weights : (K,) array
        Weight ``a_j`` of each observation's L1 term.
    eps : float
        Trace weight (already multiplied by K, as ``gsft.solve_gsft`` does).
    min_depth : float
        Minimum distance of every observed point from its ray's origin along the ray.
    t_cost : (3,) array, optional
        Linear cost on ``t`` (the depth reward of a central view, :func:`depth_reward`).
    """

    D: np.ndarray
    rays: RayObservations
    obs_weights: np.ndarray
    eps: float
    min_depth: float = 0.0
    t_cost: np.ndarray | None = None

    @property
    def n_modes(self) -> int:
        """Number of shape modes M (from the width of ``D``)."""
        return (self.D.shape[1] - 3) // 3

    def __len__(self) -> int:
        return len(self.D)


@dataclass(frozen=True)
class SdpSolution:
    """Raw solution of one SDP solve, in the solver's (scaled) units."""

    gram: np.ndarray  # (10+M, 10+M)
    translation: np.ndarray  # (3,)
    points: np.ndarray  # (K, 3) world points V_j
    objective: float
    status: str
    iterations: int
    solve_time: float  # seconds (wall clock)


def _cross_rows() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row k of ``[d]_x`` has two entries: ``(col_a, sign_a * d[idx_a]), (col_b, ...)``."""
    # [d]_x = [[0, -d2, d1], [d2, 0, -d0], [-d1, d0, 0]]
    cols = np.array([[1, 2], [0, 2], [0, 1]])
    didx = np.array([[2, 1], [2, 0], [1, 0]])
    sign = np.array([[-1.0, 1.0], [1.0, -1.0], [-1.0, 1.0]])
    return cols, didx, sign


class KnownPoseSDP:
    """The G-SfT SDP for ``n_obs`` observations of a model with ``n_modes`` modes.

    Parameters
    ----------
    n_obs : int
        Number of observations (rays) K.
    n_modes : int
        Number of shape modes M.
    settings : dict, optional
        Clarabel settings to override (e.g. ``{"tol_gap_rel": 1e-7}``).
    """

    def __init__(self, n_obs: int, n_modes: int, settings: dict | None = None) -> None:
        self.n_obs = K = int(n_obs)
        self.n_modes = M = int(n_modes)
        self.n = n = gram_size(M)
        self.nt = nt = svec_size(n)
        self._settings = dict(settings or {})
        # variable offsets
        self.o_t = nt
        self.o_v = nt + 3
        self.o_e = nt + 3 + 3 * K
        self.n_var = nt + 3 + 6 * K

        A_rot, b_rot = rotation_constraints(n)
        self._b_rot = b_rot
        n_rot = A_rot.shape[0]
        rot_row, rot_col = np.nonzero(A_rot)  # row-major, as a COO of the rows would be
        rows, cols = self._pattern(n_rot)
        self._set_order(np.concatenate([rot_row, rows]), np.concatenate([rot_col, cols]))
        self._static_vals = {
            "rot": A_rot[rot_row, rot_col],
            "vd_one": np.ones(3 * K),
            "vd_t": -np.ones(3 * K),
            "psd": -np.ones(nt),
        }
        self._cones = [
            clarabel.ZeroConeT(n_rot + 3 * K),
            clarabel.NonnegativeConeT(7 * K),
            clarabel.PSDTriangleConeT(n),
        ]
        self._n_rot = n_rot
        diag_k, _ = svec_index(np.arange(n), np.arange(n))
        self._diag_k = diag_k
        self._solver: clarabel.DefaultSolver | None = None

    def _pattern(self, row0: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows and columns of the constraint matrix's entries below the ``row0`` rotation
        rows, in order: the point definitions, the ``|r| <= e`` rows, the depth rows, the PSD
        block; sets ``n_con`` and the index arrays :meth:`_values` fills them by."""
        K, nt = self.n_obs, self.nt
        # --- V definition rows: V_jr - sum_s coef * D_js x_k - t_r = 0 -------------------------
        kpat, cpat = point_map_pattern(self.n_modes)  # (3, S)
        S = kpat.shape[1]
        self._kpat, self._cpat = kpat, cpat
        jr = np.arange(3 * K)  # row index j*3 + r within the block
        r_of = jr % 3
        vd_rows = np.concatenate([np.repeat(row0 + jr, S), row0 + jr, row0 + jr])
        vd_cols = np.concatenate([kpat[r_of].ravel(), self.o_v + jr, self.o_t + r_of])
        # --- |r| <= e rows -----------------------------------------------------------------------
        cols, _, _ = _cross_rows()
        row1 = row0 + 3 * K
        comp = np.arange(3)
        jk = (np.arange(K)[:, None] * 3 + comp[None, :]).ravel()  # (3K,) j*3+k
        k_of = jk % 3
        j2 = jk // 3
        ineq_rows = []
        ineq_cols = []
        for half in range(2):
            rows = row1 + half * 3 * K + jk
            ineq_rows += [rows, rows, rows]
            ineq_cols += [
                self.o_e + jk,
                self.o_v + 3 * j2 + cols[k_of, 0],
                self.o_v + 3 * j2 + cols[k_of, 1],
            ]
        # depth rows: s = (V_j - C_j) . d_j >= 0
        row_d = row1 + 6 * K
        ineq_rows.append(np.repeat(row_d + np.arange(K), 3))
        ineq_cols.append(self.o_v + np.arange(3 * K))
        row2 = row_d + K
        self.n_con = row2 + nt
        self._j_of, self._r_of, self._jk, self._k_of, self._j2 = jr // 3, r_of, jk, k_of, j2
        all_rows = np.concatenate([vd_rows, *ineq_rows, row2 + np.arange(nt)])
        return all_rows, np.concatenate([vd_cols, *ineq_cols, np.arange(nt)])

    def _set_order(self, all_rows: np.ndarray, all_cols: np.ndarray) -> None:
        """The constraint matrix's CSC pattern (``_A``) and the permutation from the order of
        ``all_rows``/``all_cols`` to its data order (``_perm``; no duplicates by
        construction)."""
        import scipy.sparse as sp  # Clarabel's path only: the IPM's register path goes without

        order = sp.csc_matrix(
            (np.arange(1, len(all_rows) + 1, dtype=float), (all_rows, all_cols)),
            shape=(self.n_con, self.n_var),
        )
        order.sort_indices()
        if order.nnz != len(all_rows):
            raise AssertionError("duplicate entries in the SDP pattern")
        self._perm = order.data.astype(np.int64) - 1
        self._A = order
        self._P = sp.csc_matrix((self.n_var, self.n_var))

    # ------------------------------------------------------------------------------------------
    def _values(self, data: KnownPoseData) -> tuple[np.ndarray, np.ndarray]:
        """Data-dependent values of A (in CSC order) and b."""
        K = self.n_obs
        D, min_depth = data.D, data.min_depth
        origins, directions = data.rays.origins, data.rays.directions
        cols, didx, sign = _cross_rows()
        vd = -(self._cpat[self._r_of] * D[self._j_of]).ravel()  # (3K*S,)
        d = directions
        # cross-product entries for each (j, k): sign * d_j[didx]
        cx = sign[self._k_of] * d[self._j2[:, None], didx[self._k_of]]  # (3K, 2)
        e_coef = -np.ones(3 * K)
        vals = np.concatenate(
            [
                self._static_vals["rot"],
                vd,
                self._static_vals["vd_one"],
                self._static_vals["vd_t"],
                e_coef,
                -cx[:, 0],
                -cx[:, 1],
                e_coef,
                cx[:, 0],
                cx[:, 1],
                -d.ravel(),
                self._static_vals["psd"],
            ]
        )
        cxd = np.cross(origins, directions).ravel()  # (3K,) C_j x d_j
        depth = -np.einsum("ki,ki->k", origins, directions) - min_depth
        b = np.concatenate([self._b_rot, np.zeros(3 * K), cxd, -cxd, depth, np.zeros(self.nt)])
        return vals[self._perm], b

    def _objective(self, data: KnownPoseData) -> np.ndarray:
        q = np.zeros(self.n_var)
        q[self._diag_k] = data.eps
        q[self.o_e :] = np.repeat(data.obs_weights, 3)
        if data.t_cost is not None:
            q[self.o_t : self.o_t + 3] = data.t_cost
        return q

    def _make_settings(self) -> clarabel.DefaultSettings:
        s = clarabel.DefaultSettings()
        s.verbose = False
        s.presolve_enable = False  # required for data updates
        s.input_sparse_dropzeros = False  # keep the pattern fixed
        for key, val in self._settings.items():
            if not hasattr(s, key):
                raise ValueError(f"settings: unknown Clarabel setting {key!r}")
            setattr(s, key, val)
        return s

    def solve(self, data: KnownPoseData) -> SdpSolution:
        """Solve for new ``data`` (same K and M as at construction)."""
        A_data, b = self._values(data)
        q = self._objective(data)
        t0 = time.perf_counter()
        if self._solver is None:
            import scipy.sparse as sp

            A = sp.csc_matrix((A_data, self._A.indices, self._A.indptr), shape=self._A.shape)
            self._solver = clarabel.DefaultSolver(
                self._P, q, A, b, self._cones, self._make_settings()
            )
        else:
            self._solver.update(q=q, A=A_data, b=b)
        sol = self._solver.solve()
        elapsed = time.perf_counter() - t0
        status = str(sol.status)
        if "Solved" not in status:
            raise SolverFailure(f"SDP solver status {status} after {sol.iterations} iterations")
        x = np.asarray(sol.x)
        gram = svec_to_matrix(x[: self.nt], self.n)
        return SdpSolution(
            gram=gram,
            translation=x[self.o_t : self.o_t + 3].copy(),
            points=x[self.o_v : self.o_e].reshape(self.n_obs, 3).copy(),
            objective=float(sol.obj_val),
            status=status,
            iterations=int(sol.iterations),
            solve_time=elapsed,
        )


def depth_reward(directions: np.ndarray, weights: np.ndarray, reward: float) -> np.ndarray:
    """Linear cost on the translation that rewards depth along a central view's mean ray.

    Scaling a central (point-source) view's solution about the source keeps every point on its
    ray, and the relaxation can realise any scale ``s <= 1`` (a mixture of rotations, rank > 1)
    at the same trace, so with one view it is not tight. A reward ``-mu m . t`` selects
    ``s = 1``. It is ``reward`` times the rate ``sum_j a_j |m x d_j|`` at which the L1 term grows
    when the object slides along ``m`` without scaling, so for ``reward < 1`` it cannot move a
    consistent solution (an exact-penalty argument) and adds no bias on noise-free data.

    Parameters
    ----------
    directions : (K, 3) array
        Unit ray directions of one central view (any frame; the cost is in the same frame).
    weights : (K,) array
        The L1 terms' weights ``a_j``.
    reward : float
        In [0, 1).
    """
    m = directions.mean(axis=0)
    m /= np.linalg.norm(m)
    rate = float(np.sum(weights * np.linalg.norm(np.cross(m, directions), axis=1)))
    return -reward * rate * m


_P120, _P201 = np.array([1, 2, 0]), np.array([2, 0, 1])  # the cross product's cyclic shifts


class KnownPoseIPM:
    """The same SDP as :class:`KnownPoseSDP` as a structured :class:`ipm.ConicProblem`.

    Variables ``x = (svec Delta, t, e)``; the world points are substituted. Constraints
    ``e -/+ r >= 0`` with ``r_j = V_j x d_j - C_j x d_j``, the depth rows
    ``(V_j - C_j) . d_j >= 0`` (the paper's positive-depth assumption: without them a single
    view admits the mirror solution behind the source) and ``Delta PSD``; the rotation rows are
    the equalities. :meth:`kkt_factor` eliminates ``e`` analytically and forms the reduced
    matrix over ``(Delta, t)`` as ``sum_j`` of per-observation rank-3 terms with six dense
    products of the ``(K, 4 + 3M)`` data matrix, then factors that small dense system.
    """

    def __init__(self, data: KnownPoseData) -> None:
        D, n_modes = data.D, data.n_modes
        K = self.K = len(D)
        self.n = n = gram_size(n_modes)
        self.nt = svec_size(n)
        self.nz = self.nt + 3
        self.D = D
        self.Dt = np.column_stack([D, np.ones(K)])
        # observation-major copy: the products W_jq Dt_j of kkt_factor with rows of K
        # contiguous entries (2.5x faster than broadcasting over the rows of Dt), into a
        # buffer reused every iteration (a fresh 1.3 MB array per iteration costs page faults)
        self._DtT = np.ascontiguousarray(self.Dt.T)
        self._WDt = np.empty((6, self.Dt.shape[1], K))
        self._Hu = np.zeros((self.nz, self.nz))  # the reduced matrix's upper triangle
        self._Hs = np.empty((self.nz, self.nz))  # its scaled form and Cholesky factor
        self._set_directions(data.rays.directions)
        lay = _layout(n_modes)
        self.kpat, self.cpat, self.A_eq, self.b = lay.kpat, lay.cpat, lay.A_eq, lay.b
        self.A_full = lay.A_full
        self._lay = lay
        self.n_lp = 7 * K
        self.psd_sizes = (n,)
        self.c, self.h = self._cost_and_bounds(data)

    def _set_directions(self, directions: np.ndarray) -> None:
        """The ray directions (K, 3) and the index arrays of the cross products ``V x d``."""
        K = len(directions)
        self.d = directions
        # V x d = V[:, (1, 2, 0)] * d[:, (2, 0, 1)] - V[:, (2, 0, 1)] * d[:, (1, 2, 0)]
        self._d201 = directions[:, [2, 0, 1]].ravel()
        self._d120 = directions[:, [1, 2, 0]].ravel()
        # flat indices of V[:, (1, 2, 0)] and V[:, (2, 0, 1)]: a flat take costs a tenth of
        # ``take(..., axis=1)``, which copies the (K, 3) array element by element
        rows3 = 3 * np.arange(K)[:, None]
        self._i120 = (rows3 + _P120).ravel()
        self._i201 = (rows3 + _P201).ravel()
        self._dT = np.ascontiguousarray(directions.T)  # contiguous components, for kkt_factor

    def _cost_and_bounds(self, data: KnownPoseData) -> tuple[np.ndarray, np.ndarray]:
        """The cost ``c`` (the trace weight on the Gram diagonal, the translation's cost, the
        L1 terms' weights on ``e``) and the right-hand side ``h`` of the cone constraints."""
        n, nt = self.n, self.nt
        origins, directions = data.rays.origins, data.rays.directions
        c = np.zeros(self.nz + 3 * self.K)
        diag_k, _ = svec_index(np.arange(n), np.arange(n))
        c[diag_k] = data.eps
        c[self.nz :] = np.repeat(data.obs_weights, 3)
        if data.t_cost is not None:
            c[nt : nt + 3] = data.t_cost
        cxd = np.cross(origins, directions).ravel()
        # depth rows: (V_j - C_j) . d_j >= min_depth, every point in front of its ray's origin
        depth0 = np.einsum("ki,ki->k", origins, directions) + data.min_depth
        return c, np.concatenate([cxd, -cxd, -depth0, np.zeros(nt)])

    def warm_point(self, gram: np.ndarray, t: np.ndarray, mu: float):
        """An interior primal-dual start near the primal point ``(gram, t)`` (normalised
        units): the Gram matrix moved inside by ``sqrt(mu)``, bounds ``e`` just above the
        residuals, and dual points ``z = mu / s`` (``Z = mu S^-1``) on the central path."""
        n, nt, K = self.n, self.nt, self.K
        beta = np.sqrt(mu)
        x = np.zeros(self.nz + 3 * K)
        x[:nt] = svec(gram + beta * np.eye(n))
        x[nt : nt + 3] = t
        x[self.nz :] = np.abs(self._B(x[: self.nz]) - self.h[: 3 * K]) + beta
        s = self.h - self.G(x)
        lp = 7 * K
        s[:lp] = np.maximum(s[:lp], beta)
        z = np.empty_like(s)
        z[:lp] = mu / s[:lp]
        z[lp:] = svec(mu * np.linalg.inv(smat(s[lp:], n)))
        return x, np.zeros(len(self.b)), s, z

    # -- the linear map z = (Delta, t) -> r = V x d (without the constant) -----------------------
    def points(self, z: np.ndarray) -> np.ndarray:
        """World points ``V_j`` (K, 3) for ``z = (svec Delta, t)``."""
        # row r maps Dt_j to coordinate r
        Y = (z.take(self._lay.zidx) * self._lay.zcoef).reshape(3, -1)
        return self.Dt @ Y.T

    def _xd(self, V: np.ndarray) -> np.ndarray:
        """Row-wise ``V_j x d_j`` (K, 3)."""
        flat = V.ravel()
        out = flat.take(self._i120)
        out *= self._d201
        b = flat.take(self._i201)
        b *= self._d120
        out -= b
        return out.reshape(self.K, 3)

    def _B(self, z: np.ndarray) -> np.ndarray:
        return self._xd(self.points(z)).ravel()

    def _Vt(self, gV: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Adjoint of :meth:`points`: gradient (K, 3) on the points -> gradient on ``z``
        (into ``out``, of length ``nz``, when given)."""
        out = np.zeros(self.nz) if out is None else out
        out[self._lay.zidx] = (self.Dt.T @ gV).T.ravel() * self._lay.zcoef  # distinct indices
        return out

    def _Bt(self, v: np.ndarray) -> np.ndarray:
        return self._Vt(-self._xd(v.reshape(self.K, 3)))  # d/dV of sum v . (V x d)

    # -- ConicProblem -----------------------------------------------------------------------------
    def G(self, x: np.ndarray) -> np.ndarray:
        z = x[: self.nz]
        V = self.points(z)
        return self._G_of(z, x[self.nz :], V, self._xd(V).ravel())

    def _G_of(self, z: np.ndarray, e: np.ndarray, V: np.ndarray, Bz: np.ndarray) -> np.ndarray:
        """``G x`` for ``x = (z, e)`` from the points ``V`` of ``z`` and ``Bz = V x d``
        (written into one array: no per-part temporaries and concatenation)."""
        m, K = 3 * self.K, self.K
        out = np.empty(2 * m + K + self.nt)
        np.subtract(Bz, e, out=out[:m])
        u2 = out[m : 2 * m]
        np.negative(Bz, out=u2)
        u2 -= e
        # -(V_j . d_j) by whole columns (einsum over rows of 3 costs ~80 instructions a row),
        # summed as numpy's einsum sums three products, (a0 + a2) + a1: bitwise its result
        depth = out[2 * m : 2 * m + K]
        dT = self._dT
        np.multiply(V[:, 0], dT[0], out=depth)
        depth += V[:, 2] * dT[2]
        depth += V[:, 1] * dT[1]
        np.negative(depth, out=depth)
        np.negative(z[: self.nt], out=out[2 * m + K :])
        return out

    def Gt(self, u: np.ndarray) -> np.ndarray:
        m = 3 * self.K
        u1, u2 = u[:m], u[m : 2 * m]
        u4, u3 = u[2 * m : 2 * m + self.K], u[2 * m + self.K :]
        out = np.empty(self.nz + m)
        out[: self.nz] = 0.0  # the e part is written whole below: no zero fill of it
        gV = self._xd((u2 - u1).reshape(self.K, 3))
        for k in range(3):  # column by column: a (K, 1) x (K, 3) broadcast runs buffered
            gV[:, k] -= u4 * self._dT[k]
        self._Vt(gV, out[: self.nz])
        out[: self.nt] -= u3
        e = out[self.nz :]
        np.add(u1, u2, out=e)
        np.negative(e, out=e)
        return out

    def A(self, x: np.ndarray) -> np.ndarray:
        return self.A_eq @ x[: self.nt]

    def At(self, y: np.ndarray) -> np.ndarray:
        out = np.zeros(self.nz + 3 * self.K)
        out[: self.nt] = self.A_eq.T @ y
        return out

    def kkt_factor(self, d_lp: np.ndarray, psd_T: list[np.ndarray]):
        m = 3 * self.K
        d1, d2, d4 = d_lp[:m], d_lp[m : 2 * m], d_lp[2 * m :]
        dsum = d1 + d2
        omega = (4.0 * d1 * d2 / dsum).reshape(self.K, 3)
        # sum_j W_j[r, r2] Dt_j Dt_j' for the 6 pairs r <= r2
        WpT = _ray_weights(self._dT, omega.T.copy(), d4)
        # one (p, K) x (K, 6p) product (measured faster than a (6, K) x (K, p(p+1)/2) product
        # with precomputed Dt_ja Dt_jb: a 6-row product streams the larger matrix at a poor rate)
        np.multiply(WpT[:, None, :], self._DtT[None, :, :], out=self._WDt)
        blocks = self._DtT @ self._WDt.reshape(-1, self.K).T
        lay = self._lay
        # the upper triangle of H, C order: its transpose is H's lower triangle in Fortran order,
        # what the Cholesky reads (half of the assembly work, no copy)
        # into a buffer kept by the problem (a fresh zeroed 242 kB matrix per iteration cost a
        # memset of its every byte): its lower triangle stays zero, the skron entries are
        # overwritten, and the data-block targets outside them are reset before the sum
        Hu = self._Hu
        flat = Hu.reshape(-1)
        flat[lay.svec_triu] = skron_triu(psd_T[0])
        flat[lay.h_outside] = 0.0
        flat[lay.h_index] += blocks.reshape(-1).take(lay.h_take) * lay.h_coef
        fac = dense_kkt_factor(Hu.T, self.A_full, self._Hs)  # valid until the next call
        d21 = d2 - d1
        ratio = d21 / dsum

        def solve(bx: np.ndarray, by: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            bz, be = bx[: self.nz], bx[self.nz :]
            z, y = fac(bz - self._Bt(ratio * be), by)
            V = self.points(z)
            Bz = self._xd(V).ravel()
            x = np.empty(len(bx))  # (z, e) written in place: no concatenation copy
            x[: self.nz] = z
            e = x[self.nz :]
            np.divide(be - d21 * Bz, dsum, out=e)
            # G x from the points already at hand (the solver needs it next)
            return x, y, self._G_of(z, e, V, Bz)

        return solve


def _ray_weights(dT: np.ndarray, omegaT: np.ndarray, d_depth: np.ndarray) -> np.ndarray:
    """Upper triangles ``(00, 01, 02, 11, 12, 22)`` of the 3 x 3 matrices
    ``W_j = [d_j]_x' diag(omega_j) [d_j]_x + d_depth_j d_j d_j'``, one row per entry: (6, K).

    ``dT`` and ``omegaT`` are (3, K): component-major, so that every operation below runs on
    contiguous rows. Written out entry by entry: a batched (K, 3, 3) matmul is several times
    slower.
    """
    d0, d1, d2 = dT
    w0, w1, w2 = omegaT
    W = np.empty((6, len(d_depth)))
    W[0] = w1 * d2 * d2 + w2 * d1 * d1 + d_depth * d0 * d0
    W[1] = (d_depth - w2) * d0 * d1
    W[2] = (d_depth - w1) * d0 * d2
    W[3] = w0 * d2 * d2 + w2 * d0 * d0 + d_depth * d1 * d1
    W[4] = (d_depth - w0) * d1 * d2
    W[5] = w0 * d1 * d1 + w1 * d0 * d0 + d_depth * d2 * d2
    return W


@dataclass(frozen=True)
class _Layout:
    """What :class:`KnownPoseIPM` needs that depends on the number of modes only."""

    kpat: np.ndarray
    cpat: np.ndarray
    zidx: np.ndarray  # coordinate r of V_j = Dt_j . (cv_r * z[idx_r]), the three in one
    zcoef: np.ndarray
    A_eq: np.ndarray  # rotation rows on svec(Delta)
    A_full: np.ndarray  # the same on z = (svec Delta, t)
    b: np.ndarray
    svec_triu: np.ndarray  # flat indices of the PSD block's upper triangle in the (nz, nz) H
    h_index: np.ndarray  # see _data_block_layout
    h_coef: np.ndarray
    h_take: np.ndarray
    h_outside: np.ndarray  # the h_index targets outside svec_triu (zeroed per assembly)


_LAYOUTS: dict[int, _Layout] = {}


def _layout(n_modes: int) -> _Layout:
    """The :class:`_Layout` of ``n_modes`` (a memo: a pure function of ``n_modes``; building
    it costs ~1 ms, the registration builds a problem per solve)."""
    if n_modes not in _LAYOUTS:
        n = gram_size(n_modes)
        nt = svec_size(n)
        nz = nt + 3
        kpat, cpat = point_map_pattern(n_modes)
        zidx = np.concatenate([np.append(kpat[r], nt + r) for r in range(3)])
        zcoef = np.concatenate([np.append(cpat[r], 1.0) for r in range(3)])
        A_rot, b = rotation_constraints(n)
        A_eq = A_rot
        rows, cols = np.triu_indices(nt)
        svec_triu = rows * nz + cols
        h_index, h_coef, h_take = _data_block_layout(zidx, zcoef, nt)
        _LAYOUTS[n_modes] = _Layout(
            kpat,
            cpat,
            zidx,
            zcoef,
            A_eq,
            np.hstack([A_eq, np.zeros((len(b), 3))]),
            b,
            svec_triu,
            h_index,
            h_coef,
            h_take,
            np.setdiff1d(h_index, svec_triu),
        )
    return _LAYOUTS[n_modes]


def _data_block_layout(
    zidx: np.ndarray, zcoef: np.ndarray, nt: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the data blocks of :meth:`KnownPoseIPM.kkt_factor` go in the reduced matrix.

    Coordinate ``r`` of a point reads the entries ``idx_r = zidx[r p : (r + 1) p]`` of ``z``
    (coefficients ``cv_r = zcoef[r p : (r + 1) p]``) times ``Dt_j``, so block ``(r, r2)`` of
    ``sum_j W_j[r, r2] Dt_j Dt_j'`` adds ``cv_r cv_r2' *`` it at ``(idx_r, idx_r2)`` and its
    transpose at ``(idx_r2, idx_r)``. The ``idx_r`` are disjoint, so every target is hit
    once. Block ``q`` (the pairs of ``np.triu_indices(3)``) is columns ``q p : (q + 1) p`` of
    the ``(p, 6p)`` product.

    Returns the flat target indices into the upper triangle of the ``(nt + 3)^2`` matrix and,
    per target, the coefficient and the entry of the flattened ``(p, 6p)`` product it takes.
    """
    nz = nt + 3
    p = len(zidx) // 3
    idx, cv = zidx.reshape(3, p), zcoef.reshape(3, p)
    pairs = np.triu_indices(3)
    targets, takes, coefs = [], [], []
    a, b = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
    for q, (r, r2) in enumerate(zip(*pairs, strict=True)):
        src = (a * 6 * p + q * p + b).ravel()  # entry (a, b) of block q
        targets.append((idx[r][:, None] * nz + idx[r2][None, :]).ravel())
        takes.append(src)
        coef = (cv[r][:, None] * cv[r2][None, :]).ravel()
        coefs.append(coef)
        if r != r2:
            targets.append((idx[r2][None, :] * nz + idx[r][:, None]).ravel())
            takes.append(src)
            coefs.append(coef)
    targets, coefs, takes = (np.concatenate(a) for a in (targets, coefs, takes))
    upper = targets // nz <= targets % nz  # the upper triangle only (H is symmetric)
    return targets[upper], coefs[upper], takes[upper]
