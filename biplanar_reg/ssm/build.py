"""Build a :class:`ShapeModel` from shapes in correspondence: Procrustes alignment and PCA.

Modes are stored scaled so that weights are in standard deviations:
``modes[i] = sqrt(variances[i]) * unit_eigenvector_i`` with ``variances`` the sample variances
(divisor S - 1), mm^2. The model frame is the frame of the first input shape (the aligned mean is
rigidly fitted back onto it), so landmarks picked on the template keep their meaning.

Diagnostic :func:`affine_fractions`: the fraction of each mode's squared displacement explained by
the best affine map of the mean (``A @ x + b``). A mode near 1 is a pure scaling/shear of the
mean; such modes are partly interchangeable with the rotation, and the convex (SDP) relaxation of
the G-SfT solver then tends to lose tightness (measured: lambda2/lambda1 0.04-0.18 with an
affine basis, see docs/ssm.md). A solver seeing fractions above ~0.9 should not trust the rounded
relaxation alone: round, then refine locally (or re-parameterise the model).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .._validate import as_array
from ..pose import Pose, SimilarityFit
from .model import ShapeModel

__all__ = ["procrustes_align", "build_ssm", "explained_fractions", "affine_fractions"]

ALIGNMENTS = ("rigid", "similarity", "none")


def _fit(source: np.ndarray, target: np.ndarray, scaling: bool) -> SimilarityFit:
    """Least-squares ``source -> target`` fit: a similarity, or rigid (scale 1)."""
    if scaling:
        return Pose.fit_similarity(source, target)
    return SimilarityFit(1.0, Pose.fit_rigid(source, target))


def procrustes_align(
    shapes: object, scaling: bool = False, max_iter: int = 100, tol: float = 1e-10
) -> np.ndarray:
    """Generalised Procrustes alignment of shapes in correspondence.

    Parameters
    ----------
    shapes : (S, N, 3) array
        Shapes, mm.
    scaling : bool
        Also remove size (similarity alignment); the mean keeps the first shape's size.
    max_iter, tol : int, float
        Stop when the mean moves less than ``tol`` times its size (RMS), or after ``max_iter``.

    Returns
    -------
    (S, N, 3) array
        Aligned shapes, in the frame of the first shape (the mean is fitted back onto it).
    """
    x = as_array("shapes", shapes, (None, None, 3))
    mean = x[0].copy()
    aligned = x.copy()
    for _ in range(int(max_iter)):
        for i in range(len(x)):
            aligned[i] = _fit(x[i], mean, scaling).apply(x[i])
        new_mean = aligned.mean(axis=0)
        if scaling:  # keep the reference size fixed, otherwise the mean shrinks
            new_mean = Pose.fit_similarity(new_mean, x[0]).apply(new_mean)
        size = np.sqrt(np.mean(np.sum((new_mean - new_mean.mean(0)) ** 2, axis=1)))
        change = np.sqrt(np.mean(np.sum((new_mean - mean) ** 2, axis=1)))
        mean = new_mean
        if change <= tol * max(size, 1e-300):
            break
    # Express everything in the first shape's frame (rigid only: sizes stay as aligned).
    return Pose.fit_rigid(aligned.mean(axis=0), x[0]).apply(aligned)


def build_ssm(
    shapes: object,
    faces: object | None = None,
    n_modes: int | None = None,
    variance: float | None = 0.98,
    align: str = "rigid",
    landmarks: Mapping[str, int] | None = None,
) -> ShapeModel:
    """PCA shape model from shapes in correspondence.

    Parameters
    ----------
    shapes : (S, N, 3) array
        S >= 2 shapes, mm, vertex i of every shape corresponding.
    faces : (F, 3) int array, optional
        Shared triangles (a surface model) or ``None`` (a point model).
    n_modes : int, optional
        Keep exactly this many modes (1 .. rank). Overrides ``variance``.
    variance : float, optional
        Keep the fewest modes whose cumulative explained variance reaches this fraction
        (0, 1]. Used when ``n_modes`` is ``None``.
    align : {"rigid", "similarity", "none"}
        Generalised Procrustes alignment before PCA.
    landmarks : mapping of str to int, optional
        Landmark name -> vertex index.

    Returns
    -------
    ShapeModel
        ``variances`` holds each kept mode's variance (mm^2); modes are in standard deviations.
    """
    x = as_array("shapes", shapes, (None, None, 3))
    if len(x) < 2:
        raise ValueError(f"shapes: need at least 2 shapes to learn modes, got {len(x)}")
    if x.shape[1] == 0:
        raise ValueError("shapes: the shapes have no vertices")
    if align not in ALIGNMENTS:
        raise ValueError(f"align: expected one of {list(ALIGNMENTS)}, got {align!r}")
    if align != "none":
        x = procrustes_align(x, scaling=(align == "similarity"))
    s_count, n = x.shape[:2]
    data = x.reshape(s_count, 3 * n)
    mean = data.mean(axis=0)
    _, sig, vt = np.linalg.svd(data - mean, full_matrices=False)
    var = sig**2 / (s_count - 1)
    rank = int(np.sum(var > 1e-12 * max(var.max(initial=0.0), 1e-300)))
    if rank == 0:
        raise ValueError("shapes: all shapes are identical (after alignment); no modes to learn")
    if n_modes is not None:
        k = int(n_modes)
        if not 1 <= k <= rank:
            raise ValueError(f"n_modes: must be in 1..{rank} (the data's rank), got {n_modes}")
    else:
        frac = 0.98 if variance is None else float(variance)
        if not 0.0 < frac <= 1.0:
            raise ValueError(f"variance: must be in (0, 1], got {variance}")
        cumulative = np.cumsum(var[:rank]) / var[:rank].sum()
        k = int(min(rank, np.searchsorted(cumulative, frac - 1e-12) + 1))
    vecs = vt[:k]
    # Deterministic signs: the largest-magnitude entry of each eigenvector is positive.
    signs = np.sign(vecs[np.arange(k), np.argmax(np.abs(vecs), axis=1)])
    vecs = vecs * signs[:, None]
    modes = (np.sqrt(var[:k])[:, None] * vecs).reshape(k, n, 3)
    return ShapeModel(
        mean.reshape(n, 3),
        modes,
        faces=faces,
        variances=var[:k],
        landmarks=landmarks,
        truncation_modes=leave_one_out_residuals(data, k),
        population_variances=var[:rank],
    )


#: Most leave-one-out folds :func:`leave_one_out_residual` runs (evenly spread over the shapes).
MAX_FOLDS = 30


def leave_one_out_residuals(data: np.ndarray, n_modes: int) -> np.ndarray | None:
    """Truncation modes (F, N, 3) of a PCA model, mm: for each of at most :data:`MAX_FOLDS`
    shapes, the PCA of the others with ``n_modes`` modes (at most their rank) and the
    left-out shape's residual from its projection, divided by ``sqrt(F)`` (so that the sum of
    the squares at a vertex is the mean square leave-one-out error there).

    ``data`` (S, 3N): aligned shapes, one per row. None for fewer than 3 shapes.
    """
    s_count = len(data)
    if s_count < 3:
        return None
    folds = np.unique(np.linspace(0, s_count - 1, min(s_count, MAX_FOLDS)).round().astype(int))
    out = []
    for i in folds:
        rest = np.delete(data, i, axis=0)
        mu = rest.mean(axis=0)
        _, sig, vt = np.linalg.svd(rest - mu, full_matrices=False)
        k = min(n_modes, int(np.sum(sig > 1e-9 * max(sig.max(initial=0.0), 1e-300))))
        d = data[i] - mu
        out.append(d - vt[:k].T @ (vt[:k] @ d))
    return np.stack(out).reshape(len(folds), -1, 3) / np.sqrt(len(folds))


def explained_fractions(model: ShapeModel) -> np.ndarray:
    """Each mode's share of the training set's total variance (M,).

    The total is ``sum(model.population_variances)`` (all modes) when the model knows it, so the
    cumulative sum is the true compactness; otherwise (older files, statismo models) the share
    of the kept variance (the cumulative sum then reaches 1 at the last kept mode).
    """
    var = model.variances if model.variances is not None else np.sum(model.modes**2, axis=(1, 2))
    total = var.sum()
    if model.population_variances is not None and model.population_variances.sum() > 0:
        total = float(model.population_variances.sum())
    return var / total if total > 0 else np.zeros_like(var)


def affine_fractions(model: ShapeModel) -> np.ndarray:
    """Fraction of each mode's squared norm explained by an affine map of the mean (M,).

    For mode ``m`` (N, 3), the fraction is ``||P m||^2 / ||m||^2`` where ``P`` projects onto the
    12-dimensional space of displacements ``A @ x + b`` evaluated at the mean's points ``x``.
    1 means the mode is exactly an affine map (scaling, shear, rotation-like or translation) of
    the mean; a generic non-linear shape variation is near 0. See the module docstring for what
    it means for the convex solver.
    """
    homog = np.hstack([model.mean, np.ones((model.n_vertices, 1))])
    u, sig, _ = np.linalg.svd(homog, full_matrices=False)
    q = u[:, sig > 1e-10 * sig[0]]  # a planar or collinear mean spans fewer affine maps
    out = np.zeros(model.n_modes)
    for i, mode in enumerate(model.modes):
        total = float(np.sum(mode * mode))
        out[i] = float(np.sum((q.T @ mode) ** 2) / total) if total > 0 else 0.0
    return out
