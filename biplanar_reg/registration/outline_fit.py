"""Final local refinement on the annotated outlines: each annotated point to the model's outline.

The convex boosting iterations (:mod:`.outline_match`) pair model outline points with the
annotated outline and re-solve with those pairs fixed; the pairs only change between solves,
so the fit creeps towards the outline and stalls where the discrete outline vertex set
flips back and forth. This refinement instead minimises the registration's objective itself,
re-matching at every evaluation::

    F(R, t, w) = 1/2 sum_l |offset_l|^2 / s_l^2                      (accepted landmarks)
               + 1/2 sum_c min(|n_c . (P_c - o_c)|, g_c)^2 / s_c^2   (annotated outline points)
               + 1/2 lambda |w|^2                                     (shape prior)

``P_c`` is the point of the model's projected outline nearest to annotated point ``c`` (a
point on an outline edge, interpolated between its two vertices), ``o_c`` the origin of
``c``'s ray and ``n_c`` the normal of the plane through that ray and the outline's tangent, so
the term is ``c``'s distance across the model outline (the model may slide along it). The
outline is sampled at 1 px; ``s_c`` is the outline sigma times ``sqrt(spacing)``, so an outline
weighs as independent samples every ``spacing`` px, whatever its sampling. ``g_c`` is a fixed
truncation (robust: an annotated stretch far from the model has no pull). Matching from the
annotation to the model, not the other way round, uses only what was annotated, so open and
partial outlines need no end handling.

Levenberg-Marquardt (:func:`.refine.levenberg_marquardt`) keeps a step only when it lowers
``F`` evaluated with fresh matches, so the refinement never ends worse than its start.
Units: mm for offsets and sigmas (the landmarks' sigmas are the caller's), pixels for the
matching; world frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..calibration.views import View
from ..ssm.model import ShapeModel
from .outline_match import OutlineTarget, Segments, model_outline
from .rays import RayObservations
from .refine import (
    PoseShape,
    levenberg_marquardt,
    pose_shape_jacobian,
    retract_pose_shape,
    tangent_bases,
)

__all__: list[str] = []

#: Rejected trial steps in a row after which the refinement stops: the matches switch between
#: discrete outline edges, so the last digits of the objective cannot be won anyway.
MAX_REJECTED = 6


@dataclass(frozen=True)
class OutlineTerm:
    """The annotated outline of one view as refinement terms.

    Attributes
    ----------
    view : View
    target : OutlineTarget
        The prepared annotation (its usable 1 px samples are the terms).
    sigma_mm : float
        Standard deviation of one sample's offset across the outline, mm (already scaled for
        the sample spacing).
    gate_px : float
        Truncation of each term, pixels.
    mm_per_px : float
        Pixel size at the bone, to turn ``gate_px`` into mm.
    """

    view: View
    target: OutlineTarget
    sigma_mm: float
    gate_px: float
    mm_per_px: float


@dataclass(frozen=True)
class OutlineFitResult:
    """Output of :func:`refine_on_outlines` (world frame, mm)."""

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool
    n_active: int  # outline samples within their gate at the end


@dataclass(frozen=True)
class _Linearised:
    """Residual terms of one evaluation and what their Jacobian needs (``refine.py``)."""

    residuals: np.ndarray  # (T, 2), scaled by 1 / sigma
    points: np.ndarray  # (T, 3) model points Q of the terms, object frame, mm
    modes: np.ndarray  # (M, T, 3) their mode displacements
    bases: np.ndarray  # (T, 3, 2) directions in which each term is measured
    inv_sigma: np.ndarray  # (T,) 1 / sigma, 0 for a capped term (no gradient)
    n_active: int  # outline terms within their gate


def _outline_terms(
    model: ShapeModel,
    term: OutlineTerm,
    samples: tuple[np.ndarray, np.ndarray, np.ndarray],
    V: np.ndarray,
    Qall: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    he: object,
) -> _Linearised:
    """The terms of one view's annotated outline samples against the model outline at ``V``."""
    q, o, d = samples
    M = model.n_modes
    outl = model_outline(V, model, term.view, 3, he)
    e = outl.edges
    if len(e) == 0:  # the model left the view: every term at its cap
        res = np.column_stack([np.full(len(q), term.gate_px), np.zeros(len(q))])
        res *= term.mm_per_px / term.sigma_mm
        zeros = np.zeros((len(q), 3))
        return _Linearised(
            res, zeros, np.zeros((M, len(q), 3)), np.zeros((len(q), 3, 2)), np.zeros(len(q)), 0
        )
    uv = outl.uv_all
    segs = Segments.build(uv[e[:, 0]], uv[e[:, 1]])
    _, _, s, u = segs.nearest(q)
    i, j = e[s, 0], e[s, 1]
    Qc = (1.0 - u)[:, None] * Qall[i] + u[:, None] * Qall[j]
    Pc = (1.0 - u)[None, :, None] * model.modes[:, i] + u[None, :, None] * model.modes[:, j]
    Vc = Qc @ R.T + t
    # the plane through each sample's ray and the outline's tangent there
    tan = uv[j] - uv[i]
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    o2, d2 = term.view.rays(q + tan)
    depth = np.einsum("ki,ki->k", d, Vc - o)[:, None]
    n = np.cross(d, (o2 + depth * d2) - (o + depth * d))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    off = np.einsum("ki,ki->k", n, Vc - o)
    cap = term.gate_px * term.mm_per_px
    active = np.abs(off) <= cap
    res = np.column_stack([np.clip(off, -cap, cap), np.zeros(len(q))]) / term.sigma_mm
    basis = np.zeros((len(q), 3, 2))
    basis[:, :, 0] = n
    inv = np.where(active, 1.0 / term.sigma_mm, 0.0)  # capped terms: no gradient
    return _Linearised(res, Qc, Pc, basis, inv, int(active.sum()))


