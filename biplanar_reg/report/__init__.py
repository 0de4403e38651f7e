"""Error reports: figures (matplotlib, off-screen PyVista) and HTML pages (Jinja2)."""

from .case_report import ReportView, write_case_report
from .figures import convergence_figure, histogram_figure, overlay_figure
from .html import render_template, write_page
from .render3d import render_error_mesh

__all__ = [
    "ReportView",
    "convergence_figure",
    "histogram_figure",
    "overlay_figure",
    "render_error_mesh",
    "render_template",
    "write_case_report",
    "write_page",
]
