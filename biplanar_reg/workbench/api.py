"""The workbench's HTTP server: the page, its static files and the JSON API (Starlette).

Every request must carry the launch token: the query parameter ``token``, the header
``X-Workbench-Token`` or the cookie ``biplanar_wb`` that ``GET /?token=...`` sets (HttpOnly,
SameSite=Strict); otherwise 403. Errors are ``{"error": "<field or path>: <what is wrong>"}``
with a 4xx status (400 bad input, 403 token, 404 unknown view/contour/tile/result, 409 not now,
413 body too large), and 500 ``{"error": "internal error: ..."}`` (logged) for a bug; a
traceback never reaches the client. The routes are listed in ``docs/workbench.md``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import secrets
from collections.abc import AsyncIterator, Awaitable, Callable
from html import escape
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
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .outline_tools import outline_routes
from .session import Conflict, NotFound, Workbench

__all__ = ["create_app"]

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).resolve().parent / "static"
COOKIE = "biplanar_wb"
HEADER = "x-workbench-token"
#: Largest request body, bytes (a 100,000-point contour is ~3 MB of JSON).
MAX_BODY = 8 * 1024 * 1024
#: Seconds between keep-alive comments of the event stream.
KEEPALIVE_S = 15.0
_SECURITY_HEADERS = [
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),  # the page's URL holds the token
    (b"x-frame-options", b"DENY"),
]


class ApiError(Exception):
    """An error response: ``status`` and the one-line ``message``."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def _one_line(exc: BaseException) -> str:
    problems = getattr(exc, "problems", None)  # AnnotationError: every problem, by its key
    text = "; ".join(problems) if problems else str(exc)
    return " ".join(text.split()) or type(exc).__name__


def _valid(candidate: str | None, token: str) -> bool:
    """Constant-time comparison with the token."""
    if not candidate:
        return False
    return secrets.compare_digest(candidate.encode("utf-8", "replace"), token.encode("ascii"))


def _forbidden_page(message: str) -> HTMLResponse:
    """The 403 answer to a browser: a short page that says what to do (escaped)."""
    body = (
        "<!doctype html><html><head><meta charset='utf-8'><title>biplanar-reg workbench: "
        "access denied</title></head><body style='font-family:sans-serif;margin:3em'>"
        f"<h1>Access denied (403)</h1><p>{escape(message)}</p></body></html>"
    )
    return HTMLResponse(body, status_code=403)


class TokenGuard:
    """ASGI middleware: refuse (403) every HTTP request without the launch token."""

    def __init__(self, app: ASGIApp, token: str):
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        given = (
            request.query_params.get("token"),
            request.headers.get(HEADER),
            request.cookies.get(COOKIE),
        )
        if not any(_valid(t, self.token) for t in given):
            message = (
                "token: missing or wrong workbench token (open the URL that biplanar-reg "
                "workbench printed)"
            )
            # a person who opens the page without the token reads a page, not raw JSON
            wants_page = not request.url.path.startswith("/api") and "text/html" in (
                request.headers.get("accept", "")
            )
            response = _forbidden_page(message) if wants_page else _error(403, message)
            await response(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = list(message.get("headers", [])) + _SECURITY_HEADERS
            await send(message)

        await self.app(scope, receive, send_with_headers)


Handler = Callable[[Request], Awaitable[Response]]


def _guarded(fn: Handler) -> Handler:
    """Map the session's exceptions to JSON error responses (never a traceback)."""

    async def endpoint(request: Request) -> Response:
        try:
            return await fn(request)
        except ApiError as exc:
            return _error(exc.status, exc.message)
        except NotFound as exc:
            return _error(404, _one_line(exc))
        except Conflict as exc:
            return _error(409, _one_line(exc))
        except ValueError as exc:  # bad input, named by its field (AnnotationError included)
            return _error(400, _one_line(exc))
        except Exception as exc:  # noqa: BLE001 - the client gets one line, the log the rest
            log.exception("%s %s failed", request.method, request.url.path)
            return _error(500, f"internal error: {type(exc).__name__}: {_one_line(exc)}")

    endpoint.__name__ = fn.__name__
    return endpoint


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"non-standard JSON number {name!r}")


async def _body(request: Request) -> dict[str, Any]:
    """The request's JSON object body (NaN/Infinity refused; at most :data:`MAX_BODY` bytes)."""
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY:
            raise ApiError(413, f"body: larger than {MAX_BODY} bytes")
        chunks.append(chunk)
    raw = b"".join(chunks)
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_refuse_constant)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ApiError(400, f"body: not valid JSON ({_one_line(exc)})") from None
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


_TOKEN_SLOT = re.compile(r"([?&]token=)(?=[\"'&#])")
_HEAD = re.compile(r"<head[^>]*>", re.I)


def _page(token: str) -> str:
    """``index.html`` with the token: every empty ``?token=`` / ``&token=`` of a URL in it is
    completed, and ``<meta name="workbench-token" content="...">`` is added for scripts that
    send it as the ``X-Workbench-Token`` header."""
    html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    html = _TOKEN_SLOT.sub(lambda m: m.group(1) + token, html)
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

    async def index(self, request: Request) -> Response:
        html = await _call(_page, self.token)
        resp = HTMLResponse(html, headers={"Cache-Control": "no-store"})
        if _valid(request.query_params.get("token"), self.token):
            resp.set_cookie(COOKIE, self.token, httponly=True, samesite="strict", path="/")
        return resp

    async def case(self, request: Request) -> Response:
        return JSONResponse(await _call(self.wb.case_info))

    async def annotations(self, request: Request) -> Response:
        return JSONResponse(await _call(self.wb.annotations_document))

    async def tile(self, request: Request) -> Response:
        p = request.path_params
        lo, hi = _query_float(request, "lo"), _query_float(request, "hi")
        png = await _call(self.wb.tile, p["view"], p["level"], p["tx"], p["ty"], lo, hi)
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
        view, i = request.path_params["view"], request.path_params["index"]
        if request.method == "DELETE":
            return JSONResponse({"index": i, "view": await _call(self.wb.delete_contour, view, i)})
        body = await _body(request)
        args = (view, i, body.get("uv"), body.get("closed"), body.get("anchors"))
        return JSONResponse({"index": i, "view": await _call(self.wb.replace_contour, *args)})

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
        body = await _body(request) if action == "nudge" else {}
        if action == "nudge":
            args = (body.get("view"), body.get("translate_px"), body.get("rotate_deg"))
            return JSONResponse(await _call(self.aid.nudge, *args))
        if action == "reset":
            return JSONResponse(await _call(self.aid.reset))
        if action == "start":
            return JSONResponse(await _call(self.aid.save_start))
        raise ApiError(404, f"{request.url.path}: no such pose-aid action (nudge, reset, start)")

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
        (v + "/contours/{index:int}", h.contour, ["PUT", "DELETE"]),
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


def create_app(workbench: Workbench, token: str) -> Starlette:
    """The ASGI application of a workbench.

    Parameters
    ----------
    workbench : Workbench
        The open case (the app does not close it).
    token : str
        The launch token every request must carry (``secrets.token_urlsafe(24)``).

    Returns
    -------
    Starlette
        The application (token check first); run it with uvicorn.
    """
    if not token or not token.isascii():
        raise ValueError("token: expected a non-empty ASCII string")
    app = Starlette(
        routes=_routes(workbench, token),
        middleware=[Middleware(TokenGuard, token=token)],
        exception_handlers={HTTPException: _http_error},
    )
    app.state.workbench = workbench
    return app
