"""Camera models of X-ray views (pixels <-> world rays) and calibration I/O.

See ``docs/calibration.md``; the package exports the names listed in ``docs/api.md``. The
format readers and writers (``mayacam``, ``dlt``, ``native_json``, ``dicom_geometry``), the
pinhole maths and phantom calibration (``phantom.calibrate_phantom``) live in their modules;
``autoscoper`` writes Autoscoper trials (``docs/exports.md``).
"""

from ..errors import CalibrationFormatError
from .autoscoper import AutoscoperVolume, read_autoscoper_cfg, write_autoscoper_trial
from .geometry import principal_rays_distance, view_angle_deg
from .io import FORMATS, WRITABLE_FORMATS, detect_format, load_calibration, save_calibration
from .projection_matrix import compose_projection, decompose_projection
from .views import OrthographicView, PerspectiveView, SlotScanningView, View

__all__ = [
    "View",
    "PerspectiveView",
    "OrthographicView",
    "SlotScanningView",
    "CalibrationFormatError",
    "FORMATS",
    "WRITABLE_FORMATS",
    "detect_format",
    "load_calibration",
    "save_calibration",
    "view_angle_deg",
    "principal_rays_distance",
    "compose_projection",
    "decompose_projection",
    "AutoscoperVolume",
    "read_autoscoper_cfg",
    "write_autoscoper_trial",
]
