"""The workbench's HTTP server: the page, its static files and the JSON API (Starlette).

Every connection passes :class:`biplanar_reg.workbench.access.Guard` first: the ``Host``
header, the peer's user, cross-origin requests, the launch token (the ``X-Workbench-Token``
header, the session cookie that a one-time URL ``/?launch=CODE`` or ``/?token=...`` sets, or
the query parameter ``token``; a state-changing request needs the header and a JSON body);
otherwise 403 (415 for a body that is not JSON). Errors are ``{"error": "<field or path>: <what
is wrong>"}`` with a 4xx status (400 bad input, 403 refused, 404 unknown view/contour/tile/
result, 409 not now or a stale edit, 413 body too large, 415 not JSON), and 500 ``{"error":
"internal error: ..."}`` (logged) for a bug; a traceback never reaches the client. The routes
are listed in ``docs/workbench.md``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..errors import one_line
from .access import Access, Guard
from .outline_tools import outline_routes
from .session import Conflict, NotFound, Workbench, require_version
from .view_aids import ViewAids, view_aid_routes

__all__ = ["create_app"]

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).resolve().parent / "static"
#: Largest request body, bytes (a 100,000-point contour is ~3 MB of JSON).
MAX_BODY = 8 * 1024 * 1024
#: Seconds between keep-alive comments of the event stream.
KEEPALIVE_S = 15.0


class ApiError(Exception):
    """An error response: ``status`` and the one-line ``message``."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


Handler = Callable[[Request], Awaitable[Response]]


def _guarded(fn: Handler) -> Handler:
    """Map the session's exceptions to JSON error responses (never a traceback)."""

    async def endpoint(request: Request) -> Response:
        try:
            return await fn(request)
        except ApiError as exc:
            return _error(exc.status, exc.message)
        except NotFound as exc:
            return _error(404, one_line(exc))
        except Conflict as exc:
            return _error(409, one_line(exc))
        except ValueError as exc:  # bad input, named by its field (AnnotationError included)
            return _error(400, one_line(exc))
        except Exception as exc:  # noqa: BLE001 - the client gets one line, the log the rest
            log.exception("%s %s failed", request.method, request.url.path)
            return _error(500, f"internal error: {type(exc).__name__}: {one_line(exc)}")

    endpoint.__name__ = fn.__name__
    return endpoint


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"non-standard JSON number {name!r}")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise ValueError(f"duplicate key {key!r}")
        doc[key] = value
    return doc


async def _body(request: Request) -> dict[str, Any]:
    """The request's JSON object body (NaN/Infinity and duplicate keys refused; at most
    :data:`MAX_BODY` bytes). The guard let only ``Content-Type: application/json`` through."""
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY:
            raise ApiError(413, f"body: larger than {MAX_BODY} bytes")
        chunks.append(chunk)
    raw = b"".join(chunks)
    try:
        doc = json.loads(
            raw.decode("utf-8"), parse_constant=_refuse_constant, object_pairs_hook=_unique_keys
        )
    except (ValueError, UnicodeDecodeError) as exc:
        raise ApiError(400, f"body: not valid JSON ({one_line(exc)})") from None
    if not isinstance(doc, dict):
        raise ApiError(400, f"body: expected a JSON object, got {type(doc).__name__}")
    return doc


def _query_float(request: Request, name: str) -> float | None:
    value = request.query_params.get(name)
    if value is None or value == "":
        return None
    try:
        return float(value)
    except ValueError:
        raise ApiError(400, f"{name}: expected a number, got {value[:40]!r}") from None


_HEAD = re.compile(r"<head[^>]*>", re.I)


def page_html(name: str, token: str) -> str:
    """``static/<name>`` with ``<meta name="workbench-token" content="...">`` added after
    ``<head>``, for its scripts, which send it in the ``X-Workbench-Token`` header. (The page is
    served only to a browser that has the session cookie, with ``Cache-Control: no-store``; its
    static files get through with the cookie.)"""
    html = (STATIC_DIR / name).read_text(encoding="utf-8")
    meta = f'<meta name="workbench-token" content="{token}">'
    m = _HEAD.search(html)
    return html[: m.end()] + meta + html[m.end() :] if m else meta + html


async def _call(fn: Callable[..., Any], *args: Any) -> Any:
    """Run a session method in the thread pool: file I/O and numerics stay off the event loop."""
    return await run_in_threadpool(fn, *args)


