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
5. refine: Levenberg-Marquardt on the ray offsets plus the prior (``refine.py``).

The conic solvers (``backend``): the structured interior-point method (``ipm.py`` with
``sdp.KnownPoseIPM``), Clarabel on the explicit-point form (``sdp.KnownPoseSDP``) and the same
program stated readably in cvxpy (``cvxpy_program.py``, the reference statement).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial

import numpy as np

from ..pose import nearest_rotation
from ..ssm.model import ShapeModel
from .ipm import smat, solve_conic
from .lifting import point_map_values
from .rays import RayObservations, check_rays
from .refine import (
    DEFAULT_MAX_REFINE_ITER,
    PoseShape,
    ray_distances,
    refine_cost,
    refine_pose_shape,
    tangent_bases,
)
from .sdp import KnownPoseData, KnownPoseIPM, KnownPoseSDP, SdpSolution, SolverFailure, depth_reward

__all__ = [
    "GsftResult",
    "solve_gsft",
    "DEFAULT_EPS",
    "DEFAULT_DEPTH_REWARD",
    "MIN_DEPTH_SIZES",
    "RECENTRE_DISTANCE",
]

#: Default trace weight per unit of observation weight (normalised units); see docs/solver.md.
DEFAULT_EPS = 1e-3
#: Default minimum depth of every observed point along its ray, in model sizes (RMS radii).
MIN_DEPTH_SIZES = 5.0
#: Default ``depth_reward_weight`` (a fraction of the L1 term's restoring rate).
DEFAULT_DEPTH_REWARD = 0.1
#: The conic solvers of ``solve_gsft(..., backend=...)``.
BACKENDS = ("auto", "ipm", "clarabel", "cvxpy")
#: Clarabel settings of the ``backend="auto"`` fallback (used only when the IPM fails): a bound
#: on its time (seconds) and iterations, so a last resort cannot run for minutes.
FALLBACK_SETTINGS = {"time_limit": 30.0, "max_iter": 100}
#: Barrier parameter of an IPM warm start (``warm_start=``): measured by
#: ``benchmarks/warm_start.py`` (smaller values take more iterations than a cold start).
WARM_START_MU = 0.1
#: The SDP is solved again, centred on the object, when it lands farther than this from the
#: guessed centre (normalised units: model RMS radii).
RECENTRE_DISTANCE = 3.0

try:  # small dense BLAS calls: one thread is faster than two fighting over a shared machine
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover - optional
    ThreadpoolController = None


@lru_cache(maxsize=1)
def _threadpools() -> object | None:
    """The process's BLAS/OpenMP thread pools, found once (finding them takes ~1 ms, a
    ``threadpool_limits`` per solve did it every time; limiting found pools takes 10 us)."""
    return ThreadpoolController() if ThreadpoolController is not None else None


def _one_thread() -> object | None:
    """Limit the thread pools to one thread until ``.unregister()`` (None without threadpoolctl)."""
    pools = _threadpools()
    return pools.limit(limits=1) if pools is not None else None


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
    refine_cost_before, refine_cost_after : float
        Refinement cost at the rounded SDP solution and at the result.
    refine_iterations : int
    refine_converged : bool
    eps : float
        Trace weight used (normalised units).
    scale : float
        Normalising length (model RMS radius, mm).
    centre : (3,) array
        Normalising world centre (mm).
    sdp_iterations : int
    backend : str
        ``"ipm"``, ``"clarabel"`` or ``"cvxpy"`` (the one that produced the SDP solution).
    timings : dict
        Seconds: ``build``, ``solve``, ``refine`` (the refinement), ``total``.
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
    refine_cost_before: float
    refine_cost_after: float
    refine_iterations: int
    refine_converged: bool
    eps: float
    scale: float
    centre: np.ndarray
    sdp_iterations: int
    backend: str
    timings: dict = field(default_factory=dict)


def check_model(model: object) -> None:
    """Check that ``model`` is a :class:`ShapeModel` whose mean shape has an extent (its size,
    the RMS radius in mm, is the solvers' normalising length)."""
    if not isinstance(model, ShapeModel):
        raise ValueError(f"model: expected a ShapeModel, got {type(model).__name__}")
    if model.size <= 0:
        raise ValueError("model: the mean shape has zero extent")


