"""Per-contour residuals: how far each annotated contour lies from the registered outline.

Each annotated contour is resampled at 1 px and the ends of open contours (the first and last
3 px) are left out, as the registration does (:func:`biplanar_reg.registration.outline_match.
prepare_outline`); each remaining point's distance to the nearest segment of the registered
model's projected outline is its residual (pixels). The solver's per-view
``contour_errors_px`` are these residuals of all the view's contours, in order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..annotation import Contour
from ..registration.outline_match import Segments, prepare_outline

__all__ = ["ContourResidual", "contour_residuals"]

#: Arc length of the "worst stretch" of a contour, pixels.
STRETCH_PX = 20


@dataclass(frozen=True)
class ContourResidual:
    """Residuals of one annotated contour (pixels).

    Attributes
    ----------
    index : int
        Position of the contour in its view's annotations (0-based).
    closed : bool
    length_px : float
        Arc length of the contour.
    distances_px : (P,) array
        Residual of each point of the contour resampled at 1 px (open ends left out).
    mean_px, max_px : float
        Their mean and maximum (NaN when no point is left).
    worst_mean_px : float
        Mean residual of the worst stretch: the ``STRETCH_PX`` (20) consecutive points with the
        largest mean (the whole contour when it is shorter).
    worst_uv : (2,) array
        Pixel position of the worst stretch's middle point.
    """

    index: int
    closed: bool
    length_px: float
    distances_px: np.ndarray
    mean_px: float
    max_px: float
    worst_mean_px: float
    worst_uv: np.ndarray


def _segments(outlines: Sequence[np.ndarray]) -> Segments | None:
    """The segments of the outline polylines (pixels); a polyline whose ends are within
    three times its median step is closed (:func:`biplanar_reg.outline.chain_edges` does not
    repeat the first point of a loop)."""
    a, b = [], []
    for line in outlines:
        line = np.asarray(line, float)
        if len(line) < 2:
            continue
        steps = np.linalg.norm(np.diff(line, axis=0), axis=1)
        if np.linalg.norm(line[-1] - line[0]) <= 3.0 * float(np.median(steps)):
            line = np.vstack([line, line[:1]])
        a.append(line[:-1])
        b.append(line[1:])
    return Segments.build(np.vstack(a), np.vstack(b)) if a else None


def _worst_stretch(d: np.ndarray, closed: bool) -> tuple[float, int]:
    """Largest mean of ``STRETCH_PX`` consecutive residuals (wrapping round a closed contour)
    and the index of that stretch's middle point."""
    n = min(STRETCH_PX, len(d))
    x = np.concatenate([d, d[: n - 1]]) if closed and len(d) > n else d
    c = np.concatenate([[0.0], np.cumsum(x)])
    means = (c[n:] - c[:-n]) / n
    k = int(np.argmax(means))
    return float(means[k]), (k + n // 2) % len(d)


def contour_residuals(
    contours: Sequence[Contour], outlines: Sequence[np.ndarray]
) -> list[ContourResidual]:
    """Residuals of each annotated contour of one view against the registered outline.

    Parameters
    ----------
    contours : sequence of Contour
        The view's annotated contours (pixels).
    outlines : sequence of (Q, 2) arrays
        The registered model's projected outline polylines in that view, pixels.

    Returns
    -------
    list of ContourResidual
        One per contour, in order; empty when there is no outline to measure against.
    """
    segs = _segments(outlines)
    if segs is None:
        return []
    out = []
    for i, c in enumerate(contours):
        target = prepare_outline([c])
        if target is None or len(target.points) < 2:
            continue
        pts = target.points[target.usable]
        d = segs.nearest(pts)[1] if len(pts) else np.zeros(0)
        length = float(target.length[0])
        if len(d) == 0:
            nan = float("nan")
            out.append(ContourResidual(i, c.closed, length, d, nan, nan, nan, target.points[0]))
            continue
        worst, k = _worst_stretch(d, c.closed)
        out.append(
            ContourResidual(
                i, c.closed, length, d, float(d.mean()), float(d.max()), worst, pts[k].copy()
            )
        )
    return out
