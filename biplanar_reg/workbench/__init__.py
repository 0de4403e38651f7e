"""The workbench: annotate, register and review one case folder in the browser.

``biplanar-reg workbench CASE_DIR`` serves a local page (Starlette + uvicorn, bound to
127.0.0.1, a per-launch token) whose every edit is saved in the case folder in the documented
formats. :class:`Workbench` is the open case (lock, views, edits), :func:`create_app` the ASGI
application over it. See ``docs/workbench.md``.
"""

from .api import create_app
from .session import Workbench, WorkbenchError

__all__ = ["create_app", "Workbench", "WorkbenchError"]
