"""Camera models of X-ray views (pixels <-> world rays) and calibration I/O."""

from .views import OrthographicView, PerspectiveView, SlotScanningView, View

__all__ = ["View", "PerspectiveView", "OrthographicView", "SlotScanningView"]