class _Handlers:
    """The endpoints over one workbench (see ``docs/workbench.md`` for each)."""

    def __init__(self, wb: Workbench, token: str):
        self.wb = wb
        self.token = token
        from .model_view import ModelView
        from .pose_aid import PoseAid

        self.aid = PoseAid(wb)
        self.meshes = ModelView(wb, self.aid.mean)
        self.aids = ViewAids(wb)  # epipolar curves, markers, CLAHE tiles (view_aids.py)

    async def index(self, request: Request) -> Response:
        html = await _call(page_html, "index.html", self.token)
        return HTMLResponse(html, headers={"Cache-Control": "no-store"})

    async def case(self, request: Request) -> Response:
        return JSONResponse(await _call(self.wb.case_info))

    async def annotations(self, request: Request) -> Response:
        return JSONResponse(await _call(self.wb.annotations_document))

    async def tile(self, request: Request) -> Response:
        p = request.path_params
        lo, hi = _query_float(request, "lo"), _query_float(request, "hi")
        make = self.aids.tile if request.query_params.get("clahe") == "1" else self.wb.tile
        png = await _call(make, p["view"], p["level"], p["tx"], p["ty"], lo, hi)
        return Response(
            png, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"}
        )

    async def landmark(self, request: Request) -> Response:
        view, name = request.path_params["view"], request.path_params["name"]
        if request.method == "DELETE":
            return JSONResponse(await _call(self.wb.delete_landmark, view, name))
        body = await _body(request)
        args = (view, name, body.get("uv"), body.get("sigma_px"))
        return JSONResponse(await _call(self.wb.set_landmark, *args))

    async def snap(self, request: Request) -> Response:
        body = await _body(request)
        args = (request.path_params["view"], body.get("uv"), body.get("mode"))
        return JSONResponse(await _call(self.wb.snap, *args, body.get("radius_px")))

    async def livewire(self, request: Request) -> Response:
        body = await _body(request)
        args = (request.path_params["view"], body.get("anchors"), body.get("closed"))
        return JSONResponse(await _call(self.wb.livewire, *args))

    async def contours(self, request: Request) -> Response:
        body = await _body(request)
        args = (body.get("uv"), body.get("closed"), body.get("anchors"))
        index, doc = await _call(self.wb.add_contour, request.path_params["view"], *args)
        return JSONResponse({"index": index, "view": doc})

    async def contour(self, request: Request) -> Response:
        view, ref = request.path_params["view"], request.path_params["ref"]
        version = require_version(request.query_params.get("version"))
        i = await _call(self.wb.contour_index, view, ref, version)  # a stale edit: 409
        if request.method == "DELETE":
            doc = await _call(lambda: self.wb.delete_contour(view, ref, version=version))
            return JSONResponse({"index": i, "view": doc})
        body = await _body(request)
        args = (view, ref, body.get("uv"), body.get("closed"), body.get("anchors"))
        doc = await _call(lambda: self.wb.replace_contour(*args, version=version))
        return JSONResponse({"index": i, "view": doc})

    async def history(self, request: Request) -> Response:
        return JSONResponse({"history": await _call(self.wb.history.status)})

    async def history_move(self, request: Request) -> Response:
        action = request.path_params["action"]
        if action not in ("undo", "redo"):
            raise ApiError(404, f"{request.url.path}: no such history action (undo, redo)")
        return JSONResponse(await _call(getattr(self.wb, action)))

    async def register(self, request: Request) -> Response:
        if request.method == "POST":
            return JSONResponse(await _call(self.wb.start_registration))
        return JSONResponse(self.wb.job.status())

    async def events(self, request: Request) -> Response:
        return StreamingResponse(
            _events(self.wb),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )

    async def result(self, request: Request) -> Response:
        return JSONResponse(await _call(self.wb.result))

    async def model_landmark(self, request: Request) -> Response:
        name = request.path_params["name"]
        if request.method == "DELETE":
            return JSONResponse(await _call(self.wb.delete_model_landmark, name))
        body = await _body(request)
        return JSONResponse(await _call(self.wb.set_model_landmark, name, body.get("vertex")))

    async def pose_aid(self, request: Request) -> Response:
        return JSONResponse(await _call(self.aid.document))

    async def pose_aid_action(self, request: Request) -> Response:
        action = request.path_params["action"]
        body = await _body(request) if action in ("nudge", "set") else {}
        if action == "nudge":
            args = (body.get("view"), body.get("translate_px"), body.get("rotate_deg"))
            return JSONResponse(await _call(self.aid.nudge, *args, body.get("preview", False)))
        if action == "set":
            args = (body.get("centre_mm"), body.get("angles_deg"))
            return JSONResponse(await _call(self.aid.set_fields, *args))
        simple = {"reset": self.aid.reset, "undo": self.aid.undo, "start": self.aid.save_start}
        if action in simple:
            return JSONResponse(await _call(simple[action]))
        raise ApiError(
            404, f"{request.url.path}: no such pose-aid action (nudge, set, reset, undo, start)"
        )

    async def propose_outline(self, request: Request) -> Response:
        body = await _body(request)
        args = (request.path_params["view"], body.get("spacing_px"))
        return JSONResponse(await _call(self.aid.propose, *args))

    async def model_mesh(self, request: Request) -> Response:
        return JSONResponse(await _call(self.meshes.model_mesh))

    async def result_mesh(self, request: Request) -> Response:
        return JSONResponse(await _call(self.meshes.result_mesh))

    async def result_shading(self, request: Request) -> Response:
        view = request.path_params["view"]
        return JSONResponse(await _call(self.meshes.shading, view))


