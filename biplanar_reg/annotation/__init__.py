"""Annotation of X-ray images: landmarks, contours and semi-automatic tools.

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.
See ``docs/annotation.md``; the package exports the names listed in ``docs/api.md`` (the
implementation modules hold more, for the package's own use).
"""

from .._lazy import lazy_dir, lazy_getattr
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

# eager: a lazy ``livewire`` would be shadowed by the submodule of that name once imported
from .livewire import livewire  # noqa: E402

#: The other semi-automatic tools and the radiograph renderer, imported on first use (a
#: case's registration uses none of them; ``livewire`` imports scikit-image and scipy.ndimage
#: only when it runs).
_LAZY = {
    "Radiograph": ".render",
    "render_radiograph": ".render",
    "ContourRecipe": ".recipe",
    "load_recipe": ".recipe",
    "run_recipe": ".recipe",
    "grabcut_outline": ".region",
    "SnapResult": ".snap",
    "snap_landmark": ".snap",
}


__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)


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
