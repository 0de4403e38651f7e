"""Per-view annotated observations, turned into rays for the solvers.

A :class:`ViewObservations` holds what one calibrated X-ray view contributes: named landmarks
(model vertex ids, pixels, uncertainties) and outline contours (pixel polylines). The helpers
here convert them to rays in the world frame and pixel uncertainties to the solvers' sigmas
(mm of offset from the ray at the object).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array
from ..annotation.annotations import Contour
from ..calibration.views import View
from .rays import RayObservations

__all__ = ["ViewObservations", "landmark_rays", "mm_per_pixel"]


@dataclass(frozen=True)
class ViewObservations:
    """Observations in one calibrated view.

    Parameters
    ----------
    name : str
        View name (as in the case file).
    view : View
        The calibrated camera model (world frame, mm).
    landmark_names : list of str
        Names of the annotated landmarks (for reports).
    landmark_ids : (L,) int array
        Model vertex ids of the landmarks.
    landmark_uv : (L, 2) array
        Annotated pixels.
    landmark_sigma_px : (L,) array
        Annotator's uncertainty of each landmark, pixels.
    contours : list of Contour
        Annotated (possibly partial, open) outlines of the bone in this view.
    """

    name: str
    view: View
    landmark_names: list[str] = field(default_factory=list)
    landmark_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    landmark_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    landmark_sigma_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    contours: list[Contour] = field(default_factory=list)

    def __post_init__(self) -> None:
        L = len(self.landmark_names)
        ids = as_array(f"{self.name}: landmark_ids", self.landmark_ids, (L,), dtype=int)
        uv = as_array(f"{self.name}: landmark_uv", np.reshape(self.landmark_uv, (-1, 2)), (L, 2))
        sig = as_array(f"{self.name}: landmark_sigma_px", self.landmark_sigma_px, (L,))
        if np.any(sig <= 0):
            raise ValueError(f"{self.name}: landmark_sigma_px must be positive")
        object.__setattr__(self, "landmark_ids", ids)
        object.__setattr__(self, "landmark_uv", uv)
        object.__setattr__(self, "landmark_sigma_px", sig)
        checked = []
        for i, c in enumerate(self.contours):
            uv = as_array(f"{self.name}: contours[{i}]", c.uv, (None, 2))
            if len(uv) < 3:
                raise ValueError(f"{self.name}: contours[{i}] has {len(uv)} point(s); needs 3")
            if np.all(uv == uv[0]):
                raise ValueError(
                    f"{self.name}: contours[{i}]: all {len(uv)} points are "
                    f"({uv[0, 0]:g}, {uv[0, 1]:g}); a contour needs at least 2 different points"
                )
            checked.append(Contour(uv=uv, closed=bool(c.closed)))
        object.__setattr__(self, "contours", checked)

    def without_landmarks(self, names: list[str]) -> ViewObservations:
        """These observations without the named landmarks (e.g. to compare a fit without a
        suspected blunder); an unknown name is an error."""
        unknown = sorted(set(names) - set(self.landmark_names))
        if unknown:
            raise ValueError(f"{self.name}: no landmark(s) named {unknown}")
        keep = np.array([n not in names for n in self.landmark_names], dtype=bool)
        return ViewObservations(
            name=self.name,
            view=self.view,
            landmark_names=[n for n, k in zip(self.landmark_names, keep, strict=True) if k],
            landmark_ids=self.landmark_ids[keep],
            landmark_uv=self.landmark_uv[keep],
            landmark_sigma_px=self.landmark_sigma_px[keep],
            contours=self.contours,
        )


def mm_per_pixel(view: View, X: np.ndarray) -> np.ndarray:
    """Size of one pixel at the world points ``X`` (K, 3), mm: the distance from ``X`` to the ray
    of the pixel one column away from its projection. Exact for every view kind (perspective,
    orthographic, slot-scanning), so pixel sigmas convert consistently."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    uv = view.project(X)
    o, d = view.rays(uv + np.array([1.0, 0.0]))
    v = X - o
    return np.linalg.norm(v - np.sum(v * d, axis=1, keepdims=True) * d, axis=1)


def landmark_rays(
    views: list[ViewObservations], centre: np.ndarray | None = None
) -> RayObservations:
    """Every view's landmarks as rays (world frame).

    Parameters
    ----------
    views : list of ViewObservations
    centre : (3,) array, optional
        Where the object roughly is (mm); pixel sigmas are converted to mm there. Default: the
        point nearest to all landmark rays.

    Returns
    -------
    RayObservations
        The landmarks of ``views[0]``, then ``views[1]``, ... (in each view's order), with
        sigmas in mm (``mm_per_pixel`` at ``centre`` times the pixel sigmas) and ``view_index``
        the index into ``views``.
    """
    from .gsft import nearest_point_to_rays

    ids, org, dirs, sig_px, vi = [], [], [], [], []
    for i, v in enumerate(views):
        if len(v.landmark_ids) == 0:
            continue
        o, d = v.view.rays(v.landmark_uv)
        ids.append(v.landmark_ids)
        org.append(o)
        dirs.append(d)
        sig_px.append(v.landmark_sigma_px)
        vi.append(np.full(len(o), i))
    if not ids:
        return RayObservations.empty()
    ids, org, dirs = np.concatenate(ids), np.vstack(org), np.vstack(dirs)
    sig_px, vi = np.concatenate(sig_px), np.concatenate(vi)
    if centre is None:
        centre = nearest_point_to_rays(org, dirs)
    scale = np.empty(len(ids))
    for i, v in enumerate(views):
        sel = vi == i
        if np.any(sel):
            scale[sel] = mm_per_pixel(v.view, centre[None, :])[0]
    return RayObservations(ids, org, dirs, sig_px * scale, vi)


def landmark_errors(
    views: list[ViewObservations], vertices: np.ndarray
) -> dict[str, dict[str, float]]:
    """Reprojection error (px) of every landmark of every view for registered ``vertices``."""
    out: dict[str, dict[str, float]] = {}
    for v in views:
        if len(v.landmark_ids) == 0:
            out[v.name] = {}
            continue
        uv = v.view.project(vertices[v.landmark_ids])
        err = np.linalg.norm(uv - v.landmark_uv, axis=1)
        out[v.name] = {n: float(e) for n, e in zip(v.landmark_names, err, strict=True)}
    return out
