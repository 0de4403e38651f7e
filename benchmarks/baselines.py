"""Baselines the seed paper compares G-SfT with, for the benchmarks (not part of the package).

* :func:`prox_admm` -- Zhou et al. (CVPR 2015), "3D shape estimation from 2D landmarks: a convex
  relaxation approach", written from the paper's description. Weak perspective, one view: the
  image points ``W`` (2 x K, centred) are modelled as ``sum_i M_i B_i`` with ``M_i = c_i Rbar_i``
  (``Rbar_i`` 2 x 3 with orthonormal rows). The non-convex set of such ``M_i`` is replaced by
  its convex hull, the spectral-norm ball, giving

  ``min_M 1/2 ||W - sum_i M_i B_i||_F^2 + lam * sum_i ||M_i||_2``,

  solved by ADMM on the split ``M = Z``: the ``M`` step is the proximal operator of the
  spectral norm (:func:`spectral_norm_prox`, computed from an SVD), the ``Z`` step a small
  linear solve, and the penalty ``mu`` follows the standard residual-balancing rule (Boyd et
  al. 2011, section 3.4.1: double when the primal residual is 10x the dual one, halve in the
  opposite case). Our adaptation to a statistical shape model: the bases are the model's mean
  (``B_0``) and its modes, and since an SSM has one rotation, the solution is rounded to one
  rotation (the best rank-one fit of the stacked ``M_i``, projected to orthonormal rows) and
  coefficients ``c_i``; the weights are ``w_i = c_i / c_0`` and ``c_0`` the image scale.
* :func:`repeated_single_view` -- the "trivial" multi-view approach: solve every view alone with
  :func:`biplanar_reg.registration.solve_gsft` (known poses, world frame), rigidly align the
  per-view reconstructions (generalised Procrustes) and take their Euclidean mean.

Units: model and world coordinates in mm; weak-perspective image coordinates in any unit (the
scale absorbs it).

Used by ``benchmarks/known_poses_single_view.py``, ``benchmarks/known_poses_multi_view.py`` (as
``from baselines import ...``: the scripts run from ``benchmarks/``) and
``tests/test_baselines.py`` (``import benchmarks.baselines``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from biplanar_reg.pose import Pose
from biplanar_reg.registration import GsftResult, RayObservations, solve_gsft
from biplanar_reg.ssm.build import procrustes_align
from biplanar_reg.ssm.model import ShapeModel

__all__ = [
    "spectral_norm_prox",
    "ProxAdmmResult",
    "prox_admm",
    "DEFAULT_PROX_LAMBDA",
    "RepeatedSingleViewResult",
    "repeated_single_view",
    "combine_reconstructions",
]

#: Default ``lam`` of :func:`prox_admm` per observation, in normalised units (image points and
#: the mean shape both scaled to unit RMS radius); chosen by ``benchmarks/known_poses_single_view.py
#: --lambda-sweep`` (see docs/benchmarks.md).
DEFAULT_PROX_LAMBDA = 1e-3


def _as_array(name: str, value: object, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (``None``: any length); a ``ValueError``
    names the argument."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be read as a numeric array ({exc})") from None
    if arr.ndim != len(shape) or any(
        w is not None and h != w for h, w in zip(arr.shape, shape, strict=True)
    ):
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


def _project_l1_ball(v: np.ndarray, radius: float) -> np.ndarray:
    """Row-wise projection of non-negative vectors (B, n) onto ``{x >= 0, sum x <= radius}``."""
    u = -np.sort(-v, axis=1)
    css = np.cumsum(u, axis=1)
    k = np.arange(1, v.shape[1] + 1)
    rho = np.sum(u * k > css - radius, axis=1) - 1  # the condition holds on a prefix
    rho = np.maximum(rho, 0)
    theta = (css[np.arange(len(v)), rho] - radius) / (rho + 1.0)
    theta = np.where(v.sum(axis=1) <= radius, 0.0, theta)
    return np.maximum(v - theta[:, None], 0.0)


def _spectral_prox_batch(X: np.ndarray, alpha: float) -> np.ndarray:
    """:func:`spectral_norm_prox` of each matrix of a stack (B, m, n)."""
    U, s, Vt = np.linalg.svd(X, full_matrices=False)
    shrunk = s - _project_l1_ball(s, alpha)
    return np.einsum("bij,bj,bjk->bik", U, shrunk, Vt)


def spectral_norm_prox(X: object, alpha: float) -> np.ndarray:
    """Proximal operator of ``alpha * ||X||_2`` (largest singular value).

    ``argmin_Y alpha ||Y||_2 + 1/2 ||Y - X||_F^2``. By Moreau's decomposition it is ``X`` minus
    the projection of ``X`` onto the nuclear-norm ball of radius ``alpha``; on the singular
    values ``s`` this is ``s - P(s)`` with ``P`` the projection onto the l1 ball, i.e. the
    largest singular values are shrunk to a common level ``tau`` with ``sum (s - tau)_+ =
    alpha`` (zero when ``sum s <= alpha``). Singular vectors are kept.

    Parameters
    ----------
    X : (m, n) array
    alpha : float
        Non-negative threshold.

    Returns
    -------
    (m, n) array
    """
    x = _as_array("X", X, (None, None))
    if not np.isfinite(alpha) or alpha < 0:
        raise ValueError(f"alpha: must be a number >= 0, got {alpha!r}")
    return _spectral_prox_batch(x[None], float(alpha))[0]


@dataclass(frozen=True)
class ProxAdmmResult:
    """Result of :func:`prox_admm`.

    Attributes
    ----------
    rotation : (3, 3) array
        Object-to-camera rotation; its first two rows are the image axes, the third their cross
        product (a proper rotation).
    scale : float
        Weak-perspective scale (image units per mm).
    weights : (M,) array
        Shape weights.
    translation_2d : (2,) array
        Image translation: ``uv = scale * (R X)[:2] + translation_2d``.
    vertices : (N, 3) array
        The reconstruction in the camera frame, mm: ``instance(w) @ R.T + (translation_2d /
        scale, 0)``, so that ``uv = scale * vertices[:, :2]``; depth is unobservable under weak
        perspective (set so the model origin is at depth 0).
    bases : (M + 1, 2, 3) array
        The relaxed solution ``M_i`` (normalised units, before rounding).
    rank_one_ratio : float
        Second over first singular value of the stacked ``M_i`` (6 x (M+1)): 0 when the relaxed
        solution is one rotation, i.e. consistent with the SSM.
    iterations : int
    converged : bool
    primal_residual, dual_residual : float
        Final ADMM residuals (normalised units).
    """

    rotation: np.ndarray
    scale: float
    weights: np.ndarray
    translation_2d: np.ndarray
    vertices: np.ndarray
    bases: np.ndarray
    rank_one_ratio: float
    iterations: int
    converged: bool
    primal_residual: float
    dual_residual: float


def _admm(WBq, g_val, g_vec, nb, lam_abs, mu, max_iter, tol):
    """ADMM on ``M = Z`` (normalised units); returns ``M``, iterations, converged and the final
    primal and dual residuals."""
    Z = np.zeros((2, 3 * nb))
    Mv = np.zeros_like(Z)
    Y = np.zeros_like(Z)
    rho = float(mu)
    r = s = np.inf
    converged = False
    it = 0
    while it < int(max_iter):
        it += 1
        # M step: block-wise spectral-norm prox at Z - Y / mu
        V = (Z - Y / rho).reshape(2, nb, 3).transpose(1, 0, 2)
        Mv = _spectral_prox_batch(V, lam_abs / rho).transpose(1, 0, 2).reshape(2, 3 * nb)
        # Z step: argmin 1/2 ||W - Z B||^2 + mu/2 ||M - Z + Y/mu||^2
        Z_prev = Z
        Z = ((WBq + (rho * Mv + Y) @ g_vec) / (g_val + rho)) @ g_vec.T
        Y = Y + rho * (Mv - Z)
        r = float(np.linalg.norm(Mv - Z))
        s = float(rho * np.linalg.norm(Z - Z_prev))
        scale_p = max(np.linalg.norm(Mv), np.linalg.norm(Z), 1e-12)
        if r <= tol * scale_p and s <= tol * max(np.linalg.norm(Y), 1e-12):
            converged = True
            break
        # residual balancing (Y is the unscaled dual, so it needs no rescaling)
        if r > 10.0 * s:
            rho *= 2.0
        elif s > 10.0 * r:
            rho /= 2.0
    return Mv, it, converged, r, s


def prox_admm(
    model: ShapeModel,
    vertex_ids: object,
    uv: object,
    *,
    lam: float = DEFAULT_PROX_LAMBDA,
    mu: float = 1.0,
    max_iter: int = 2000,
    tol: float = 1e-7,
) -> ProxAdmmResult:
    """Prox-ADMM (Zhou et al. 2015): weak-perspective shape and rotation from one view.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm); its mean and modes are the bases.
    vertex_ids : (K,) int array
        Model vertex of each image point.
    uv : (K, 2) array
        Weak-perspective (scaled orthographic) image coordinates, any unit.
    lam : float
        Weight of ``sum_i ||M_i||_2`` per observation, normalised units (the program uses
        ``lam * K``).
    mu : float
        Initial ADMM penalty (adapted by residual balancing).
    max_iter : int
        Iteration limit.
    tol : float
        Stop when the primal and dual residuals are below ``tol`` relative to the iterates.

    Returns
    -------
    ProxAdmmResult

    Raises
    ------
    ValueError
        Bad input (the message names the argument).
    """
    if not isinstance(model, ShapeModel):
        raise ValueError(f"model: expected a ShapeModel, got {type(model).__name__}")
    ids = model.check_vertex_ids(vertex_ids)
    K = len(ids)
    W = _as_array("uv", uv, (K, 2))
    if K < 3:
        raise ValueError(f"vertex_ids: at least 3 image points are needed, got {K}")
    for name, v in (("lam", lam), ("mu", mu), ("tol", tol)):
        if not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name}: must be a positive number, got {v!r}")
    if int(max_iter) < 1:
        raise ValueError(f"max_iter: must be >= 1, got {max_iter}")

    # bases (M+1, 3, K) centred over the observed points: centring removes the 2-D translation
    pts = np.concatenate([model.mean[ids][None], model.modes[:, ids]])  # (M+1, K, 3)
    pts_c = pts - pts.mean(axis=1, keepdims=True)
    b_scale = float(np.sqrt(np.mean(np.sum(pts_c[0] ** 2, axis=1))))
    w_centre = W.mean(axis=0)
    Wc = W - w_centre
    w_scale = float(np.sqrt(np.mean(np.sum(Wc**2, axis=1))))
    if b_scale <= 0:
        raise ValueError("vertex_ids: the observed model points coincide")
    if w_scale <= 0:
        raise ValueError("uv: all image points coincide")
    nb = pts.shape[0]
    B = (pts_c / b_scale).transpose(0, 2, 1).reshape(3 * nb, K)  # stacked bases (3(M+1), K)
    Wn = (Wc / w_scale).T  # (2, K)
    lam_abs = lam * K
    G, WB = B @ B.T, Wn @ B.T

    # (G + mu I)^-1 for any mu from one eigendecomposition (mu changes with the balancing)
    g_val, g_vec = np.linalg.eigh(G)
    Mv, it, converged, r, s = _admm(WB @ g_vec, g_val, g_vec, nb, lam_abs, mu, max_iter, tol)
    blocks = Mv.reshape(2, nb, 3).transpose(1, 0, 2)  # (M+1, 2, 3)
    # one rotation for all bases: best rank-one fit of [vec M_0 ... vec M_M], sign from M_0
    A = blocks.reshape(nb, 6).T
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    u = U[:, 0].reshape(2, 3)
    if np.sum(u * blocks[0]) < 0:
        u = -u
    Uu, _, Vt = np.linalg.svd(u, full_matrices=False)
    Rbar = Uu @ Vt
    c = np.einsum("ijk,jk->i", blocks, Rbar) / 2.0  # least-squares c_i given Rbar
    if c[0] <= 0:
        raise ValueError(
            "uv: Prox-ADMM returned a zero mean-shape coefficient (lam too large for this data)"
        )
    weights = c[1:] / c[0]  # all bases share b_scale
    scale = float(c[0] * w_scale / b_scale)
    R = np.vstack([Rbar, np.cross(Rbar[0], Rbar[1])])
    shape = model.instance(weights)
    t2 = w_centre - scale * shape[ids].mean(axis=0) @ Rbar.T
    vertices = shape @ R.T + np.append(t2 / scale, 0.0)
    ratio = float(sv[1] / sv[0]) if len(sv) > 1 and sv[0] > 0 else 0.0
    return ProxAdmmResult(
        rotation=R,
        scale=scale,
        weights=weights,
        translation_2d=t2,
        vertices=vertices,
        bases=blocks,
        rank_one_ratio=ratio,
        iterations=it,
        converged=converged,
        primal_residual=r,
        dual_residual=s,
    )


# -- repeated single-view SfT + combination ------------------------------------------------------
@dataclass(frozen=True)
class RepeatedSingleViewResult:
    """Result of :func:`repeated_single_view` (world frame, mm).

    Attributes
    ----------
    vertices : (N, 3) array
        The combined reconstruction: Euclidean mean of the rigidly aligned per-view
        reconstructions, rigidly placed onto the mean of the unaligned ones.
    view_vertices : (P', N, 3) array
        Each solved view's reconstruction as :func:`solve_gsft` placed it.
    solved : list of int
        Indices of the views that were solved.
    skipped : list of int
        Indices of the views skipped because they have too few observations for a single-view
        solve (only with ``skip_underdetermined=True``).
    results : list of GsftResult
        The per-view solver results, in ``solved`` order.
    """

    vertices: np.ndarray
    view_vertices: np.ndarray
    solved: list[int]
    skipped: list[int]
    results: list[GsftResult]


def combine_reconstructions(shapes: object) -> np.ndarray:
    """Euclidean mean of reconstructions after rigid alignment, placed where they are on average.

    Parameters
    ----------
    shapes : (P, N, 3) array
        Reconstructions of one object, corresponding vertex by vertex, mm.

    Returns
    -------
    (N, 3) array
        The generalised-Procrustes (rigid) mean, rigidly fitted onto the plain mean of
        ``shapes`` (so one shape is returned unchanged).
    """
    x = _as_array("shapes", shapes, (None, None, 3))
    if len(x) == 0:
        raise ValueError("shapes: at least one reconstruction is needed")
    mean = procrustes_align(x).mean(axis=0)
    target = x.mean(axis=0)
    return Pose.fit_rigid(mean, target).apply(mean)


def _min_observations(ids: np.ndarray) -> bool:
    return len(ids) >= 4 and len(np.unique(ids)) >= 3


def _view_rays(i: int, view: object) -> RayObservations:
    """``views[i]`` of :func:`repeated_single_view` as rays."""
    if isinstance(view, RayObservations):
        return view
    if len(view) not in (3, 4):
        raise ValueError(
            f"views[{i}]: expected a RayObservations or (vertex_ids, origins, directions[, "
            f"sigmas]), got {len(view)} items"
        )
    try:
        return RayObservations(view[0], view[1], view[2], view[3] if len(view) == 4 else None)
    except ValueError as exc:
        raise ValueError(f"views[{i}]: {exc}") from None


def repeated_single_view(
    model: ShapeModel,
    views: Sequence[object],
    *,
    skip_underdetermined: bool = False,
    **gsft_options: object,
) -> RepeatedSingleViewResult:
    """The trivial multi-view solution: G-SfT on every view alone, then a rigid mean.

    Parameters
    ----------
    model : ShapeModel
        The shape model (object frame, mm).
    views : sequence of RayObservations or (vertex_ids, origins, directions[, sigmas])
        Per-view rays in the world frame (mm), as for :func:`solve_gsft`.
    skip_underdetermined : bool
        Skip views with fewer than 4 observations or 3 distinct points (a single-view solve
        needs them) instead of raising.
    **gsft_options
        Passed to :func:`solve_gsft` (``eps``, ``prior_weight``, ...).

    Returns
    -------
    RepeatedSingleViewResult

    Raises
    ------
    ValueError
        Bad input; the message names the view (``views[i]``).
    """
    if len(views) == 0:
        raise ValueError("views: at least one view is needed")
    results, solved, skipped = [], [], []
    for i, view in enumerate(views):
        rays = _view_rays(i, view)
        model.check_vertex_ids(rays.vertex_ids, name=f"views[{i}]: vertex_ids")
        if skip_underdetermined and not _min_observations(rays.vertex_ids):
            skipped.append(i)
            continue
        try:
            results.append(solve_gsft(model, rays, **gsft_options))
        except ValueError as exc:
            raise ValueError(f"views[{i}]: {exc}") from None
        solved.append(i)
    if not results:
        raise ValueError(
            f"views: none of the {len(views)} views has the 4 observations of 3 distinct points "
            "a single-view solve needs"
        )
    per_view = np.array([r.vertices for r in results])
    return RepeatedSingleViewResult(
        vertices=combine_reconstructions(per_view),
        view_vertices=per_view,
        solved=solved,
        skipped=skipped,
        results=results,
    )
