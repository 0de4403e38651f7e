"""G-SfT with known view poses: the convex SDP, rounding to SO(3) and a local refinement.

Pipeline of :func:`solve_gsft`:

1. validate the observations (``vertex_ids``, rays, ``sigmas``);
2. normalise: centre the model at its mean's centroid and the world at the point nearest to all
   rays, divide lengths by the model's RMS radius (the relaxation is markedly tighter and the
   conic solver more accurate in these units; see ``docs/solver.md``);
3. solve the SDP (``eps * tr(Delta) + sum_j a_j ||(V_j - C_j) x d_j||_1``); if the object lands
   far from the chosen centre (e.g. one perspective view, whose rays all meet at the source),
   re-centre on it and solve once more;
4. round: ``R`` = SVD projection of the rotation block read from the Gram matrix's first row,
   ``w`` = its weight entries, ``t`` from the SDP;
5. polish: Levenberg-Marquardt on the ray offsets plus the prior (``polish.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array, unit_directions
from ..ssm.model import ShapeModel
from .ipm import solve_conic
from .lifting import point_map_values
from .polish import polish_cost, polish_pose_shape, ray_offsets, tangent_bases
from .rotations import project_to_so3
from .sdp import KnownPoseIPM, KnownPoseSDP, SolverFailure, depth_reward

__all__ = ["GsftResult", "solve_gsft", "DEFAULT_EPS", "MIN_DEPTH_SIZES", "SolverFailure"]

#: Default trace weight per unit of observation weight (normalised units); see docs/solver.md.
DEFAULT_EPS = 1e-3
#: Default minimum depth of every observed point along its ray, in model sizes (RMS radii).
MIN_DEPTH_SIZES = 5.0
#: Default ``depth_reward_weight`` (a fraction of the L1 term's restoring rate).
DEFAULT_DEPTH_REWARD = 0.1

try:  # small dense BLAS calls: one thread is faster than two fighting over a shared machine
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - optional
    threadpool_limits = None


@dataclass(frozen=True)
class GsftResult:
    """Result of :func:`solve_gsft` (world frame, mm).

    Attributes
    ----------
    rotation : (3, 3) array
        Object-to-world rotation ``R``.
    translation : (3,) array
        Object-to-world translation ``t`` (mm): ``V = R (mean + sum w_i P_i) + t``.
    weights : (M,) array
        Shape weights (standard deviations when the model's modes are so scaled).
    vertices : (N, 3) array
        The registered shape, world frame, mm.
    certificate : float
        ``lambda_2 / lambda_1`` of the SDP's Gram matrix (0 = rank one = tight relaxation).
    objective : float
        SDP objective in its normalised units (see ``scale``).
    status : str
        Conic solver status: ``"solved"`` or ``"solved_reduced"`` (reduced accuracy that the
        refinement absorbs).
    sdp_rotation, sdp_translation, sdp_weights : arrays
        The rounded SDP solution before the local refinement.
    residuals : (K,) array
        Distance of each observed model point from its ray after refinement, mm.
    sdp_residuals : (K,) array
        The same for the rounded SDP solution.
    sigmas : (K,) array
        Standard deviations used by the refinement (given, or estimated from the residuals).
    polish_cost_before, polish_cost_after : float
        Refinement cost at the rounded SDP solution and at the result.
    polish_iterations : int
    polish_converged : bool
    eps : float
        Trace weight used (normalised units).
    scale : float
        Normalising length (model RMS radius, mm).
    centre : (3,) array
        Normalising world centre (mm).
    sdp_iterations : int
    backend : str
        ``"ipm"`` or ``"clarabel"`` (the one that produced the SDP solution).
    timings : dict
        Seconds: ``build``, ``solve``, ``polish``, ``total``.
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    certificate: float
    objective: float
    status: str
    sdp_rotation: np.ndarray
    sdp_translation: np.ndarray
    sdp_weights: np.ndarray
    residuals: np.ndarray
    sdp_residuals: np.ndarray
    sigmas: np.ndarray
    polish_cost_before: float
    polish_cost_after: float
    polish_iterations: int
    polish_converged: bool
    eps: float
    scale: float
    centre: np.ndarray
    sdp_iterations: int
    backend: str
    timings: dict = field(default_factory=dict)


@dataclass(frozen=True)
class _Observations:
    ids: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    sigmas: np.ndarray | None


def check_observations(
    model: ShapeModel,
    vertex_ids: object,
    origins: object,
    directions: object,
    sigmas: object | None,
) -> _Observations:
    """Validate the inputs of :func:`solve_gsft`; raise ``ValueError`` naming the argument."""
    if not isinstance(model, ShapeModel):
        raise ValueError(f"model: expected a ShapeModel, got {type(model).__name__}")
    ids = model.check_vertex_ids(vertex_ids)
    K = len(ids)
    o = as_array("origins", origins, (K, 3))
    d = unit_directions("directions", as_array("directions", directions, (K, 3)))
    s = None
    if sigmas is not None:
        s = as_array("sigmas", sigmas, (K,))
        if np.any(s <= 0):
            raise ValueError(f"sigmas: must be positive (row {int(np.argmin(s))} is {s.min()})")
    if K < 4:
        raise ValueError(f"vertex_ids: at least 4 observations are needed in total, got {K}")
    if len(np.unique(ids)) < 3:
        raise ValueError(
            "vertex_ids: observations of fewer than 3 distinct model points cannot fix the pose"
        )
    ev = np.linalg.eigvalsh(d.T @ d / K)
    if ev[1] < 1e-12 * ev[2]:
        raise ValueError(
            "directions: all rays are parallel (e.g. a single orthographic view); the depth "
            "along them is unobservable"
        )
    return _Observations(ids, o, d, s)


def nearest_point_to_rays(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Least-squares point closest to all rays (mm); for near-parallel rays, their centroid."""
    P = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]
    A = P.sum(axis=0)
    b = np.einsum("kij,kj->i", P, origins)
    ev = np.linalg.eigvalsh(A)
    if ev[0] < 1e-6 * ev[-1]:
        return origins.mean(axis=0)
    return np.linalg.solve(A, b)


def _solve_sdp(D, origins, directions, a, eps, n_modes, backend, settings, min_depth, t_cost):
    """One SDP solve in normalised units; returns (gram, t, objective, status, iters, backend)."""
    if backend in ("auto", "ipm"):
        prob = KnownPoseIPM(D, origins, directions, a, eps, n_modes, min_depth, t_cost)
        sol = solve_conic(prob, **(settings or {}))
        if sol.status != "failed" or backend == "ipm":
            if sol.status == "failed":
                raise SolverFailure(
                    f"SDP interior-point solver did not converge (residual {sol.residual:.2e}, "
                    f"gap {sol.gap:.2e} after {sol.iterations} iterations)"
                )
            from .ipm import smat

            gram = smat(sol.x[: prob.nt], prob.n)
            t = sol.x[prob.nt : prob.nt + 3]
            return gram, t, sol.primal_objective, sol.status, sol.iterations, "ipm"
    if backend not in ("auto", "clarabel", "ipm"):
        raise ValueError(f"backend: expected 'auto', 'ipm' or 'clarabel', got {backend!r}")
    sdp = KnownPoseSDP(len(D), n_modes, settings=settings if backend == "clarabel" else None)
    sol = sdp.solve(D, origins, directions, a, eps, min_depth, t_cost)
    status = "solved" if sol.status == "Solved" else "solved_reduced"
    return sol.gram, sol.translation, sol.objective, status, sol.iterations, "clarabel"


def solve_gsft(
    model: ShapeModel,
    vertex_ids: object,
    origins: object,
    directions: object,
    sigmas: object | None = None,
    *,
    eps: float = DEFAULT_EPS,
    polish: bool = True,
    prior_weight: float = 1.0,
    max_polish_iter: int = 50,
    min_depth: float | None = None,
    depth_reward_weight: float = DEFAULT_DEPTH_REWARD,
    backend: str = "auto",
    solver_settings: dict | None = None,
    initial: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> GsftResult:
    """Register a shape model to rays with known view poses (the seed paper's G-SfT).

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    vertex_ids : (K,) int array
        Model vertex observed by each ray.
    origins : (K, 3) array
        Ray origins in the world frame, mm (the X-ray source for a perspective view).
    directions : (K, 3) array
        Ray directions in the world frame (normalised here; zero length is an error).
    sigmas : (K,) array, optional
        Standard deviation of each observation's distance from its ray, mm (for a pixel with
        ``sigma_px``: ``sigma_px * pixel spacing * source-object / source-detector distance``).
        Relative values weight the SDP's terms (``a_j`` proportional to ``1 / sigma_j``);
        absolute values set the balance of data and prior in the refinement. When omitted,
        all observations weigh the same and the refinement estimates one common sigma from the
        residuals (so noise-free data is fitted exactly and noisy data gets the MAP estimate).
    eps : float
        Trace weight per unit observation weight, in normalised units: the SDP uses
        ``eps * K * tr(Delta)`` so the balance does not change with the number of observations.
    polish : bool
        Run the Levenberg-Marquardt refinement (default) after rounding.
    prior_weight : float
        Weight ``lambda`` of ``1/2 lambda ||w||^2`` in the refinement (1 = Gaussian prior with
        the model's standard deviations).
    max_polish_iter : int
        Iteration limit of the refinement.
    min_depth : float, optional
        Every observed point must lie at least this far (mm) in front of its ray's origin
        along the ray. Without it the relaxation can mix the solution with its mirror image
        behind the source and collapse the object onto the source (seen with one view).
        Default: ``MIN_DEPTH_SIZES`` (5) times the model's RMS radius; X-ray sources are much
        farther from the bone than that.
    depth_reward_weight : float
        In [0, 1). When every ray comes from one source (a single perspective view), a small
        linear reward on the depth along the mean ray keeps the relaxation tight (see
        :func:`sdp.depth_reward`: it cannot move a consistent solution). 0 = the paper's program.
    backend : {"auto", "ipm", "clarabel"}
        Conic solver: the project's structured interior-point method (fast), Clarabel (a general
        sparse solver, slower at many observations), or "auto": the IPM, falling back to
        Clarabel if the IPM does not converge.
    solver_settings : dict, optional
        Options for the backend (``solve_conic`` keywords or Clarabel settings).
    initial : (R, t, w), optional
        A second starting point for the local refinement (e.g. the previous iterate of
        silhouette boosting): the refinement also runs from it and the lower-cost result is
        kept, so a non-tight SDP cannot pull a good estimate into a worse basin.

    Returns
    -------
    GsftResult

    Raises
    ------
    ValueError
        Bad input (the message names the argument).
    SolverFailure
        The conic solver did not produce a usable solution.
    """
    t_start = time.perf_counter()
    obs = check_observations(model, vertex_ids, origins, directions, sigmas)
    if not np.isfinite(eps) or eps <= 0:
        raise ValueError(f"eps: must be a positive number, got {eps!r}")
    if not np.isfinite(depth_reward_weight) or not 0 <= depth_reward_weight < 1:
        raise ValueError(f"depth_reward_weight: must be in [0, 1), got {depth_reward_weight!r}")
    if not np.isfinite(prior_weight) or prior_weight < 0:
        raise ValueError(f"prior_weight: must be >= 0, got {prior_weight!r}")
    K, M = len(obs.ids), model.n_modes

    # -- normalisation --------------------------------------------------------------------------
    scale = model.size
    if scale <= 0:
        raise ValueError("model: the mean shape has zero extent")
    cm = model.mean.mean(axis=0)
    mean_pts = model.mean[obs.ids]  # mm, object frame
    mode_pts = model.modes[:, obs.ids]
    D = point_map_values((mean_pts - cm) / scale, mode_pts / scale)
    inv = np.ones(K) if obs.sigmas is None else 1.0 / obs.sigmas
    a = inv / inv.mean()
    eps_abs = eps * K
    depth_n = (MIN_DEPTH_SIZES * scale if min_depth is None else float(min_depth)) / scale
    centre = nearest_point_to_rays(obs.origins, obs.directions)
    # one central view (all rays from one source): reward depth so the relaxation stays tight
    central = np.ptp(obs.origins, axis=0).max() <= 1e-9 * max(1.0, np.abs(obs.origins).max())
    t_cost = depth_reward(obs.directions, a, depth_reward_weight) if central else None
    t_build = time.perf_counter() - t_start

    # -- SDP, re-centred once if the object is far from the guessed centre --------------------
    t0 = time.perf_counter()
    limits = threadpool_limits(1) if threadpool_limits is not None else None
    try:
        for _ in range(2):
            o_n = (obs.origins - centre) / scale
            gram, t_n, objective, status, iters, used = _solve_sdp(
                D, o_n, obs.directions, a, eps_abs, M, backend, solver_settings, depth_n, t_cost
            )
            if np.linalg.norm(t_n) <= 3.0:
                break
            centre = centre + scale * t_n
    finally:
        if limits is not None:
            limits.unregister()
    t_solve = time.perf_counter() - t0

    ev = np.linalg.eigvalsh(gram)
    certificate = float(max(ev[-2], 0.0) / ev[-1]) if ev[-1] > 0 else 1.0
    R_sdp = project_to_so3(gram[0, 1:10].reshape(3, 3))
    w_sdp = gram[0, 10:].copy()
    # V = R (Q - cm) / s * s + s t_n + centre  =>  t = s t_n + centre - R cm
    t_sdp = scale * t_n + centre - R_sdp @ cm

    # -- refinement -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    bases = tangent_bases(obs.directions)

    def offsets(R, t, w):
        V = (mean_pts + np.tensordot(w, mode_pts, axes=1)) @ R.T + t
        return np.linalg.norm(ray_offsets(V, obs.origins, bases), axis=1)

    sdp_res = offsets(R_sdp, t_sdp, w_sdp)
    R, t, w = R_sdp, t_sdp, w_sdp
    cost_before = cost_after = float("nan")
    p_iters, p_conv = 0, True
    if obs.sigmas is not None:
        sig = obs.sigmas
    else:
        sig = np.full(K, _estimate_sigma(sdp_res, K, M, scale))
    if polish:
        data = (mean_pts, mode_pts, obs.origins, obs.directions)
        for _ in range(10):  # sigma converges quadratically to 0 on noise-free data
            res = polish_pose_shape(
                R, t, w, *data, sig, prior_weight=prior_weight, max_iter=max_polish_iter
            )
            R, t, w = res.rotation, res.translation, res.weights
            p_iters, p_conv = p_iters + res.iterations, res.converged
            if obs.sigmas is not None:
                break
            # one common sigma, re-estimated from the refined residuals until it settles
            new = _estimate_sigma(offsets(R, t, w), K, M, scale)
            if abs(new - sig[0]) <= 0.1 * sig[0]:
                break
            sig = np.full(K, new)
        cost_before = polish_cost(R_sdp, t_sdp, w_sdp, *data, sig, prior_weight)
        cost_after = polish_cost(R, t, w, *data, sig, prior_weight)
        if cost_after > cost_before:  # sigma moved between rounds: restart from the SDP point
            res = polish_pose_shape(
                R_sdp,
                t_sdp,
                w_sdp,
                *data,
                sig,
                prior_weight=prior_weight,
                max_iter=max_polish_iter,
            )
            R, t, w, cost_after = res.rotation, res.translation, res.weights, res.cost_after
            p_iters, p_conv = p_iters + res.iterations, res.converged
        if initial is not None:
            R0, t0_, w0 = (np.asarray(a, dtype=float) for a in initial)
            alt = polish_pose_shape(
                R0,
                t0_,
                model.check_weights(w0),
                *data,
                sig,
                prior_weight=prior_weight,
                max_iter=max_polish_iter,
            )
            if alt.cost_after < cost_after:
                R, t, w, cost_after = alt.rotation, alt.translation, alt.weights, alt.cost_after
                p_iters, p_conv = p_iters + alt.iterations, alt.converged
    t_polish = time.perf_counter() - t0
    vertices = model.instance(w) @ R.T + t
    return GsftResult(
        rotation=R,
        translation=t,
        weights=w,
        vertices=vertices,
        certificate=certificate,
        objective=float(objective),
        status=status,
        sdp_rotation=R_sdp,
        sdp_translation=t_sdp,
        sdp_weights=w_sdp,
        residuals=offsets(R, t, w),
        sdp_residuals=sdp_res,
        sigmas=sig,
        polish_cost_before=float(cost_before),
        polish_cost_after=float(cost_after),
        polish_iterations=p_iters,
        polish_converged=p_conv,
        eps=eps_abs,
        scale=scale,
        centre=centre,
        sdp_iterations=iters,
        backend=used,
        timings={
            "build": t_build,
            "solve": t_solve,
            "polish": t_polish,
            "total": time.perf_counter() - t_start,
        },
    )


def common_sigma(distances: np.ndarray, dof: int, scale: float) -> float:
    """One sigma (mm) for all ray offsets: RMS per offset component corrected for the ``dof``
    degrees of freedom left after fitting, floored at 1e-9 of the model size (noise-free
    data)."""
    return max(float(np.sqrt(np.sum(distances**2) / max(dof, 1))), 1e-9 * scale)


def _estimate_sigma(distances: np.ndarray, K: int, M: int, scale: float) -> float:
    """:func:`common_sigma` for K two-component offsets and a fit of 6 + M parameters."""
    return common_sigma(distances, 2 * K - 6 - M, scale)
