"""Posterior uncertainty of a registration, per vertex, in mm (Laplace approximation).

At the solution ``theta = (rotation step, translation, weights)`` of the final refinement
(:mod:`.outline_fit`; landmarks only: :mod:`.refine`) the registration objective is linearised:
``J`` is the refinement's own analytic Gauss-Newton Jacobian (:func:`.refine.pose_shape_jacobian`
with the outline matches held fixed; a capped outline term has no gradient and carries no
information). Each row is scaled by its *stated* noise (a landmark's pixel sigma in mm at the
bone; an outline sample's ``contour_sigma_px`` in mm), and the data then say how far to trust
that statement, per group of rows (the landmarks; each view's outline):

* **residual scale** ``v_g``: ``(nu0 + sum r^2) / (nu0 + sum (1 - h))`` with ``h`` the rows'
  leverages (a fitted residual is smaller than its error by ``1 - h``) and ``nu0 =``
  :data:`PRIOR_DOF` pseudo-rows at the stated scale (``v = 1``), so that six landmarks cannot
  talk the scale down to nothing. ``v > 1`` means the sigmas were too small *or* the model
  cannot follow the data (truncation, below);
* **correlation** ``kappa_g``: an outline is sampled at 1 px, and its errors (tracing wander,
  model misfit) are correlated along it; ``kappa`` is the integrated autocorrelation time of the
  residuals along the outline, in samples (``1 + 2 sum rho_k`` up to the first non-positive
  ``rho_k``), so the outline counts as ``n / kappa`` independent samples. Landmarks: 1.

The error covariance of the pose and weights is that of the estimator the refinement is, with its
row weights ``W_e`` (landmarks ``2 lambda_lm``, outline samples ``2 (1 - lambda_lm) /
contour_spacing_px``, relative to the stated noise) and ``C_e = (J' W_e J + lambda diag(0,
I))^-1``. Its data share is measured from the residuals themselves by a leave-one-cluster-out
jackknife (the cluster-robust sandwich "CR3"): the clusters are the landmarks (one each) and
contiguous blocks of ``max(10, 4 kappa_g)`` outline samples, and each contributes ``d d'`` with
``d = C_e J_b' W_b (I - H_bb)^-1 r_b`` (the change of the estimate when the cluster is left out,
one Gauss-Newton step). So a wrongly stated sigma, correlated tracing errors and a traced
stretch that followed the wrong edge count as much as the residuals show, not as the sigmas
say. The shape prior adds ``C_e lambda diag(0, I) C_e`` (true weights drawn from
``N(0, I / lambda)``). Without ``W_e`` (:func:`vertex_sd` alone) the efficient
``(J' Sigma^-1 J + lambda diag(0, I))^-1`` with ``Sigma = diag(v_g kappa_g)`` is used. Each
vertex's 3x3 covariance is ``A_v C A_v'`` with ``A_v = dV_v / dtheta = [-[R Q_v]_x, I, R P_v]``.

**Model truncation.** A model whose span does not contain the bone leaves an error no choice of
``theta`` removes. :func:`biplanar_reg.ssm.build_ssm` stores it as ``truncation_modes`` (the
leave-one-out residuals of its population, ``T``). A left-out shape's residual lies in the
training data's span, much of which the full model spans, so that a fit would absorb it through
its weights: :func:`out_of_span_truncation` keeps its component orthogonal to the model's modes
(a new shape's residual is orthogonal to them) and rescales it by one factor to the
leave-one-out mean square. The bone is ``model(theta) + T z`` with ``z ~ N(0, I)``, which the
fit ignored. Its error is then ``G (noise + K z)`` in the parameters
(gain ``G = C_e J' W_e``, ``K = d rows / d z``) and ``A_v G K z - T_v z`` at vertex ``v``, which
adds ``(A_v G K - T_v)(A_v G K - T_v)'``: the model's own error there and what it did to the fitted
pose and weights. Any residual variance beyond the stated noise (``v_g > 1``) is added too, as
``tau^2 = max(0, v_g - 1) * mean(stated sigma^2)`` (mm^2, pooled over the groups by their row
counts, counted once along the surface normal). A model without truncation modes gets the
pose and weight part and ``tau`` only: a lower bound.

**Degrees of freedom.** Both shares are estimated: the data's from the jackknife clusters,
the truncation's from ``F`` folds. Per vertex, :attr:`VertexUncertainty.dof` is their
Satterthwaite combination (the data's from each cluster's expected share under the working
model, Bell-McCaffrey / Imbens-Kolesar; the truncation's ``F``); :func:`student_factor` turns
``2 sd_mm`` into the Student-t interval of the same 95.4 % level.

**The number.** ``sd_mm = sqrt((trace(Cov_v) + tau^2) / 3)``: the root mean square over the
three axes of the vertex's position standard deviation, mm. The matching error statistic is
the RMS over axes of the vertex's error vector, ``|e_v| / sqrt(3)``; "within 2 sd" means
``|e_v| <= 2 sqrt(3) sd_mm``. For a Gaussian error that event has probability 95.4 % (all
variance along one direction) to 99.3 % (isotropic). The view poses are taken as known:
their uncertainty (``poses = "refine"``/``"unknown"``) is not included.

Frames and units: world frame, mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..ssm.model import ShapeModel
from .outline_fit import OutlineTerm, _Linearised, _outline_terms
from .outline_match import adaptive_gate, outline_distances
from .rays import RayObservations
from .refine import PoseShape, pose_shape_jacobian, tangent_bases
from .rotations import skew

__all__ = [
    "Linearisation",
    "VertexUncertainty",
    "linearise_fit",
    "out_of_span_truncation",
    "student_factor",
    "vertex_sd",
]

#: Pseudo-rows of evidence that the stated sigmas are right (the prior of the residual scale).
PRIOR_DOF = 4.0
#: Largest lag (samples) of the outline residuals' autocorrelation.
MAX_LAG = 400
#: Smallest jackknife block of outline samples.
BLOCK_MIN = 10
#: Jackknife block length in correlation lengths: blocks must be long against the residuals'
#: correlation to be nearly independent (measured on benchmarks/uncertainty.py: 2-sd coverage
#: 71 % with 2, 79 % with 4).
BLOCK_KAPPAS = 4.0
#: Fixed-point passes of leverage -> scale -> weights (the leverages depend on the weights).
SCALE_PASSES = 3


@dataclass(frozen=True)
class Linearisation:
    """The registration objective linearised at a solution (rows scaled by the stated noise).

    Attributes
    ----------
    jacobian : (K, 6 + M) array
        d(scaled residual) / d(rotation step, translation, weights); 1/mm * mm = 1 per unit.
    residuals : (K,) array
        Residuals divided by the stated noise (dimensionless).
    sigma_mm : (K,) array
        The stated noise of each row, mm.
    group : (K,) int array
        0: landmarks; ``1 + i``: the outline of the ``i``-th outline term (view).
    truncation_jacobian : (K, F) array
        d(scaled residual) / d(truncation weights ``z``) (:attr:`ShapeModel.truncation_modes`;
        F = 0 when the model has none).
    """

    jacobian: np.ndarray
    residuals: np.ndarray
    sigma_mm: np.ndarray
    group: np.ndarray
    truncation_jacobian: np.ndarray


@dataclass(frozen=True)
class VertexUncertainty:
    """Output of :func:`vertex_sd` (world frame, mm).

    Attributes
    ----------
    sd_mm : (N,) array
        Per-vertex standard deviation, RMS over the three axes, mm (module docstring).
    parameter_sd_mm : (N,) array
        The same without the truncation term (pose and weights only).
    truncation_mm : float
        ``tau``: the model truncation error estimated from the residuals, mm (along the normal).
    covariance : (6 + M, 6 + M) array
        Posterior covariance of (rotation step rad, translation mm, weights).
    scales : dict
        ``{group: {"n", "variance_ratio", "correlation_samples", "truncation_mm"}}``.
    dof : (N,) array
        Satterthwaite degrees of freedom of each vertex's variance estimate (``inf``: known).
    """

    sd_mm: np.ndarray
    parameter_sd_mm: np.ndarray
    truncation_mm: float
    covariance: np.ndarray
    scales: dict
    dof: np.ndarray | None = None


def linearise_fit(
    model: ShapeModel,
    state: PoseShape,
    landmarks: RayObservations,
    outlines: list[OutlineTerm],
    he: object | None = None,
) -> Linearisation:
    """The objective of :func:`.outline_fit.refine_on_outlines` linearised at ``state``.

    Parameters
    ----------
    model : ShapeModel
    state : (R, t, w)
        The solution: object-to-world rotation, translation (mm), weights.
    landmarks : RayObservations
        The accepted landmark rays (world, mm), ``sigmas`` their stated noise (mm).
    outlines : list of OutlineTerm
        Each view's annotated outline, ``sigma_mm`` the stated noise of one 1 px sample (mm).
    he : HalfEdges, optional
        The mesh topology.

    Returns
    -------
    Linearisation
        Landmarks give two rows each, outline samples one (capped samples none).
    """
    if landmarks.sigmas is None:
        raise ValueError("landmarks: sigmas (mm) are needed")
    R, t, w = state
    Qall = model.instance(w)
    V = Qall @ R.T + t
    n_trunc = 0 if model.truncation_modes is None else len(model.truncation_modes)
    if n_trunc:  # the truncation modes as extra columns (their weights are 0 at the solution)
        model = ShapeModel(
            model.mean, np.concatenate([model.modes, model.truncation_modes]), faces=model.faces
        )
    ids = landmarks.vertex_ids
    bases = tangent_bases(landmarks.directions) if len(ids) else np.zeros((0, 3, 2))
    inv = 1.0 / landmarks.sigmas
    lm = np.einsum("kia,ki->ka", bases, V[ids] - landmarks.origins) * inv[:, None]
    parts = []
    if len(ids):  # an outline-only registration has no landmark rows
        parts.append((_Linearised(lm, Qall[ids], model.modes[:, ids], bases, inv, 0), 0, 2))
    for g, term in enumerate(outlines, start=1):
        q = term.target.points[term.target.usable]
        if len(q):
            part = _outline_terms(model, term, (q, *term.view.rays(q)), V, Qall, R, t, he)
            parts.append((part, g, 1))
    jac, res, sig, grp = [], [], [], []
    for part, g, n_comp in parts:
        keep = part.inv_sigma > 0  # capped outline terms carry no information
        J = pose_shape_jacobian(
            R, part.points, part.modes, part.bases, part.inv_sigma, 0.0, model.n_modes
        )[: 2 * len(part.points)].reshape(len(part.points), 2, -1)
        jac.append(J[keep, :n_comp].reshape(-1, J.shape[-1]))
        res.append(part.residuals[keep, :n_comp].ravel())
        s = 1.0 / part.inv_sigma[keep]
        sig.append(np.repeat(s, n_comp))
        grp.append(np.full(n_comp * int(keep.sum()), g))
    J = np.vstack(jac)
    P = J.shape[1] - n_trunc
    return Linearisation(
        J[:, :P], np.concatenate(res), np.concatenate(sig), np.concatenate(grp), J[:, P:]
    )


def correlation_length(r: np.ndarray, max_lag: int = MAX_LAG) -> float:
    """Integrated autocorrelation time (samples, >= 1) of a residual sequence ``r``:
    ``1 + 2 sum_k rho_k`` over the lags before the first non-positive ``rho_k`` (the mean is
    not removed: a constant offset along an outline is a fully correlated error)."""
    r = np.asarray(r, float)
    n = len(r)
    denom = float(r @ r)
    if n < 3 or denom <= 0:
        return 1.0
    L = min(max_lag, n // 4)
    acf = np.array([float(r[:-k] @ r[k:]) for k in range(1, L + 1)]) / denom if L else []
    total = 0.0
    for rho in acf:
        if rho <= 0:
            break
        total += rho
    return max(1.0, 1.0 + 2.0 * total)


def _posterior(J: np.ndarray, row_w: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """``(J' diag(row_w) J + diag(prior))^-1`` (pseudo-inverse if singular)."""
    H = J.T @ (J * row_w[:, None]) + np.diag(prior)
    try:
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(H)


def _group_scales(
    lin: Linearisation, prior: np.ndarray, est_w: np.ndarray | None
) -> tuple[np.ndarray, dict]:
    """Per-row noise variances ``v_g kappa_g`` (stated-noise units) and per-group statistics.

    The leverages are those of the estimator (weights ``est_w``); without them, of the
    efficient estimator (weights ``1 / (v kappa)``, found by :data:`SCALE_PASSES` passes)."""
    J, r, grp = lin.jacobian, lin.residuals, lin.group
    row_var = np.ones(len(r))
    kappa = {g: (1.0 if g == 0 else correlation_length(r[grp == g])) for g in np.unique(grp)}
    stats: dict = {}
    for _ in range(1 if est_w is not None else SCALE_PASSES):
        w = 1.0 / row_var if est_w is None else est_w
        C = _posterior(J, w, prior)
        h = w * np.einsum("kp,pq,kq->k", J, C, J)
        for g, k in kappa.items():
            sel = grp == g
            dof = PRIOR_DOF + float(np.sum(np.clip(1.0 - h[sel], 0.0, 1.0)))
            v = (PRIOR_DOF + float(r[sel] @ r[sel])) / dof
            row_var[sel] = v * k
            tau2 = max(0.0, v - 1.0) * float(np.mean(lin.sigma_mm[sel] ** 2))
            stats[int(g)] = {
                "n": int(sel.sum()),
                "variance_ratio": v,
                "correlation_samples": k,
                "excess_mm": float(np.sqrt(tau2)),
            }
    return row_var, stats


def _parameter_covariance(
    J: np.ndarray, row_var: np.ndarray, prior: np.ndarray, est_w: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Error covariance of the estimate (P, P) and its gain ``G = C_e J' W_e`` (P, K).

    With the estimator's weights ``W_e`` (``C_e = (J' W_e J + prior)^-1``) the sandwich
    ``C_e (J' W_e Sigma W_e J + prior) C_e`` (``Sigma = diag(row_var)``, the prior term for the
    weights drawn from the prior); without, the efficient ``(J' Sigma^-1 J + prior)^-1``."""
    w = 1.0 / row_var if est_w is None else est_w
    C = _posterior(J, w, prior)
    G = C @ (J.T * w)
    if est_w is None:
        return C, G
    return C @ (J.T @ (J * (w * w * row_var)[:, None]) + np.diag(prior)) @ C, G


def _clusters(lin: Linearisation, stats: dict) -> list[np.ndarray]:
    """Row indices of the jackknife clusters: each landmark (its two rows), and each outline
    cut into contiguous blocks of ``max(BLOCK_MIN, BLOCK_KAPPAS kappa)`` samples."""
    out = []
    for g, st in stats.items():
        rows = np.flatnonzero(lin.group == g)
        size = 2 if g == 0 else max(BLOCK_MIN, int(round(BLOCK_KAPPAS * st["correlation_samples"])))
        out += [rows[i : i + size] for i in range(0, len(rows), size)]
    return out


def _jackknife_covariance(
    lin: Linearisation, est_w: np.ndarray, prior: np.ndarray, clusters: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-cluster-out (CR3) covariance of the estimate (P, P): the sum over clusters of
    ``d d'`` with ``d = C_e J_b' W_b (I - H_bb)^-1 r_b`` (the one-step change of the estimate when
    the cluster is left out), plus the prior term ``C_e lambda diag(0, I) C_e``; and the
    prior term alone (P, P)."""
    sw = np.sqrt(est_w)
    J, r = lin.jacobian * sw[:, None], lin.residuals * sw
    C = _posterior(J, np.ones(len(r)), prior)
    V = C @ np.diag(prior) @ C
    prior_part = V.copy()
    for rows in clusters:
        Jb = J[rows]
        I_H = np.eye(len(rows)) - Jb @ C @ Jb.T
        try:
            u = np.linalg.solve(I_H, r[rows])
        except np.linalg.LinAlgError:
            u = np.linalg.lstsq(I_H, r[rows], rcond=None)[0]
        d = C @ (Jb.T @ u)
        V += np.outer(d, d)
    return V, prior_part


def _cluster_dof(
    lin: Linearisation,
    est_w: np.ndarray,
    prior: np.ndarray,
    clusters: list[np.ndarray],
    row_var: np.ndarray,
    grams: np.ndarray,
) -> np.ndarray:
    """Per vertex, the Satterthwaite degrees of freedom (N,) of the jackknife variance, from
    each cluster's expected share under the working model (rows independent between clusters
    with variances ``row_var``; Bell and McCaffrey 2002, Imbens and Kolesar 2016):
    ``nu = (sum_c q_c)^2 / sum_c q_c^2``, ``q_c =
    trace(A_v C_e J_c' W_c Sigma_c W_c J_c C_e A_v')``. A few clusters carrying a vertex's
    variance give a few degrees of freedom.

    ``grams`` (N, P^2) are the vertices' ``A_v' A_v`` (:func:`_vertex_grams`): with the
    clusters' ``E_c = C_e J_c' W_c Sigma_c W_c J_c C_e`` (P, P), ``q_c = sum(grams_v * E_c)``
    for every vertex and cluster is one matrix product (N, P^2) x (P^2, clusters)."""
    sw = np.sqrt(est_w)
    J = lin.jacobian * sw[:, None]
    C = _posterior(J, np.ones(len(J)), prior)
    B = J @ C.T  # row r: C J_r (the change of the estimate per unit residual r)
    E = np.empty((len(clusters), *C.shape))
    for c, rows in enumerate(clusters):
        E[c] = B[rows].T @ (B[rows] * row_var[rows, None])
    q = grams.reshape(len(grams), -1) @ E.reshape(len(clusters), -1).T  # (N, clusters)
    return q.sum(axis=1) ** 2 / np.maximum(np.sum(q * q, axis=1), 1e-300)


def _vertex_grams(A: np.ndarray) -> np.ndarray:
    """``A_v' A_v`` (N, P, P) of each vertex's Jacobian ``A_v`` (3, P) (``A`` (N, 3, P)), so
    that ``trace(A_v X A_v') = sum(grams_v * X)`` for any (P, P) ``X``: every vertex's variance
    under a covariance ``X`` is then one matrix-vector product."""
    return np.matmul(A.transpose(0, 2, 1), A)


def vertex_jacobians(model: ShapeModel, state: PoseShape) -> np.ndarray:
    """``dV_v / dtheta`` (N, 3, 6 + M) of every posed vertex ``V_v = R Q_v(w) + t`` with
    respect to (rotation step, translation, weights), ``R <- exp([dw]_x) R``."""
    R, _, w = state
    RQ = model.instance(w) @ R.T
    N, M = model.n_vertices, model.n_modes
    A = np.zeros((N, 3, 6 + M))
    A[:, :, 0:3] = -skew(RQ)
    A[:, :, 3:6] = np.eye(3)
    if M:
        A[:, :, 6:] = np.einsum("rc,mnc->nrm", R, model.modes)
    return A


def vertex_sd(
    model: ShapeModel,
    state: PoseShape,
    lin: Linearisation,
    *,
    prior_weight: float = 1.0,
    estimator_weights: np.ndarray | None = None,
) -> VertexUncertainty:
    """Per-vertex standard deviation (mm) of a registration from its :class:`Linearisation`.

    Parameters
    ----------
    model : ShapeModel
    state : (R, t, w)
        The solution the linearisation was taken at.
    lin : Linearisation
        From :func:`linearise_fit` (rows scaled by the stated noise).
    prior_weight : float
        ``lambda`` of the shape prior ``1/2 lambda |w|^2``.
    estimator_weights : (K,) array, optional
        The weights the fit gave each row (relative to the stated-noise scaling): the error
        covariance is then the sandwich of that estimator; default: the efficient estimator's.

    Returns
    -------
    VertexUncertainty
        ``sd_mm`` (N,) is ``sqrt((trace of the vertex covariance + tau^2) / 3)``: see the
        module docstring for the estimate and the matching error statistic.
    """
    M = model.n_modes
    prior = np.concatenate([np.zeros(6), np.full(M, float(prior_weight))])
    model, lin = out_of_span_truncation(model, lin)
    row_var, stats = _group_scales(lin, prior, estimator_weights)
    C, G = _parameter_covariance(lin.jacobian, row_var, prior, estimator_weights)
    A = vertex_jacobians(model, state)
    grams = _vertex_grams(A).reshape(model.n_vertices, -1)  # (N, P^2)
    n_vert = model.n_vertices
    var_p, nu_d = np.zeros(n_vert), np.full(n_vert, np.inf)
    if estimator_weights is not None:  # the data's share from the residuals themselves
        clusters = _clusters(lin, stats)
        C, prior_part = _jackknife_covariance(lin, estimator_weights, prior, clusters)
        var_p = grams @ prior_part.ravel()
        nu_d = _cluster_dof(lin, estimator_weights, prior, clusters, row_var, grams)
    var_c = np.maximum(grams @ C.ravel(), 0.0)
    var_d = np.maximum(var_c - var_p, 0.0)
    var_t, nu_t = np.zeros(n_vert), np.inf
    if model.truncation_modes is not None:
        var_t = np.einsum("nii->n", _truncation_covariance(model, state, lin, G, A))
        nu_t = float(len(model.truncation_modes))  # a sample covariance of F folds
    n = np.array([s["n"] for s in stats.values()], float)
    ex2 = np.array([s["excess_mm"] ** 2 for s in stats.values()])
    excess2 = float(n @ ex2 / n.sum()) if n.sum() else 0.0
    var = var_c + var_t + excess2
    denom = var_d**2 / nu_d + var_t**2 / nu_t
    with np.errstate(divide="ignore"):  # nothing estimated: infinitely many dof
        dof = np.where(denom > 0, var**2 / np.where(denom > 0, denom, 1.0), np.inf)
    own = 0.0 if model.truncation_modes is None else float(np.mean(model.truncation_sd**2))
    return VertexUncertainty(
        sd_mm=np.sqrt(var / 3.0),
        parameter_sd_mm=np.sqrt(var_c / 3.0),
        truncation_mm=float(np.sqrt(own + excess2)),
        covariance=C,
        scales=stats,
        dof=dof,
    )


def student_factor(dof: np.ndarray) -> np.ndarray:
    """``t_nu(q) / z(q)`` at ``q = Phi(2)`` (97.7 %): ``2 student_factor(dof) sd_mm`` is the
    two-sided 95.4 % interval of a Student-t with ``nu = dof`` degrees of freedom, the
    predictive distribution of an error whose variance was estimated with ``nu`` degrees of
    freedom (:attr:`VertexUncertainty.dof`); 1 for ``nu = inf``. ``sd_mm`` itself is the
    standard deviation estimate, without this factor."""
    from scipy.special import stdtrit  # Student-t quantile; scipy.stats costs seconds to import

    q = 0.5 * (1.0 + math.erf(2.0 / math.sqrt(2.0)))  # Phi(2)
    nu = np.asarray(dof, float)
    out = np.ones_like(nu)
    finite = np.isfinite(nu)
    out[finite] = stdtrit(np.maximum(nu[finite], 1.0), q) / 2.0
    return out


def out_of_span_truncation(
    model: ShapeModel, lin: Linearisation
) -> tuple[ShapeModel, Linearisation]:
    """The truncation modes with their component in the model's span removed, rescaled to keep
    their total mean square (and the linearisation's truncation columns likewise).

    The leave-one-out residual of a training shape (:func:`biplanar_reg.ssm.build.
    leave_one_out_residuals`) has the size of a new shape's out-of-span error but lies in the
    training data's span, most of which the full model spans (on the realistic benchmark's
    model: 62 % of its energy): a fit absorbs that part exactly through its weights, so left as
    is it under-states the error the model cannot represent. A new shape's residual is
    orthogonal to the model's modes; the projection keeps the part of the leave-one-out
    residuals with that property and the one global factor restores the leave-one-out size
    (the cross-validated estimate of the mean square truncation error). Without truncation
    modes, or with none outside the span, the inputs are returned unchanged.
    """
    T = model.truncation_modes
    if T is None or model.n_modes == 0:
        return model, lin
    F = len(T)
    Mm = model.modes.reshape(model.n_modes, -1).T  # (3N, M)
    coef = np.linalg.lstsq(Mm, T.reshape(F, -1).T, rcond=None)[0]  # (M, F)
    Tp = T.reshape(F, -1).T - Mm @ coef
    norm_p = float(np.linalg.norm(Tp))
    if norm_p <= 1e-9 * max(float(np.linalg.norm(T)), 1e-300):
        return model, lin
    c = float(np.linalg.norm(T)) / norm_p
    # the rows are linear in the displacement: K(T) = K(T_perp) + J_w coef
    K = c * (lin.truncation_jacobian - lin.jacobian[:, 6:] @ coef)
    trunc = c * Tp.T.reshape(F, model.n_vertices, 3)
    out = ShapeModel(
        model.mean,
        model.modes,
        faces=model.faces,
        variances=model.variances,
        truncation_modes=trunc,
    )
    return out, replace(lin, truncation_jacobian=K)


def _truncation_covariance(model, state, lin, G, A) -> np.ndarray:
    """The truncation modes' share (N, 3, 3) of each vertex's error covariance, mm^2.

    The fit ignored them (``z = 0``), so with the gain ``G = C_e J' W_e`` its error is
    ``G (noise + K z)``: the vertex error ``A_v G K z - T_v z`` adds
    ``(A_v G K - T_v)(A_v G K - T_v)'`` (``z ~ N(0, I)``; ``K`` the rows' and ``T_v`` the
    vertex's truncation Jacobians), the sandwich of an estimator that ignores ``z``.
    """
    R = state[0]
    GK = G @ lin.truncation_jacobian  # (P, F)
    T = np.einsum("rc,fnc->nrf", R, model.truncation_modes)  # (N, 3, F)
    D = np.einsum("nip,pf->nif", A, GK) - T
    return np.einsum("nif,njf->nij", D, D)


def registration_uncertainty(problem, result, outlines: dict, rejected: frozenset[int]):
    """:func:`vertex_sd` of a registration (:mod:`.register`): the accepted landmarks with
    their stated sigmas, each outlined view's samples with ``contour_sigma_px`` in mm and the
    final refinement's gate (the adaptive gate of the current distances, at most ``gate_px``).

    Returns the :class:`VertexUncertainty`, or None when there is nothing to linearise.
    """
    state, lin, est_w = registration_linearisation(problem, result, outlines, rejected)
    if len(lin.residuals) == 0:
        return None
    return vertex_sd(
        problem.model,
        state,
        lin,
        prior_weight=problem.options.prior_weight,
        estimator_weights=est_w,
    )


def registration_linearisation(problem, result, outlines: dict, rejected: frozenset[int]):
    """``(state, Linearisation, estimator weights)`` of a registration at its solution (the
    inputs of :func:`vertex_sd`; see :func:`registration_uncertainty`)."""
    opts, lm = problem.options, problem.landmarks
    accepted = np.array([i not in rejected for i in range(len(lm))], dtype=bool)
    terms = []
    if problem.use_outlines:
        for i, t in problem.targets.items():
            if i not in outlines:
                continue
            gate = adaptive_gate(outline_distances(outlines[i], t), opts.match_floor_px)
            mmpp = problem.mm_per_px[i]
            sig = opts.contour_sigma_px * mmpp
            terms.append(OutlineTerm(problem.views[i].view, t, sig, min(opts.gate_px, gate), mmpp))
    state = (result.rotation, result.translation, result.weights)
    lin = linearise_fit(problem.model, state, lm.rays.select(accepted), terms, problem.topology)
    # the refinement's weights relative to the stated noise (:func:`.stages.refine_once`)
    lam = opts.landmark_weight
    est_w = np.where(
        lin.group == 0, 2.0 * lam, 2.0 * max(1.0 - lam, 1e-12) / opts.contour_spacing_px
    )
    return state, lin, est_w