def refine_on_outlines(
    model: ShapeModel,
    start: PoseShape,
    landmarks: RayObservations,
    outlines: list[OutlineTerm],
    *,
    prior_weight: float = 1.0,
    max_iter: int = 30,
    tol: float = 1e-6,
    he: object | None = None,
    callback: Callable[[tuple, float, int], None] | None = None,
) -> OutlineFitResult:
    """Minimise ``F`` of the module docstring from ``start = (R, t, w)``.

    Parameters
    ----------
    model : ShapeModel
    start : (R, t, w)
        Object-to-world rotation, translation (mm) and weights to start from.
    landmarks : RayObservations
        The landmark rays (world, mm) with their offset sigmas (mm, required;
        ``RayObservations.empty()`` for none).
    outlines : list of OutlineTerm
    prior_weight : float
        ``lambda`` of the prior.
    max_iter, tol
        Levenberg-Marquardt iterations and relative-decrease tolerance.
    he : HalfEdges, optional
        The mesh topology, computed once by the caller.
    callback : callable, optional
        ``callback((R, t, w), F, n_active)`` after every accepted step.
    """
    if landmarks.sigmas is None:
        raise ValueError("landmarks: sigmas (mm) are needed")
    ids, org = landmarks.vertex_ids, landmarks.origins
    lm_bases = tangent_bases(landmarks.directions) if len(ids) else np.zeros((0, 3, 2))
    lm_inv = 1.0 / landmarks.sigmas
    sqrt_lam = float(np.sqrt(prior_weight))
    M = model.n_modes
    # the annotated samples and their rays are fixed: compute once
    samples = []
    for term in outlines:
        q = term.target.points[term.target.usable]
        samples.append((q, *term.view.rays(q)))

    def residuals(state):
        R, t, w = state
        Qall = model.instance(w)
        V = Qall @ R.T + t
        lm = np.einsum("kia,ki->ka", lm_bases, V[ids] - org) * lm_inv[:, None]
        parts = [_Linearised(lm, Qall[ids], model.modes[:, ids], lm_bases, lm_inv, 0)]
        for term, smp in zip(outlines, samples, strict=True):
            if len(smp[0]):
                parts.append(_outline_terms(model, term, smp, V, Qall, R, t, he))
        rvec = np.concatenate([np.concatenate([p.residuals.ravel() for p in parts]), sqrt_lam * w])
        aux = (
            np.vstack([p.points for p in parts]),
            np.concatenate([p.modes for p in parts], axis=1),
            np.concatenate([p.bases for p in parts]),
            np.concatenate([p.inv_sigma for p in parts]),
        )
        return rvec, (aux, sum(p.n_active for p in parts))

    def jacobian(state, aux):
        (Q, P, B, inv), _ = aux
        return pose_shape_jacobian(state[0], Q, P, B, inv, sqrt_lam, M)

    R0, t0, w0 = (np.asarray(a, dtype=float).copy() for a in start)
    (R, t, w), cost0, cost, iterations, converged = levenberg_marquardt(
        (R0, t0, w0),
        residuals,
        jacobian,
        retract_pose_shape,
        max_iter=max_iter,
        tol=tol,
        max_rejected=MAX_REJECTED,
        callback=None if callback is None else lambda s, c, aux: callback(s, c, aux[1]),
    )
    _, (_, n_active) = residuals((R, t, w))
    return OutlineFitResult(
        rotation=R,
        translation=t,
        weights=w,
        vertices=model.instance(w) @ R.T + t,
        cost_before=cost0,
        cost_after=cost,
        iterations=iterations,
        converged=converged,
        n_active=n_active,
    )
