"""Annotation of X-ray images: landmarks, contours and semi-automatic tools.

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.
See ``docs/annotation.md``; the package exports the names listed in ``docs/api.md`` (the
implementation modules hold more, for the package's own use).
"""

from ..errors import AnnotationError
from .annotations import (
    Annotations,
    Contour,
    Landmark,
    ViewAnnotations,
    load_annotations,
    merge_annotations,
    save_annotations,
)
from .clean import clean_contour, cut_polyline, remove_self_intersections, resample_polyline
from .image import XrayImage, load_image, read_image_size
from .livewire import livewire
from .recipe import ContourRecipe, load_recipe, run_recipe
from .region import grabcut_outline
from .render import Radiograph, render_radiograph
from .snap import SnapResult, snap_landmark

__all__ = [
    "AnnotationError",
    "Annotations",
    "Contour",
    "ContourRecipe",
    "Landmark",
    "Radiograph",
    "SnapResult",
    "ViewAnnotations",
    "XrayImage",
    "clean_contour",
    "cut_polyline",
    "grabcut_outline",
    "livewire",
    "load_annotations",
    "load_image",
    "load_recipe",
    "merge_annotations",
    "read_image_size",
    "remove_self_intersections",
    "render_radiograph",
    "resample_polyline",
    "run_recipe",
    "save_annotations",
    "snap_landmark",
]
