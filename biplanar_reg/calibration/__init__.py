"""Camera models of X-ray views (pixels <-> world rays) and calibration I/O."""

from .geometry import describe_view, principal_rays_distance, view_angle_deg
from .io import FORMATS, WRITABLE_FORMATS, detect_format, load_calibration, save_calibration
from .projection_matrix import compose_projection, decompose_projection, dlt_projection
from .views import OrthographicView, PerspectiveView, SlotScanningView, View

__all__ = [
    "View",
    "PerspectiveView",
    "OrthographicView",
    "SlotScanningView",
    "FORMATS",
    "WRITABLE_FORMATS",
    "detect_format",
    "load_calibration",
    "save_calibration",
    "describe_view",
    "view_angle_deg",
    "principal_rays_distance",
    "compose_projection",
    "decompose_projection",
    "dlt_projection",
]
