"""The G-SfT-P semidefinite program: one Gram matrix per view, shape weights tied across views.

Each view ``x`` has its own lifted unknowns ``xi_x = (1, vec R_x, w_x)`` and translation ``t_x``,
where ``(R_x, t_x)`` is the object's pose in that view's camera frame. The program (all lengths
already centred and scaled by the caller; see ``unknown_poses.py``)::

    minimise    sum_x [ eps_x tr(Delta_x) + sum_j a_xj || (V_xj - C_xj) x d_xj ||_1 ]
    subject to  V_xj = R_x mean_j + sum_i (w_i R_x) P_ij + t_x     (linear in Delta_x, t_x)
                rotation rows of every Delta_x          (``lifting.rotation_constraints``)
                Delta_x[0, 10:] = Delta_1[0, 10:]       (one shape for all views)
                (V_xj - C_xj) . d_xj >= point_depth_x   (every point in front of its source)
                t_x,3 >= f_x                             (the object in front of the camera)
                Delta_x PSD

plus an optional linear term ``c_x . t_x`` per view (``SdpViewBlock.t_cost``).

Every view's block is exactly the known-pose program of :class:`sdp.KnownPoseSDP` (same
variables, rows and cones); this module stacks those blocks block-diagonally for Clarabel and
adds the coupling and minimum-depth rows, so the per-view algebra exists in one place only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import clarabel
import numpy as np

from .lifting import svec_index, svec_to_matrix
from .sdp import KnownPoseData, KnownPoseSDP, SolverFailure

__all__: list[str] = []


@dataclass(frozen=True)
class SdpViewBlock:
    """One view's block of the G-SfT-P SDP (:func:`solve_multiview_sdp`), in normalised units:
    the known-pose program of that view's Gram matrix and a bound on its depth.

    Attributes
    ----------
    data : KnownPoseData
        The view's known-pose program (``sdp.KnownPoseData``: model data, the view's rays in
        its shifted, scaled frame, L1 weights, trace weight, minimum point depth, and the
        depth reward ``t_cost``, a negative multiple of the viewing direction; see
        ``unknown_poses.py``).
    min_tz : float
        Lower bound on the third coordinate of ``t_x`` (the model centroid's depth).
    """

    data: KnownPoseData
    min_tz: float


@dataclass(frozen=True)
class MultiViewSdpSolution:
    """Raw solution of :func:`solve_multiview_sdp` (normalised units)."""

    grams: list[np.ndarray]  # P x (10+M, 10+M)
    translations: np.ndarray  # (P, 3)
    objective: float
    status: str  # "solved" or "solved_reduced"
    iterations: int
    solve_time: float  # seconds, wall clock


def _settings(overrides: dict | None) -> clarabel.DefaultSettings:
    s = clarabel.DefaultSettings()
    s.verbose = False
    for key, val in dict(overrides or {}).items():
        if not hasattr(s, key):
            raise ValueError(f"solver_settings: unknown Clarabel setting {key!r}")
        setattr(s, key, val)
    return s


def solve_multiview_sdp(
    blocks: list[SdpViewBlock], n_modes: int, settings: dict | None = None
) -> MultiViewSdpSolution:
    """Assemble and solve the G-SfT-P SDP with Clarabel.

    Parameters
    ----------
    blocks : list of SdpViewBlock
        One entry per view (P >= 1).
    n_modes : int
        Number of shape modes M.
    settings : dict, optional
        Clarabel settings to override.

    Raises
    ------
    SolverFailure
        Clarabel did not reach (reduced-accuracy) optimality.
    """
    import scipy.sparse as sp  # here: the modules that import this one run without it

    A, b, q, cones, offsets, sdps = _stacked_views(blocks, n_modes)
    n_var = A.shape[1]
    nt = sdps[0].nt
    extra, b_extra, n_tie = _coupling_rows(blocks, sdps, offsets, n_modes, n_var)
    A_all = sp.vstack([A, extra], format="csc")
    b_all = np.concatenate([b, b_extra])
    if n_tie:
        cones.append(clarabel.ZeroConeT(n_tie))
    cones.append(clarabel.NonnegativeConeT(len(blocks)))
    P = sp.csc_matrix((n_var, n_var))
    t0 = time.perf_counter()
    solver = clarabel.DefaultSolver(P, q, A_all, b_all, cones, _settings(settings))
    sol = solver.solve()
    elapsed = time.perf_counter() - t0
    status = str(sol.status)
    if "Solved" not in status:
        raise SolverFailure(
            f"G-SfT-P SDP: Clarabel status {status} after {sol.iterations} iterations"
        )
    x = np.asarray(sol.x)
    if not np.all(np.isfinite(x)):
        raise SolverFailure("G-SfT-P SDP: the solver returned non-finite values")
    grams = [svec_to_matrix(x[o : o + nt], sdps[0].n) for o in offsets]
    ts = np.array([x[o + sdps[i].o_t : o + sdps[i].o_t + 3] for i, o in enumerate(offsets)])
    return MultiViewSdpSolution(
        grams=grams,
        translations=ts,
        objective=float(sol.obj_val),
        status="solved" if status == "Solved" else "solved_reduced",
        iterations=int(sol.iterations),
        solve_time=elapsed,
    )


def _stacked_views(blocks: list[SdpViewBlock], n_modes: int):
    """Each view's known-pose SDP block side by side: the block-diagonal constraint matrix,
    its right-hand side, the objective, the cones, each block's first variable and the
    blocks' :class:`KnownPoseSDP` (for their layout)."""
    import scipy.sparse as sp

    A_blocks, b_parts, q_parts, cones = [], [], [], []
    offsets, sdps = [], []
    off = 0
    for blk in blocks:
        sdp = KnownPoseSDP(len(blk.data), n_modes)
        # the known-pose block's own constraint values and objective (its fixed pattern)
        vals, b = sdp._values(blk.data)
        A_blocks.append(sp.csc_matrix((vals, sdp._A.indices, sdp._A.indptr), shape=sdp._A.shape))
        b_parts.append(b)
        q_parts.append(sdp._objective(blk.data))
        cones += list(sdp._cones)
        offsets.append(off)
        sdps.append(sdp)
        off += sdp.n_var
    A = sp.block_diag(A_blocks, format="csc")
    return A, np.concatenate(b_parts), np.concatenate(q_parts), cones, offsets, sdps


def _coupling_rows(blocks, sdps, offsets, n_modes: int, n_var: int):
    """The rows that tie the views: every view's shape weights equal the first view's (zero
    cone, ``n_tie`` rows), and each view's centroid in front of its source (``-t_z + s =
    -min_tz``, ``s >= 0``). ``(rows (sparse), right-hand side, n_tie)``."""
    import scipy.sparse as sp

    # shared weights: Delta_x[0, 10+i] - Delta_1[0, 10+i] = 0 (same svec coefficient in both)
    k_w, _ = svec_index(np.zeros(n_modes, dtype=int), 10 + np.arange(n_modes))
    rows, cols, data = [], [], []
    r = 0
    for x in range(1, len(blocks)):
        for k in k_w:
            rows += [r, r]
            cols += [offsets[x] + int(k), offsets[0] + int(k)]
            data += [1.0, -1.0]
            r += 1
    n_tie = r
    for x in range(len(blocks)):
        rows.append(r)
        cols.append(offsets[x] + sdps[x].o_t + 2)
        data.append(-1.0)
        r += 1
    extra = sp.csc_matrix((data, (rows, cols)), shape=(r, n_var))
    b_extra = np.concatenate([np.zeros(n_tie), [-blk.min_tz for blk in blocks]])
    return extra, b_extra, n_tie
