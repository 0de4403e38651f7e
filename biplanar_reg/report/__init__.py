"""Error reports: 2D figures with matplotlib (:mod:`.plotting`), the 3D view with PyVista
off-screen (:mod:`.render3d`, matplotlib 3D where OpenGL is missing) and HTML pages (Jinja2).

The names below are loaded from their modules on first use, so that a light import (the
workbench's :mod:`.shading`, the flag table of :mod:`.advice`, :mod:`.residuals`) loads neither
matplotlib, PyVista nor Jinja2.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_dir, lazy_getattr

if TYPE_CHECKING:
    from .advice import FLAG_ADVICE, flag_advice
    from .case_report import write_case_report
    from .figures import convergence_figure, histogram_figure, overlay_figure
    from .frames import write_frames_report
    from .html import render_template, write_page
    from .render3d import render_error_mesh, render_surface
    from .report_view import ReportView
    from .residuals import ContourResidual, contour_residuals
    from .shading import shaded_faces

#: Each exported name and the module (of this package) that defines it.
_LAZY = {
    "FLAG_ADVICE": ".advice",
    "ContourResidual": ".residuals",
    "ReportView": ".report_view",
    "contour_residuals": ".residuals",
    "convergence_figure": ".figures",
    "flag_advice": ".advice",
    "histogram_figure": ".figures",
    "overlay_figure": ".figures",
    "render_error_mesh": ".render3d",
    "render_surface": ".render3d",
    "render_template": ".html",
    "shaded_faces": ".shading",
    "write_case_report": ".case_report",
    "write_frames_report": ".frames",
    "write_page": ".html",
}
__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)

__all__ = [
    "FLAG_ADVICE",
    "ContourResidual",
    "ReportView",
    "contour_residuals",
    "convergence_figure",
    "flag_advice",
    "histogram_figure",
    "overlay_figure",
    "render_error_mesh",
    "render_surface",
    "render_template",
    "shaded_faces",
    "write_case_report",
    "write_frames_report",
    "write_page",
]