def _routes(wb: Workbench, token: str) -> list[Route | Mount]:
    """The page, the JSON API and the static files."""
    h = _Handlers(wb, token)
    v = "/api/views/{view}"
    table: list[tuple[str, Handler, list[str]]] = [
        ("/", h.index, ["GET"]),
        ("/api/case", h.case, ["GET"]),
        ("/api/annotations", h.annotations, ["GET"]),
        (v + "/tiles/{level:int}/{tx:int}/{ty:int}.png", h.tile, ["GET"]),
        (v + "/landmarks/{name}", h.landmark, ["PUT", "DELETE"]),
        (v + "/snap", h.snap, ["POST"]),
        (v + "/livewire", h.livewire, ["POST"]),
        (v + "/contours", h.contours, ["POST"]),
        (v + "/contours/{ref}", h.contour, ["PUT", "DELETE"]),
        ("/api/history", h.history, ["GET"]),
        ("/api/history/{action}", h.history_move, ["POST"]),
        ("/api/register", h.register, ["GET", "POST"]),
        ("/api/register/events", h.events, ["GET"]),
        ("/api/result", h.result, ["GET"]),
        ("/api/model/landmarks/{name}", h.model_landmark, ["PUT", "DELETE"]),
        ("/api/model/mesh", h.model_mesh, ["GET"]),
        ("/api/result/mesh", h.result_mesh, ["GET"]),
        ("/api/result/shading/{view}", h.result_shading, ["GET"]),
        ("/api/pose-aid", h.pose_aid, ["GET"]),
        ("/api/pose-aid/{action}", h.pose_aid_action, ["POST"]),
        (v + "/propose-outline", h.propose_outline, ["POST"]),
    ]
    routes: list[Route | Mount] = [Route(p, _guarded(fn), methods=m) for p, fn, m in table]
    routes += outline_routes(wb, _guarded, _body, _call)  # outline editing (outline_tools.py)
    routes += view_aid_routes(h.aids, _guarded, _call)  # epipolar, markers (view_aids.py)
    routes.append(Mount("/static", app=StaticFiles(directory=STATIC_DIR), name="static"))
    return routes


def _sse(event: str | None, data: str) -> str:
    head = f"event: {event}\n" if event else ""
    return f"{head}data: {data}\n\n"


async def _events(wb: Workbench) -> AsyncIterator[str]:
    """Server-Sent Events of the registration: each progress message as a ``data:`` line (the
    current run's from its start), then ``event: done`` or ``event: failed`` with the status as
    JSON; ``event: idle`` when no registration was started."""
    job = wb.job
    run, sent = job.run, 0
    quiet = 0.0
    while True:
        new_run, messages, state, status = await run_in_threadpool(job.since, run, sent)
        if new_run != run:
            run, sent = new_run, 0
        for m in messages:
            yield _sse(None, m)
        sent += len(messages)
        if state in ("done", "failed", "idle"):
            yield _sse(state, json.dumps(status))
            return
        if messages:
            quiet = 0.0
        elif quiet >= KEEPALIVE_S:
            yield ": keep-alive\n\n"  # a comment: keeps proxies and the browser from timing out
            quiet = 0.0
        await asyncio.sleep(0.1)
        quiet += 0.1


async def _http_error(request: Request, exc: Exception) -> Response:
    """Routing errors (404, 405) and static files as JSON errors too."""
    status = getattr(exc, "status_code", 500)
    detail = getattr(exc, "detail", "") or "error"
    return _error(status, f"{request.url.path}: {detail}")


def as_access(token: str | Access) -> Access:
    """An :class:`Access` from a token string (loopback host) or the given one."""
    return token if isinstance(token, Access) else Access(token)


def create_app(workbench: Workbench, token: str | Access) -> Starlette:
    """The ASGI application of a workbench.

    Parameters
    ----------
    workbench : Workbench
        The open case (the app does not close it).
    token : str or Access
        The launch token every request must carry (ASCII, at least 16 characters, e.g.
        ``secrets.token_urlsafe(24)``), for a server on a loopback address; or an
        :class:`~biplanar_reg.workbench.access.Access` (the command's: the token, one-time
        URLs and the host it listens on).

    Returns
    -------
    Starlette
        The application (every connection checked first, see :mod:`.access`); run it with
        uvicorn.
    """
    access = as_access(token)
    app = Starlette(
        routes=_routes(workbench, access.token),
        middleware=[Middleware(Guard, access=access)],
        exception_handlers={HTTPException: _http_error},
    )
    app.state.workbench = workbench
    app.state.access = access
    return app