def check_options(
    eps: float, prior_weight: float, depth_reward_weight: float, backend: str = "auto"
) -> None:
    """Check the options the solvers share (``ValueError`` naming the option)."""
    if not np.isfinite(eps) or eps <= 0:
        raise ValueError(f"eps: must be a positive number, got {eps!r}")
    if not np.isfinite(depth_reward_weight) or not 0 <= depth_reward_weight < 1:
        raise ValueError(f"depth_reward_weight: must be in [0, 1), got {depth_reward_weight!r}")
    if not np.isfinite(prior_weight) or prior_weight < 0:
        raise ValueError(f"prior_weight: must be >= 0, got {prior_weight!r}")
    if backend not in BACKENDS:
        raise ValueError(
            f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}"
        )


def nearest_point_to_rays(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Least-squares point closest to all rays (mm); for near-parallel rays, their centroid."""
    P = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]
    A = P.sum(axis=0)
    b = np.einsum("kij,kj->i", P, origins)
    ev = np.linalg.eigvalsh(A)
    if ev[0] < 1e-6 * ev[-1]:
        return origins.mean(axis=0)
    return np.linalg.solve(A, b)


@dataclass(frozen=True)
class _Normalised:
    """The known-pose program's data in the solver's units (``docs/solver.md``,
    Normalisation): model centred at ``cm`` and divided by ``scale``."""

    scale: float  # model RMS radius, mm
    cm: np.ndarray  # (3,) centroid of the mean shape, object frame, mm
    D: np.ndarray  # (K, 3 + 3M) per-observation model data (``lifting.point_map_values``)
    a: np.ndarray  # (K,) weights of the L1 terms (1 / sigma normalised to mean 1)
    eps: float  # trace weight, eps * K
    min_depth: float  # minimum depth of every point along its ray, normalised
    t_cost: np.ndarray | None  # (3,) depth reward of a central view, or None


def _normalise(
    model: ShapeModel,
    rays: RayObservations,
    eps: float,
    min_depth: float | None,
    depth_reward_weight: float,
) -> _Normalised:
    scale = model.size
    cm = model.mean.mean(axis=0)
    ids = rays.vertex_ids
    D = point_map_values((model.mean[ids] - cm) / scale, model.modes[:, ids] / scale)
    inv = np.ones(len(rays)) if rays.sigmas is None else 1.0 / rays.sigmas
    a = inv / inv.mean()
    depth = (MIN_DEPTH_SIZES * scale if min_depth is None else float(min_depth)) / scale
    # one central view (all rays from one source): reward depth so the relaxation stays tight
    t_cost = depth_reward(rays.directions, a, depth_reward_weight) if rays.is_central else None
    return _Normalised(scale, cm, D, a, eps * len(rays), depth, t_cost)


@dataclass(frozen=True)
class _SdpSolution:
    """One solve of the program: Gram matrix and translation in normalised units."""

    gram: np.ndarray  # (10 + M, 10 + M)
    t_n: np.ndarray  # (3,) translation, normalised, relative to ``centre``
    objective: float
    status: str  # "solved" or "solved_reduced"
    iterations: int
    backend: str  # the backend that produced it
    centre: np.ndarray | None = None  # (3,) world point (mm) the program was centred on


def _warm_point(ipm: KnownPoseIPM, warm: GsftResult, prob: _Normalised, centre: np.ndarray):
    """The IPM start at ``warm``'s rounded SDP solution, in the units of ``prob`` centred at
    ``centre`` (the previous solve's centre need not be this one)."""
    R, w = warm.sdp_rotation, warm.sdp_weights
    xi = np.concatenate([[1.0], R.ravel(), w])
    t_n = (R @ prob.cm + warm.sdp_translation - centre) / prob.scale
    return ipm.warm_point(np.outer(xi, xi), t_n, WARM_START_MU)


def _solve_ipm(
    data: KnownPoseData, settings: dict | None, strict: bool, start=None
) -> _SdpSolution | None:
    """The structured interior-point solve (from ``start(ipm)`` when given, else cold); None
    when it did not converge (a :class:`SolverFailure` when ``strict``)."""
    ipm = KnownPoseIPM(data)
    sol = solve_conic(ipm, **(settings or {}), start=None if start is None else start(ipm))
    if sol.status == "failed" and start is not None:  # a poor warm start: once more, cold
        sol = solve_conic(ipm, **(settings or {}))
    if sol.status == "failed":
        if strict:
            raise SolverFailure(
                f"SDP interior-point solver did not converge (residual {sol.residual:.2e}, "
                f"gap {sol.gap:.2e} after {sol.iterations} iterations)"
            )
        return None
    gram, t = smat(sol.x[: ipm.nt], ipm.n), sol.x[ipm.nt : ipm.nt + 3]
    return _SdpSolution(gram, t, sol.primal_objective, sol.status, sol.iterations, "ipm")


def _solved(sol: SdpSolution, backend: str, status: str) -> _SdpSolution:
    return _SdpSolution(sol.gram, sol.translation, sol.objective, status, sol.iterations, backend)


def _solve_sdp(
    data: KnownPoseData, backend: str, settings: dict | None, start=None
) -> _SdpSolution:
    """One SDP solve of ``data`` with ``backend`` (``"auto"``: the IPM, Clarabel if the IPM
    does not converge); ``start(ipm)`` gives the IPM's warm start (the others take none)."""
    if backend in ("auto", "ipm"):
        sol = _solve_ipm(data, settings, strict=backend == "ipm", start=start)
        if sol is not None:
            return sol
    if backend == "cvxpy":
        from .cvxpy_program import solve_known_pose_cvxpy  # cvxpy is slow to import

        sol = solve_known_pose_cvxpy(data, settings)
        return _solved(sol, "cvxpy", sol.status)
    # the IPM's settings are not Clarabel's: a fallback from "auto" uses bounded defaults
    fallback = settings if backend == "clarabel" else FALLBACK_SETTINGS
    sdp = KnownPoseSDP(len(data), data.n_modes, fallback)
    sol = sdp.solve(data)
    return _solved(sol, "clarabel", "solved" if sol.status == "Solved" else "solved_reduced")


def _solve_recentred(
    prob: _Normalised,
    rays: RayObservations,
    backend: str,
    settings: dict | None,
    warm: GsftResult | None = None,
) -> _SdpSolution:
    """The SDP centred at the point nearest to all rays, solved once more centred on the object
    if it lands farther than ``RECENTRE_DISTANCE`` from that guess (e.g. one perspective view,
    whose rays all meet at the source)."""
    centre = nearest_point_to_rays(rays.origins, rays.directions)
    limits = _one_thread()
    try:
        for attempt in range(2):
            data = KnownPoseData(
                prob.D,
                rays.normalised(centre, prob.scale),
                prob.a,
                prob.eps,
                prob.min_depth,
                prob.t_cost,
            )
            start = partial(_warm_point, warm=warm, prob=prob, centre=centre) if warm else None
            out = _solve_sdp(data, backend, settings, start)
            if attempt == 1 or np.linalg.norm(out.t_n) <= RECENTRE_DISTANCE:
                break
            centre = centre + prob.scale * out.t_n
    finally:
        if limits is not None:
            limits.unregister()
    return replace(out, centre=centre)


def _round(prob: _Normalised, sol: _SdpSolution) -> tuple[float, PoseShape]:
    """Certificate ``lambda_2 / lambda_1`` and the rounded ``(R, t, w)`` (world, mm)."""
    ev = np.linalg.eigvalsh(sol.gram)
    certificate = float(max(ev[-2], 0.0) / ev[-1]) if ev[-1] > 0 else 1.0
    R = nearest_rotation(sol.gram[0, 1:10].reshape(3, 3))
    w = sol.gram[0, 10:].copy()
    # V = R (Q - cm) / s * s + s t_n + centre  =>  t = s t_n + centre - R cm
    t = prob.scale * sol.t_n + sol.centre - R @ prob.cm
    return certificate, (R, t, w)


@dataclass(frozen=True)
class _Refined:
    """Outcome of the refinement stage of :func:`solve_gsft`."""

    state: PoseShape  # (R, t, w), world frame, mm
    sigmas: np.ndarray  # (K,) mm, given or estimated
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool


def _refine_with_sigma_estimate(
    model: ShapeModel,
    rays: RayObservations,
    start: PoseShape,
    sig: np.ndarray,
    prior_weight: float,
    max_iter: int,
) -> tuple[PoseShape, np.ndarray, int, bool]:
    """Refine from ``start``; without given sigmas re-estimate the common sigma from the
    refined residuals until it settles. Returns the state, the sigmas, iterations, converged."""
    state, iters, converged = start, 0, True
    bases = tangent_bases(rays.directions)
    K, M = len(rays), model.n_modes
    for _ in range(10):  # sigma converges quadratically to 0 on noise-free data
        res = refine_pose_shape(
            model, rays.with_sigmas(sig), state, prior_weight=prior_weight, max_iter=max_iter
        )
        state = (res.rotation, res.translation, res.weights)
        iters, converged = iters + res.iterations, res.converged
        if rays.sigmas is not None:
            break
        # one common sigma, re-estimated from the refined residuals until it settles
        new = _estimate_sigma(ray_distances(model, rays, state, bases), K, M, model.size)
        if abs(new - sig[0]) <= 0.1 * sig[0]:
            break
        sig = np.full(K, new)
    return state, sig, iters, converged


def _refine_stage(
    model: ShapeModel,
    rays: RayObservations,
    sdp_state: PoseShape,
    sdp_dist: np.ndarray,
    initial: PoseShape | None,
    refine: bool,
    prior_weight: float,
    max_iter: int,
) -> _Refined:
    """Sigmas and the local refinement from the rounded SDP solution (and ``initial``)."""
    if rays.sigmas is not None:
        sig = rays.sigmas
    else:
        sig = np.full(len(rays), _estimate_sigma(sdp_dist, len(rays), model.n_modes, model.size))
    if not refine:
        return _Refined(sdp_state, sig, float("nan"), float("nan"), 0, True)
    state, sig, iters, conv = _refine_with_sigma_estimate(
        model, rays, sdp_state, sig, prior_weight, max_iter
    )
    final = rays.with_sigmas(sig)
    cost_before = refine_cost(model, final, sdp_state, prior_weight)
    cost_after = refine_cost(model, final, state, prior_weight)
    opts = {"prior_weight": prior_weight, "max_iter": max_iter}
    if cost_after > cost_before:  # sigma moved between rounds: restart from the SDP point
        res = refine_pose_shape(model, final, sdp_state, **opts)
        state, cost_after = (res.rotation, res.translation, res.weights), res.cost_after
        iters, conv = iters + res.iterations, res.converged
    if initial is not None:
        R0, t0, w0 = (np.asarray(a, dtype=float) for a in initial)
        alt = refine_pose_shape(model, final, (R0, t0, model.check_weights(w0)), **opts)
        if alt.cost_after < cost_after:
            state, cost_after = (alt.rotation, alt.translation, alt.weights), alt.cost_after
            iters, conv = iters + alt.iterations, alt.converged
    return _Refined(state, sig, float(cost_before), float(cost_after), iters, conv)


def solve_gsft(
    model: ShapeModel,
    rays: RayObservations,
    *,
    eps: float = DEFAULT_EPS,
    refine: bool = True,
    prior_weight: float = 1.0,
    max_refine_iter: int = DEFAULT_MAX_REFINE_ITER,
    min_depth: float | None = None,
    depth_reward_weight: float = DEFAULT_DEPTH_REWARD,
    backend: str = "auto",
    solver_settings: dict | None = None,
    initial: PoseShape | None = None,
    warm_start: GsftResult | None = None,
) -> GsftResult:
    """Register a shape model to rays with known view poses (the seed paper's G-SfT).

    One call form: ``solve_gsft(model, rays, **options)`` with a :class:`RayObservations`
    (world frame; from arrays: ``RayObservations(vertex_ids, origins, directions, sigmas)``),
    every option by keyword.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    rays : RayObservations
        The rays in the world frame, mm, one per observed model vertex: ``vertex_ids`` (K,),
        ``origins`` (K, 3) (the X-ray source of a perspective view), ``directions`` (K, 3)
        (normalised; zero length is an error) and optional ``sigmas`` (K,): the standard
        deviation of each observation's distance from its ray, mm (for a pixel with
        ``sigma_px``: ``sigma_px * pixel spacing * source-object / source-detector distance``).
        Relative sigmas weight the SDP's terms (``a_j`` proportional to ``1 / sigma_j``);
        absolute values set the balance of data and prior in the refinement. Without sigmas
        all observations weigh the same and the refinement estimates one common sigma from the
        residuals (so noise-free data is fitted exactly and noisy data gets the MAP estimate).
    eps : float
        Trace weight per unit observation weight, in normalised units: the SDP uses
        ``eps * K * tr(Delta)`` so the balance does not change with the number of observations.
    refine : bool
        Run the Levenberg-Marquardt refinement (default) after rounding.
    prior_weight : float
        Weight ``lambda`` of ``1/2 lambda ||w||^2`` in the refinement (1 = Gaussian prior with
        the model's standard deviations).
    max_refine_iter : int
        Iteration limit of each refinement run (default ``DEFAULT_MAX_REFINE_ITER``, 50).
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
    backend : {"auto", "ipm", "clarabel", "cvxpy"}
        Conic solver: the project's structured interior-point method (fast), Clarabel (a general
        sparse solver, slower at many observations), the same program stated in cvxpy and
        solved by Clarabel through it (the readable reference statement,
        ``cvxpy_program.py``; slowest), or "auto": the IPM, falling back to Clarabel if the
        IPM does not converge.
    solver_settings : dict, optional
        Options for the backend (``solve_conic`` keywords, Clarabel settings, or for "cvxpy"
        keywords of ``cvxpy.Problem.solve`` such as Clarabel settings).
    initial : (R, t, w), optional
        A second starting point for the local refinement (e.g. the previous iterate of
        outline boosting): the refinement also runs from it and the lower-cost result is
        kept, so a non-tight SDP cannot pull a good estimate into a worse basin.
    warm_start : GsftResult, optional
        A previous solution of a nearly identical problem (e.g. the previous boosting
        iterate, any K): the interior-point method starts near its rounded SDP solution
        (``WARM_START_MU``), which took 14 instead of 18 iterations on average in
        ``benchmarks/warm_start.py``; a failed warm solve is repeated cold. Other backends
        ignore it. Default: a cold start (the same result as before it existed).

    Returns
    -------
    GsftResult

    Raises
    ------
    TypeError
        ``rays`` is not a :class:`RayObservations`.
    ValueError
        Bad input (the message names the argument).
    SolverFailure
        The conic solver did not produce a usable solution.
    """
    t_start = time.perf_counter()
    check_model(model)
    if not isinstance(rays, RayObservations):
        raise TypeError(
            f"rays: expected a RayObservations (RayObservations(vertex_ids, origins, "
            f"directions, sigmas)), got {type(rays).__name__}"
        )
    check_rays(model, rays)
    check_options(eps, prior_weight, depth_reward_weight, backend)
    prob = _normalise(model, rays, eps, min_depth, depth_reward_weight)
    t_build = time.perf_counter() - t_start

    t0 = time.perf_counter()
    sol = _solve_recentred(prob, rays, backend, solver_settings, warm_start)
    t_solve = time.perf_counter() - t0
    certificate, sdp_state = _round(prob, sol)

    t0 = time.perf_counter()
    bases = tangent_bases(rays.directions)
    sdp_dist = ray_distances(model, rays, sdp_state, bases)
    fit = _refine_stage(
        model, rays, sdp_state, sdp_dist, initial, refine, prior_weight, max_refine_iter
    )
    t_refine = time.perf_counter() - t0
    R, t, w = fit.state
    return GsftResult(
        rotation=R,
        translation=t,
        weights=w,
        vertices=model.instance(w) @ R.T + t,
        certificate=certificate,
        objective=float(sol.objective),
        status=sol.status,
        sdp_rotation=sdp_state[0],
        sdp_translation=sdp_state[1],
        sdp_weights=sdp_state[2],
        residuals=ray_distances(model, rays, fit.state, bases),
        sdp_residuals=sdp_dist,
        sigmas=fit.sigmas,
        refine_cost_before=fit.cost_before,
        refine_cost_after=fit.cost_after,
        refine_iterations=fit.iterations,
        refine_converged=fit.converged,
        eps=prob.eps,
        scale=prob.scale,
        centre=sol.centre,
        sdp_iterations=sol.iterations,
        backend=sol.backend,
        timings={
            "build": t_build,
            "solve": t_solve,
            "refine": t_refine,
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
