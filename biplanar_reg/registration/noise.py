"""Each annotation group's noise estimated from the data (variance-component estimation).

A person states a sigma for their clicks, but what a click is worth depends on the landmark,
the radiograph and the person: on real wrist radiographs clicks were 10-30 px off whatever the
stated 1 or 3 px, and a traced outline wanders by several pixels where the stated outline sigma
is 1 px. With sigmas that are too small for one group, that group bends the bone: the result
then depends on a guessed number. So the registration estimates the scale of each group's
errors from the residuals, iterated with the fit (Forstner 1979; Koch 1999, "Parameter
Estimation and Hypothesis Testing in Linear Models", ch. 3.6), for the groups

* the landmarks of each view (their stated sigmas keep their ratios within the group), and
* the outline of each view (its samples, counted as independent every ``contour_spacing_px``).

For a group ``g`` with squared residuals ``S_g`` (pixels squared; a landmark's error divided
by its stated sigma's ratio to the median stated sigma) and redundancy
``r_g = n_g - tr(N^-1 N_g)`` (its effective observation count less the share of the parameters
it determines, from the Gauss-Newton normal matrix ``N`` of the whole objective, shape prior
included), the sigma is ``sigma_g^2 = (S_g + NU0 s0^2) / (r_g + NU0)``: the variance-component
estimate with an inverse-gamma prior of ``NU0`` degrees of freedom centred on a reference
``s0`` (``start_landmark_sigma_px`` for clicks, ``contour_sigma_px`` for outlines), which only
matters where the data say little (a view's two landmarks fitted exactly leave ``r_g`` near
0). The reference is a fixed number, not the stated sigmas, so a click sigma stated as 1 or
3 px gives the same result. An outline's samples are 1 px apart and their errors (tracing
wander, a stretch on the wrong edge, the model's misfit) are correlated along it, so an
outline counts as one independent sample per correlation length (the residuals' integrated
autocorrelation time, at least ``contour_spacing_px``; :func:`.uncertainty.correlation_length`),
and the fit weighs it so. The sigmas and correlation lengths are re-estimated at every
refined fit until they settle. Landmark blunders are handled before the estimate (a rejected
landmark, :mod:`.blunders`, is left out, and so is one whose error stands far out from the
others', :func:`.quality.disagreeing_landmarks`); the outlines' samples beyond their gate carry
no weight either. No sigma is below ``MIN_SIGMA_PX``.

Units: pixels for the reported sigmas; factors are dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .outline_fit import OutlineTerm
from .outline_match import adaptive_gate, outline_distances
from .problem import Problem
from .quality import disagreeing_landmarks
from .uncertainty import correlation_length, linearise_fit

__all__: list[str] = []

#: Prior degrees of freedom of every group's sigma (pseudo-observations at the reference).
NU0 = 2.0
#: Smallest estimated sigma (pixels) of a landmark click or an outline sample.
MIN_SIGMA_PX = 0.5


@dataclass(frozen=True)
class GroupNoise:
    """One group's estimated noise.

    Attributes
    ----------
    kind : str
        ``"landmarks"`` or ``"outline"``.
    view : int
        The view's index.
    sigma_px : float
        The estimated sigma, pixels: per axis of a landmark stated at the median stated
        sigma, or of one outline sample.
    redundancy : float
        Effective observation count less the parameters' share (small, even negative, for a
        view's few landmarks).
    observations : float
        Effective observation count (landmark coordinates of accepted landmarks; outline
        samples within their gate over the correlation length).
    spacing : float
        Outlines: pixels between independent samples (1 for landmarks).
    """

    kind: str
    view: int
    sigma_px: float
    redundancy: float
    observations: float
    spacing: float = 1.0


def group_noise(problem: Problem, result, weights: np.ndarray | None) -> list[GroupNoise]:
    """Every group's sigma at the fit ``result`` (module doc).

    Parameters
    ----------
    problem : Problem
        With the sigmas and outline spacings the fit used (they set the leverages).
    result : GsftResult
        The fit.
    weights : (L,) array or None
        The landmarks' robust weights (a landmark below ``rejection_weight`` is left out).
    """
    opts, lm = problem.options, problem.landmarks
    w = np.ones(len(lm)) if weights is None else np.asarray(weights, float)
    accepted = w >= opts.rejection_weight
    if len(lm):  # a landmark far out from the others' errors would set its group's sigma
        err = problem.landmark_px_errors(result.vertices)
        accepted[disagreeing_landmarks(err, lm.ratios())] = False
    terms, views = _terms(problem, result)
    k_lm = np.sqrt(2.0 * opts.landmark_weight * opts.refine_landmark_weight)
    rays = lm.rays.select(accepted)
    rays = rays.with_sigmas(rays.sigmas / k_lm) if len(rays) else rays
    state = (result.rotation, result.translation, result.weights)
    lin = linearise_fit(problem.model, state, rays, terms, problem.topology)
    if len(lin.residuals) == 0:
        return []
    lm_view = np.repeat(rays.view_index, 2) if len(rays) else np.zeros(0, int)
    outline_groups = [(g, i) for g, i in enumerate(views, start=1) if np.any(lin.group == g)]
    # residuals in pixels: a landmark's over its stated sigma's ratio to the median
    px = lin.residuals.copy()
    if len(rays):  # the refinement's sigma in px over the stated ratio: the group's scale
        scale = lm.sigma_px[accepted] / k_lm / lm.ratios()[accepted]
        px[: len(lm_view)] *= np.repeat(scale, 2)
    spacing = {}
    for g, i in outline_groups:
        px[lin.group == g] *= problem.outline_sigma_px(i)
        spacing[i] = max(opts.contour_spacing_px, correlation_length(px[lin.group == g]))
    h = _leverages(problem, lin, outline_groups, spacing)
    groups = []
    s0 = opts.start_landmark_sigma_px
    for view in np.unique(lm_view):
        rows = np.flatnonzero(lm_view == view)
        n, p = float(len(rows)), float(h[rows].sum())
        sig = _posterior_sigma(float(px[rows] @ px[rows]), n - p, s0)
        groups.append(GroupNoise("landmarks", int(view), sig, n - p, n))
    for g, i in outline_groups:
        rows = lin.group == g
        n, p = float(rows.sum()) / spacing[i], float(h[rows].sum())
        S = float(px[rows] @ px[rows]) / spacing[i]
        sig = _posterior_sigma(S, n - p, opts.contour_sigma_px)
        groups.append(GroupNoise("outline", int(i), sig, n - p, n, spacing[i]))
    return groups


def _posterior_sigma(sum_sq: float, redundancy: float, reference: float) -> float:
    """``sqrt((S + NU0 s0^2) / (r + NU0))`` (``r`` at least 0), at least :data:`MIN_SIGMA_PX`."""
    var = (sum_sq + NU0 * reference**2) / (max(redundancy, 0.0) + NU0)
    return max(float(np.sqrt(var)), MIN_SIGMA_PX)


def _leverages(problem: Problem, lin, outline_groups, spacing: dict) -> np.ndarray:
    """Each row's leverage in the objective the refinement minimises (outline rows weighed
    ``1 / spacing``), shape prior included."""
    row_w = np.ones(len(lin.residuals))
    for g, i in outline_groups:
        row_w[lin.group == g] = 1.0 / spacing[i]
    n_modes = problem.model.n_modes
    prior = np.concatenate([np.zeros(6), np.full(n_modes, problem.options.prior_weight)])
    C = np.linalg.pinv(lin.jacobian.T @ (lin.jacobian * row_w[:, None]) + np.diag(prior))
    return row_w * np.einsum("kp,pq,kq->k", lin.jacobian, C, lin.jacobian)


def _terms(problem: Problem, result) -> tuple[list[OutlineTerm], list[int]]:
    """The outline terms of the final refinement at ``result`` with one 1 px sample's sigma
    (no spacing), and the view index of each."""
    opts = problem.options
    terms, views = [], []
    outlines = problem.outlines(result) if problem.use_outlines else {}
    for i, t in problem.targets.items():
        if i not in outlines:
            continue
        gate = adaptive_gate(outline_distances(outlines[i], t), opts.match_floor_px)
        mmpp = problem.mm_per_px[i]
        view = problem.views[i].view
        terms.append(OutlineTerm(view, t, problem.outline_sigma[i], min(opts.gate_px, gate), mmpp))
        views.append(i)
    return terms, views


def with_noise(problem: Problem, groups: list[GroupNoise]) -> Problem:
    """``problem`` with the groups' estimated sigmas (landmarks: their stated ratios kept)
    and outline spacings."""
    lm = problem.landmarks
    sig_px = lm.sigma_px.copy()
    sig_mm = lm.rays.sigmas.copy() if len(lm) else np.zeros(0)
    outline_sigma, spacing = dict(problem.outline_sigma), dict(problem.outline_spacing)
    for g in groups:
        if g.kind == "landmarks":
            sel = lm.rays.view_index == g.view
            new = g.sigma_px * lm.ratios()[sel]
            sig_mm[sel] *= new / sig_px[sel]
            sig_px[sel] = new
        else:
            outline_sigma[g.view] *= g.sigma_px / problem.outline_sigma_px(g.view)
            spacing[g.view] = g.spacing
    landmarks = replace(lm, rays=lm.rays.with_sigmas(sig_mm), sigma_px=sig_px) if len(lm) else lm
    return replace(
        problem, landmarks=landmarks, outline_sigma=outline_sigma, outline_spacing=spacing
    )


def settled(problem: Problem, groups: list[GroupNoise], tol: float) -> bool:
    """Whether every group's sigma and outline spacing is within ``tol`` (relative) of the
    ones the problem uses."""
    for g in groups:
        if abs(g.sigma_px / used_sigma(problem, g) - 1.0) > tol:
            return False
        if g.kind == "outline" and abs(g.spacing / problem.spacing(g.view) - 1.0) > tol:
            return False
    return True


def used_sigma(problem: Problem, g: GroupNoise) -> float:
    """The sigma (px) ``problem`` uses for group ``g``, on :attr:`GroupNoise.sigma_px`'s scale
    (a view's landmarks all have it times their stated ratio)."""
    if g.kind == "outline":
        return problem.outline_sigma_px(g.view)
    lm = problem.landmarks
    i = int(np.flatnonzero(lm.rays.view_index == g.view)[0])
    return float(lm.sigma_px[i] / lm.ratios()[i])
