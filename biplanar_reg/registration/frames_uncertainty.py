"""Posterior uncertainty of a multi-frame registration (:mod:`.frames`), per vertex, mm.

The single-frame estimate (:mod:`.uncertainty`: Laplace approximation at the solution with the
refinement's own Jacobian, per-group residual scales and correlation lengths, the
leave-one-cluster-out jackknife, the shape prior and the model's truncation modes) applied to
the joint objective. Its parameters are every frame's pose and the shared weights
``(pose_0, ..., pose_{F-1}, w)``; frame ``g``'s rows depend on ``pose_g`` and ``w`` only.

For the vertices posed in frame ``f`` the other frames' poses are nuisance parameters: they are
eliminated exactly (in the linearisation) by projecting each other frame's rows, weights
``W_g``, onto the ``W_g``-orthogonal complement of its own pose columns,
``X -> (I - J_p (J_p' W_g J_p)^-1 J_p' W_g) X`` (Jacobian, residuals and truncation columns
alike). The projected rows carry the information of frame ``g`` about ``w`` that is left once its
pose is free: ``J_w' W_g (I - P) J_w`` is the Schur complement of the pose block. Frame ``f``'s
rows with the projected rows of the other frames form one :class:`.uncertainty.Linearisation`
in ``(pose_f, w)``, and :func:`.uncertainty.vertex_sd` gives its per-vertex sd; every frame's
outline is a group of its own (residual scale, correlation, jackknife blocks), all landmarks are
group 0 (one jackknife cluster each). The projection mixes a frame's rows by a rank-6
correction, which the residual-scale and correlation estimates of the group ignore.

"The shape's uncertainty as frames are added" is the same computation over the first ``n``
frames only, at the registration with all ``F`` frames (the linearisation point is not
re-fitted per ``n``: it is the information the first ``n`` frames carry at the final shape).
World frame, mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from .problem import Problem
from .uncertainty import Linearisation, VertexUncertainty, registration_linearisation, vertex_sd

__all__ = ["FrameLinearisation", "frame_linearisations", "frames_vertex_sd", "shape_sd"]

#: Rows a frame needs for its own pose to be determined (6 parameters).
MIN_POSE_ROWS = 6


@dataclass(frozen=True)
class FrameLinearisation:
    """One frame's rows of the joint objective at the solution (stated-noise units).

    Attributes
    ----------
    lin : Linearisation
        Columns ``(rotation step, translation, weights)`` of this frame's pose and the weights.
    weights : (K,) array
        The refinement's row weights (relative to the stated noise).
    state : (R, t, w)
        The frame's pose (model -> world, mm) and the shared weights.
    """

    lin: Linearisation
    weights: np.ndarray
    state: tuple

    @property
    def n_rows(self) -> int:
        return len(self.lin.residuals)


def frame_linearisations(
    problems: Sequence[Problem],
    rotations: np.ndarray,
    translations: np.ndarray,
    weights: np.ndarray,
    outlines: Sequence[dict],
) -> list[FrameLinearisation]:
    """Every frame's :func:`.uncertainty.registration_linearisation` at the joint solution
    (``outlines[f]``: ``{view index: ModelOutline}`` of frame ``f`` at the solution; no landmark
    is rejected in the joint refinement)."""
    out = []
    for f, p in enumerate(problems):
        res = SimpleNamespace(rotation=rotations[f], translation=translations[f], weights=weights)
        if len(p.landmarks) == 0 and not (p.use_outlines and outlines[f]):
            out.append(_no_rows(p.model, (rotations[f], translations[f], weights)))
            continue
        state, lin, est_w = registration_linearisation(p, res, outlines[f], frozenset())
        out.append(FrameLinearisation(lin, est_w, state))
    return out


def _no_rows(model, state) -> FrameLinearisation:
    """The linearisation of a frame without landmarks and outlines (no rows)."""
    T = 0 if model.truncation_modes is None else len(model.truncation_modes)
    z = np.zeros(0)
    lin = Linearisation(np.zeros((0, 6 + model.n_modes)), z, z, np.zeros(0, int), np.zeros((0, T)))
    return FrameLinearisation(lin, z, state)


def _eliminate_pose(fl: FrameLinearisation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame's rows with its pose eliminated: (K, M) weight columns, (K,) residuals and
    (K, T) truncation columns, each projected off the pose columns (module docstring)."""
    lin, W = fl.lin, fl.weights
    Jp, Jw = lin.jacobian[:, :6], lin.jacobian[:, 6:]
    A = Jp.T @ (Jp * W[:, None])
    A_inv = np.linalg.pinv(A)

    def project(X: np.ndarray) -> np.ndarray:
        return X - Jp @ (A_inv @ (Jp.T @ (W[:, None] * X)))

    r = project(lin.residuals[:, None])[:, 0]
    return project(Jw), r, project(lin.truncation_jacobian)


def _joint_linearisation(
    frames: Sequence[FrameLinearisation], target: int
) -> tuple[Linearisation, np.ndarray]:
    """Frame ``target``'s rows and the others' with their poses eliminated, one linearisation
    in ``(pose_target, w)``; each frame's outline groups renumbered to be distinct."""
    jac, res, sig, grp, trunc, est_w = [], [], [], [], [], []
    offset = 0
    for g, fl in enumerate(frames):
        lin = fl.lin
        if g == target:
            J, r, K = lin.jacobian, lin.residuals, lin.truncation_jacobian
        else:
            Jw, r, K = _eliminate_pose(fl)
            J = np.hstack([np.zeros((len(r), 6)), Jw])
        jac.append(J)
        res.append(r)
        trunc.append(K)
        sig.append(lin.sigma_mm)
        grp.append(np.where(lin.group == 0, 0, lin.group + offset))
        offset += int(lin.group.max(initial=0))
        est_w.append(fl.weights)
    lin = Linearisation(
        np.vstack(jac),
        np.concatenate(res),
        np.concatenate(sig),
        np.concatenate(grp),
        np.vstack(trunc),
    )
    return lin, np.concatenate(est_w)


def frames_vertex_sd(
    model,
    frames: Sequence[FrameLinearisation],
    target: int,
    *,
    prior_weight: float,
) -> VertexUncertainty | None:
    """:func:`.uncertainty.vertex_sd` of the shape posed in frame ``target`` (world, mm) from
    the rows of ``frames`` (the other frames' poses eliminated); None when the frame's own rows
    cannot determine its pose (fewer than :data:`MIN_POSE_ROWS`: a frame without landmarks and
    outlines)."""
    if frames[target].n_rows < MIN_POSE_ROWS:
        return None
    lin, est_w = _joint_linearisation(frames, target)
    return vertex_sd(
        model, frames[target].state, lin, prior_weight=prior_weight, estimator_weights=est_w
    )


def shape_sd(model, covariance: np.ndarray) -> np.ndarray:
    """Per-vertex sd (N,) of the shape in the **model frame**, ``Q(w)``, from the weights'
    block of a (6 + M, 6 + M) pose-and-weights covariance: RMS over the three axes, mm. No pose
    and no model truncation: what the data say about the weights alone."""
    M = model.n_modes
    if M == 0:
        return np.zeros(model.n_vertices)
    C = covariance[6:, 6:]
    P = model.modes  # (M, N, 3)
    var = np.einsum("anc,ab,bnc->n", P, C, P)
    return np.sqrt(np.maximum(var, 0.0) / 3.0)
