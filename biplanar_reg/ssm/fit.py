"""Least-squares fits of a shape model to points in correspondence: the model floor.

:func:`fit_model` finds the rigid pose (and, optionally, the mode weights) that bring the model
closest to given points, vertex ``i`` to point ``i``: the best any registration with this model
could do. It gives the two reference figures of an evaluation against a ground truth:

* the **mean-shape baseline** (``shape=False``): the mean shape, rigidly aligned;
* the **model floor** (``shape=True``): rigid pose and weights, no prior. A truth outside the
  model's span keeps a floor above zero, and a registration's error is best read as a ratio to
  it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .build import _fit_transform
from .model import ShapeModel

__all__ = ["ModelFit", "fit_model"]


@dataclass(frozen=True)
class ModelFit:
    """Result of :func:`fit_model` (mm; ``points ~ instance(weights) @ rotation.T + translation``).

    Attributes
    ----------
    rotation : (3, 3) array
    translation : (3,) array, mm
    weights : (M,) array
        Zeros for ``shape=False``.
    vertices : (N, 3) array
        The fitted, posed model instance in the points' frame, mm.
    rms_mm : float
        Vertex RMS distance between ``vertices`` and the points, mm.
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    vertices: np.ndarray
    rms_mm: float


def fit_model(
    model: ShapeModel,
    points: np.ndarray,
    *,
    shape: bool = True,
    iterations: int = 100,
    tol_mm: float = 1e-9,
) -> ModelFit:
    """Fit ``model`` to ``points`` (N, 3), mm, in vertex correspondence, by least squares.

    Alternates the rigid pose (Kabsch on the current instance) and, with ``shape``, the mode
    weights (linear least squares in the model frame, no prior), from the mean shape's rigid
    fit. Each step lowers the sum of squares, so the RMS decreases monotonically to a local
    minimum (the global one in practice: the rigid start is the mean shape's exact optimum).

    Raises
    ------
    ValueError
        ``points`` is not (N, 3) with the model's N, or not finite.
    """
    pts = np.asarray(points, dtype=float)
    if pts.shape != (model.n_vertices, 3) or not np.all(np.isfinite(pts)):
        raise ValueError(
            f"points: expected a finite ({model.n_vertices}, 3) array in correspondence with "
            f"the model, got shape {pts.shape}"
        )
    basis = model.modes.reshape(model.n_modes, 3 * model.n_vertices).T  # (3N, M)
    # the least-squares solution operator, once (each iteration is then a product, not a fresh
    # SVD of the (3N, M) basis)
    solve = np.linalg.pinv(basis) if shape and model.n_modes else None
    w = np.zeros(model.n_modes)
    inst = model.instance(w)
    _, rot, t = _fit_transform(inst, pts, scaling=False)
    rms = _rms(inst @ rot.T + t, pts)
    for _ in range(iterations if shape and model.n_modes else 0):
        local = (pts - t) @ rot  # the points in the model frame
        w = solve @ (local - model.mean).ravel()
        inst = model.instance(w)
        _, rot, t = _fit_transform(inst, pts, scaling=False)
        new = _rms(inst @ rot.T + t, pts)
        done = rms - new < tol_mm
        rms = new
        if done:
            break
    verts = inst @ rot.T + t
    return ModelFit(rot, t, w, verts, _rms(verts, pts))


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))
