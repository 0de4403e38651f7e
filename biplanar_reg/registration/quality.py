"""What a registration's result says about its own quality: the checks behind its flags.

* :func:`outline_coverage`: which parts of the model's outline in a view the annotated outline
  covers at the fit, and whether only one side of the bone was traced (one-sided outline);
* :func:`shape_plausibility`: how far the registered shape lies from the model's mean, in the
  model's own terms (Mahalanobis distance of the weights, and the volume against the volume
  range the model spans);
* :func:`disagreeing_landmarks`: landmarks whose error stands out from the others', relative
  to their estimated noise;
* :func:`view_separation`: the angle between the two views that see the bone from the most
  different directions (nearly parallel views leave its depth poorly fixed);
  :func:`same_viewpoint`: two views that see everything from one point.

Pure functions of arrays and the registration's problem; units are pixels in the images and
mm in the world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibration.views import OrthographicView, PerspectiveView, View
from ..ssm.model import ShapeModel
from ..ssm.surface import signed_volume
from .outline_match import ModelOutline, OutlineTarget, contour_sides

__all__: list[str] = []

#: A model outline point counts as covered by the annotation within this distance (pixels).
COVER_PX = 15.0
#: One-sided: one side of the bone's outline covered at least this much, the other at most
#: ``ONE_SIDED_OTHER``.
ONE_SIDED_TRACED = 0.3
ONE_SIDED_OTHER = 0.1
#: The sides are compared along the middle of the bone's projected length (its ends, where
#: the two sides meet, and a CT crop's cut, which no radiograph shows, are left out): the
#: outline points between these fractions of its extent along the long axis.
MIDDLE = (0.2, 0.8)
#: Shape flag: the weights' squared Mahalanobis distance beyond the chi-square quantile of this
#: probability (M degrees of freedom), or the volume this many of its model sd from the mean.
PLAUSIBLE_PROBABILITY = 0.999
VOLUME_SDS = 4.0


@dataclass(frozen=True)
class Coverage:
    """How the annotated outline covers the model's outline in one view at the fit.

    Attributes
    ----------
    covered : float
        Fraction of the model's outline points within :data:`COVER_PX` of an annotated sample
        facing the same way.
    sides : (float, float)
        The same along the middle of the bone's length, for the side to the left and to the
        right of its projected long axis (image axes).
    one_sided : bool
        One side traced, the other not (:data:`ONE_SIDED_TRACED`, :data:`ONE_SIDED_OTHER`).
    untraced_direction : str
        Where the untraced side lies in the image (``"left"``, ``"right"``, ``"top"``,
        ``"bottom"``), or ``""``.
    """

    covered: float
    sides: tuple[float, float]
    one_sided: bool
    untraced_direction: str = ""


def _covered_points(outline: ModelOutline, target: OutlineTarget) -> np.ndarray:
    """Whether each thinned outline point (``outline.ids``) has an annotated sample within
    :data:`COVER_PX` facing the same way (where the contour's side is known)."""
    p = outline.uv_all[outline.ids]
    foot, dist, seg, _ = target.segments.nearest(p)
    ok = dist <= COVER_PX
    sides = contour_sides(outline, target, COVER_PX)
    if outline.normal is not None and target.seg_contour is not None:
        side = target.orientation_of(sides, target.seg_contour[seg])
        st = target.segments.b[seg] - target.segments.a[seg]
        outward = side[:, None] * np.column_stack([-st[:, 1], st[:, 0]])
        facing = np.einsum("pc,pc->p", outward, outline.normal[outline.ids])
        ok &= (side == 0) | (facing > 0)
    return ok


def outline_coverage(outline: ModelOutline, target: OutlineTarget) -> Coverage:
    """The annotation's coverage of the model outline (points thinned as for matching)."""
    if len(outline.ids) == 0:
        return Coverage(0.0, (0.0, 0.0), False)
    covered = _covered_points(outline, target)
    uv = outline.uv_all[outline.ids]
    # the bone's projected long axis: the principal axis of all its projected vertices
    allp = outline.uv_all
    c = allp.mean(axis=0)
    _, vec = np.linalg.eigh(np.cov((allp - c).T))
    axis, across = vec[:, 1], vec[:, 0]
    a = (uv - c) @ axis
    # the middle of the bone's projected length (not of its outline points, which crowd
    # where the outline is intricate: a bone's head)
    extent = (allp - c) @ axis
    lo, hi = extent.min() + np.array(MIDDLE) * (extent.max() - extent.min())
    middle = (a >= lo) & (a <= hi)
    s = (uv - c) @ across
    frac = []
    for sel in (middle & (s > 0), middle & (s < 0)):
        frac.append(float(covered[sel].mean()) if np.any(sel) else 0.0)
    one = max(frac) >= ONE_SIDED_TRACED and min(frac) <= ONE_SIDED_OTHER
    direction = ""
    if one:
        sign = 1.0 if frac[0] < frac[1] else -1.0
        d = sign * across
        direction = (
            ("right" if d[0] > 0 else "left")
            if abs(d[0]) >= abs(d[1])
            else ("bottom" if d[1] > 0 else "top")
        )
    return Coverage(float(covered.mean()), (frac[0], frac[1]), one, direction)


def _chi2_quantile(p: float, k: int) -> float:
    """The chi-square quantile (Wilson-Hilferty approximation; at p = 0.999 it is 3.0 % above
    ``scipy.stats.chi2.ppf`` for k = 1, 2.3 % for 2, 1.4 % for 4, 0.7 % for 8; SciPy's stats
    module is not imported on the registration's path)."""
    from statistics import NormalDist

    z = NormalDist().inv_cdf(p)
    h = 2.0 / (9.0 * k)
    return float(k * (1.0 - h + z * np.sqrt(h)) ** 3)


@dataclass(frozen=True)
class Plausibility:
    """How unusual the registered shape is for its model.

    Attributes
    ----------
    mahalanobis2 : float
        ``sum w_i^2`` (the weights are in model standard deviations).
    limit2 : float
        Its chi-square quantile at :data:`PLAUSIBLE_PROBABILITY` (M degrees of freedom).
    volume_z : float or None
        The registered volume's distance from the mean shape's, in the model's standard
        deviations of volume (first order: ``sqrt(sum (dV/dw_i)^2)``); None without faces.
    """

    mahalanobis2: float
    limit2: float
    volume_z: float | None

    @property
    def implausible(self) -> bool:
        vol = self.volume_z is not None and abs(self.volume_z) > VOLUME_SDS
        return self.mahalanobis2 > self.limit2 or vol


def _volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume (mm^3), whichever way the faces point."""
    return abs(signed_volume(vertices, faces))


def shape_plausibility(model: ShapeModel, weights: np.ndarray) -> Plausibility:
    """:class:`Plausibility` of ``weights`` (model standard deviations)."""
    w = np.asarray(weights, float)
    m2 = float(w @ w)
    limit = _chi2_quantile(PLAUSIBLE_PROBABILITY, max(model.n_modes, 1))
    if model.faces is None or model.n_modes == 0:
        return Plausibility(m2, limit, None)
    faces = np.asarray(model.faces)
    v0 = _volume(model.mean, faces)
    h = 1e-3
    grad = np.array(
        [(_volume(model.mean + h * model.modes[i], faces) - v0) / h for i in range(model.n_modes)]
    )
    sd = float(np.linalg.norm(grad))
    z = (_volume(model.instance(w), faces) - v0) / sd if sd > 0 else 0.0
    return Plausibility(m2, limit, float(z))


#: A landmark disagrees with the rest when its error exceeds this many robust per-axis sigmas
#: of the landmark errors (a 2-D Gaussian error exceeds 4 sigma with probability 3e-4) and
#: :data:`DISAGREE_MIN_PX`.
DISAGREE_SIGMAS = 4.0
DISAGREE_MIN_PX = 10.0
#: Median of the length of a 2-D standard Gaussian vector (its per-axis sigma from a median).
_RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))


def disagreeing_landmarks(
    errors_px: np.ndarray, ratios: np.ndarray, sigmas: float = DISAGREE_SIGMAS
) -> np.ndarray:
    """Indices of the landmarks whose error stands out: above ``sigmas`` times the landmarks'
    robust per-axis sigma (median error over the Rayleigh median, each landmark's scaled by
    its stated ratio ``ratios``) and above :data:`DISAGREE_MIN_PX`. Clicks that are all 10-30
    px off (as on real radiographs) raise nothing; one far off the others does."""
    e = np.asarray(errors_px, float)
    if len(e) < 3:
        return np.zeros(0, int)
    scaled = e / np.asarray(ratios, float)
    sigma = float(np.median(scaled)) / _RAYLEIGH_MEDIAN
    limit = np.maximum(sigmas * sigma * np.asarray(ratios, float), DISAGREE_MIN_PX)
    return np.flatnonzero(e > limit)


#: Views flag: the two views of the bone furthest apart are under this angle (degrees). Measured
#: (docs/registration.md, "Nearly parallel views"): below it the registrations had long error
#: tails (vertex RMS up to 23-186 mm), failed now and then ("behind the source") and their
#: uncertainty covered fewer of the errors; from 5 degrees up they were like those 30 degrees
#: apart.
NEARLY_PARALLEL_DEG = 5.0
#: Two view origins closer than this (relative to their distance from the world origin, plus
#: 1e-9 mm) are one point; two projection directions closer than this (radians) are one.
_SAME_TOL = 1e-6


def same_viewpoint(a: View, b: View) -> bool:
    """Whether two views see every point from one point: perspective views with the same
    source position (whatever their orientation), orthographic views with the same projection
    direction (either way), and otherwise the same kind with the same calibration."""
    if isinstance(a, PerspectiveView) and isinstance(b, PerspectiveView):
        ca, cb = a.centre, b.centre
        scale = max(1.0, float(np.linalg.norm(ca)), float(np.linalg.norm(cb)))
        return float(np.linalg.norm(ca - cb)) <= _SAME_TOL * scale + 1e-9
    if isinstance(a, OrthographicView) and isinstance(b, OrthographicView):
        return float(np.linalg.norm(np.cross(a.R[2], b.R[2]))) <= _SAME_TOL
    if type(a) is not type(b):
        return False
    return all(_close(getattr(a, k), getattr(b, k)) for k in vars(a) if k != "name")


def _close(x: object, y: object) -> bool:
    """Two calibration values equal within :data:`_SAME_TOL` (``None`` only equals ``None``)."""
    if x is None or y is None:
        return x is y
    return bool(np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=_SAME_TOL, atol=1e-9))


def view_separation(views: list[View], point: np.ndarray) -> tuple[float, int, int]:
    """The two views that see ``point`` (world, mm) from the most different directions:
    ``(angle in degrees, i, j)``, the angle between their rays through the point taken as
    lines (0-90: opposed views are parallel too). ``(nan, -1, -1)`` with fewer than two views
    that see the point (a view it lies behind does not)."""
    dirs, index = [], []
    for k, view in enumerate(views):
        try:
            _, d = view.rays(view.project(np.asarray(point, float).reshape(1, 3)))
        except ValueError:  # behind the source: this view does not see the point
            continue
        dirs.append(d[0])
        index.append(k)
    if len(dirs) < 2:
        return float("nan"), -1, -1
    D = np.array(dirs)
    sin = np.linalg.norm(np.cross(D[:, None, :], D[None, :, :]), axis=-1)
    angle = np.arctan2(sin, np.abs(D @ D.T))  # as lines, exact near 0 and 90 degrees
    i, j = np.unravel_index(int(np.argmax(angle)), angle.shape)
    i, j = sorted((int(i), int(j)))
    if i == j:  # every pair at 0 degrees
        i, j = 0, 1
    return float(np.degrees(angle[i, j])), index[i], index[j]
