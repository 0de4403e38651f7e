"""Error reports: figures (matplotlib, off-screen PyVista) and HTML pages (Jinja2)."""

from .advice import FLAG_ADVICE, flag_advice
from .case_report import ReportView, write_case_report
from .figures import convergence_figure, histogram_figure, overlay_figure
from .frames import write_frames_report
from .html import render_template, write_page
from .render3d import render_error_mesh
from .residuals import ContourResidual, contour_residuals
from .shading import shaded_faces

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
    "render_template",
    "shaded_faces",
    "write_case_report",
    "write_frames_report",
    "write_page",
]
