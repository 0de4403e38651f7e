"""What the report draws of one view (:class:`ReportView`), without the plotting libraries.

The case pipeline builds these while the report's libraries may still be loading elsewhere
(:mod:`.worker`): this module imports numpy and the annotation types only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..annotation import ViewAnnotations

if TYPE_CHECKING:
    from ..calibration import View
    from ..registration import ViewObservations

__all__ = ["ReportView"]


@dataclass(frozen=True, eq=False)
class ReportView:
    """What the report draws for one view; every coordinate in the view's pixels ``(u, v)``.

    Attributes
    ----------
    name : str
        The view's name (as in the result document's ``views``).
    image_size : (W, H) or None
        Canvas size when there is no radiograph (``None``: fit the drawn data).
    display : (H, W) float array in [0, 1] or None
        The radiograph as an annotator sees it (``XrayImage.display``); ``None``: blank canvas.
    annotations : ViewAnnotations or None
        The view's annotated contours and landmarks.
    outlines : sequence of (Q, 2) arrays
        The registered model's projected outline, pixels.
    landmarks_px : mapping name -> (2,) array
        The registered model's landmarks projected into the view, pixels.
    view : View or None
        The calibrated view with the pose the registration used (estimated ones for
        ``poses = "refine"``/``"unknown"``); with the surface's faces, the overlay shows the
        registered bone shaded. ``None``: no shading.
    """

    name: str
    image_size: tuple[int, int] | None = None
    display: np.ndarray | None = None
    annotations: ViewAnnotations | None = None
    outlines: Sequence[np.ndarray] = ()
    landmarks_px: Mapping[str, np.ndarray] = field(default_factory=dict)
    view: View | None = None

    @classmethod
    def from_observations(
        cls,
        observations: ViewObservations,
        vertices: np.ndarray,
        *,
        image_size: tuple[int, int] | None = None,
        display: np.ndarray | None = None,
        annotations: ViewAnnotations | None = None,
        outlines: Sequence[np.ndarray] = (),
        view: View | None = None,
    ) -> ReportView:
        """The report view of one registered view: its name from ``observations``, and the
        registered ``vertices`` (N, 3, world frame, mm) of its landmarks projected by ``view``
        (default: the observations' view; ``landmarks_px``, pixels), which is kept for the
        shaded bone; the other fields as given."""
        o = observations
        view = o.view if view is None else view
        landmarks_px = {}
        if len(o.landmark_ids):
            uv = view.project(np.asarray(vertices)[o.landmark_ids])
            landmarks_px = dict(zip(o.landmark_names, uv, strict=True))
        return cls(o.name, image_size, display, annotations, outlines, landmarks_px, view)
