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

from ..pose import Pose, nearest_rotation
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
    steps = _Steps(model, pts, shape)
    w = np.zeros(model.n_modes)
    inst = model.mean
    pose = steps.rigid(w[: len(steps.modes)])  # the weights not fitted stay 0
    rms = _rms(pose.apply(inst), pts)
    for _ in range(iterations if steps.modes.size else 0):
        w = steps.weights(pose)
        inst = model.mean + np.tensordot(w, steps.modes, axes=1)
        pose = steps.rigid(w)
        new = _rms(pose.apply(inst), pts)
        done = rms - new < tol_mm
        rms = new
        if done:
            break
    verts = pose.apply(inst)
    return ModelFit(pose.R, pose.t, w, verts, _rms(verts, pts))


class _Steps:
    """The two steps of :func:`fit_model` for fixed points (N, 3), mm, each reduced to a few
    (3, 3) products by sums over the vertices taken once (an iteration then costs one instance
    and its RMS, not passes over the vertices for every sum):

    * :meth:`rigid`: the Kabsch pose of the instance ``mean + w modes`` onto the points. Its
      cross-covariance ``B' (Q - mean(Q))`` (``B`` the points about their centroid) is linear
      in ``w``: ``H0 + sum_m w_m H_m``;
    * :meth:`weights`: the least-squares weights of the points brought into the model frame,
      ``pinv(basis) ((points - t) R - mean)``, linear in ``R`` and ``(centroid - t) R``.
    """

    def __init__(self, model: ShapeModel, pts: np.ndarray, shape: bool) -> None:
        n_modes = model.n_modes if shape else 0
        self.modes = modes = model.modes[:n_modes]
        self.centre = pts.mean(axis=0)
        B = pts - self.centre
        self.mean_c = model.mean.mean(axis=0)
        self.modes_c = np.tensordot(
            modes, np.full(model.n_vertices, 1.0 / model.n_vertices), (1, 0)
        )
        # B' (Q - mean(Q)) = B' Q - sum(B) mean(Q)': sum(B) is 0 up to rounding, kept exact
        total = B.sum(axis=0)
        self.H0 = B.T @ model.mean - np.outer(total, self.mean_c)
        self.Hw = np.tensordot(B, modes, (0, 1)).transpose(1, 0, 2)
        self.Hw -= total[:, None] * self.modes_c[:, None, :]
        if not n_modes:
            return
        # the least-squares solution operator applied, once, to the 13 vectors the weights
        # step is a combination of: B[:, d] in coordinate c (9), 1 in coordinate c (3), mean
        basis = modes.reshape(n_modes, 3 * model.n_vertices).T  # (3N, M)
        solve = np.linalg.pinv(basis)  # (M, 3N)
        per_vertex = solve.reshape(n_modes, model.n_vertices, 3)
        self.K = np.tensordot(per_vertex, B, (1, 0))  # (M, 3, 3)
        self.s = np.tensordot(per_vertex, np.ones(model.n_vertices), (1, 0))  # (M, 3)
        self.w0 = solve @ model.mean.ravel()

    def rigid(self, w: np.ndarray) -> Pose:
        """The Kabsch fit (model -> points' frame, mm) of ``mean + w modes`` to the points (as
        :meth:`biplanar_reg.pose.Pose.fit_rigid`, from the cross-covariance)."""
        rot = nearest_rotation(self.H0 + np.tensordot(w, self.Hw, axes=1))
        return Pose(rot, self.centre - (self.mean_c + w @ self.modes_c) @ rot.T)

    def weights(self, pose: Pose) -> np.ndarray:
        """Least-squares weights of the points in the model frame of ``pose``."""
        rot, t = pose.rt
        return np.einsum("mcd,dc->m", self.K, rot) + self.s @ ((self.centre - t) @ rot) - self.w0


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS distance (mm) between two (N, 3) arrays."""
    d = (a - b).ravel()
    return float(np.sqrt(d @ d / len(a)))
