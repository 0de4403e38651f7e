"""Who may use a workbench server: the launch token, one-time URLs, and the checks that every
connection passes before the application sees it.

:class:`Access` holds the per-launch token (never printed, never on a command line), the
one-time launch codes (``/?launch=CODE`` signs a browser in once: the answer sets the session
cookie and sends the browser on to the clean URL ``/``), the name of the cookie and the host
names the server answers to. :class:`Guard` is the ASGI middleware that applies it to every
HTTP and WebSocket connection (``lifespan`` passes through, any other scope type is refused):

1. the ``Host`` header must name the bound address (``127.0.0.1``/``localhost``/``::1`` for a
   loopback address): a page of another domain that resolves to 127.0.0.1 (DNS rebinding) is
   refused;
2. the connection must come from this user's programs when the peer is on this machine
   (Linux: the peer socket's owner in ``/proc/net/tcp``; root is let through, a peer that
   cannot be looked up too);
3. a cross-origin request is refused: an ``Origin`` header other than the page's own
   (``http://`` + the ``Host`` header; another port of 127.0.0.1 is another origin), or
   ``Sec-Fetch-Site: cross-site`` / ``same-site`` (other than a top-level page navigation);
4. the token: the ``X-Workbench-Token`` header, the session cookie, or the query parameter
   ``token``; a state-changing request (``POST``, ``PUT``, ``DELETE``, ``PATCH``) must carry
   it in the header (a form or an ``<img>`` of another page cannot set a header) and
5. must be ``Content-Type: application/json`` (415 otherwise: a ``text/plain`` body is never
   read as JSON).

Refusals are 403 (415 for the content type) with ``{"error": "<what>: ..."}``; a browser
asking for a page gets a short HTML page that says what to do; a WebSocket is closed with
code 1008 before it is accepted.
"""

from __future__ import annotations

import hashlib
import ipaddress
import json
import logging
import os
import secrets
import socket
import sys
import threading
import time
from html import escape

from starlette.requests import HTTPConnection
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["Access", "Guard"]

log = logging.getLogger(__name__)

HEADER = "x-workbench-token"
COOKIE_PREFIX = "biplanar_wb_"
#: Methods that change something: the token must be in the header, the body JSON.
MUTATING = frozenset({"POST", "PUT", "DELETE", "PATCH"})
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
WILDCARD = frozenset({"0.0.0.0", "::"})
SECURITY_HEADERS = [
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
]
#: How long the owner of a connection's client socket is remembered, seconds.
PEER_CACHE_S = 2.0
_TOKEN_HINT = (
    "open the one-time URL that biplanar-reg workbench printed (press Enter in its terminal "
    "for a new one)"
)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) is this machine only."""
    if host.strip("[]").lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    """Whether ``host`` means every interface (``0.0.0.0``, ``::``)."""
    return host.strip("[]") in WILDCARD


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def host_name(header: str | None) -> str | None:
    """The host of a ``Host`` header, lower case, without the port and IPv6 brackets."""
    if not header:
        return None
    h = header.strip().lower()
    if h.startswith("["):
        end = h.find("]")
        return h[1:end] if end > 0 else None
    name, sep, port = h.rpartition(":")
    if sep and port.isdigit() and ":" not in name:
        return name or None
    return h if ":" not in h or _is_ip(h) else None


def _machine_names() -> set[str]:
    names = {"localhost"}
    for get in (socket.gethostname, socket.getfqdn):
        try:
            names.add(get().lower())
        except OSError:
            pass
    return names


class Access:
    """The credentials of one workbench server.

    Parameters
    ----------
    token : str, optional
        The launch token (default: ``secrets.token_urlsafe(24)``); ASCII, at least 16
        characters.
    host : str
        The address the server listens on: decides the host names accepted in the ``Host``
        header (a loopback address: ``127.0.0.1``, ``localhost``, ``::1``; ``0.0.0.0``/``::``:
        any IP address and this machine's names; another address or name: itself).
    """

    def __init__(self, token: str | None = None, *, host: str = "127.0.0.1"):
        token = secrets.token_urlsafe(24) if token is None else token
        if not isinstance(token, str) or not token.isascii() or len(token) < 16:
            raise ValueError("token: expected an ASCII string of at least 16 characters")
        self.token = token
        digest = hashlib.sha256(("biplanar-wb-cookie:" + token).encode()).hexdigest()
        #: one name per launch: two workbenches in one browser keep their own cookie
        self.cookie = COOKIE_PREFIX + digest[:12]
        self.host = host
        self._wildcard = is_wildcard(host)
        bare = host.strip("[]").lower()
        self._names = ({bare} | LOOPBACK_NAMES) if is_loopback(host) else {bare}
        if self._wildcard:
            self._names = _machine_names()
        self._codes: set[str] = set()
        self._lock = threading.Lock()

    # -- the token and the one-time codes ---------------------------------------------------------

    def valid(self, candidate: str | None) -> bool:
        """Constant-time comparison with the token."""
        if not candidate:
            return False
        return secrets.compare_digest(candidate.encode("utf-8", "replace"), self.token.encode())

    def one_time_code(self) -> str:
        """A new code for ``/?launch=CODE``: it signs one browser in, once."""
        code = secrets.token_urlsafe(24)
        with self._lock:
            self._codes.add(code)
        return code

    def redeem(self, code: str | None) -> bool:
        """Use up ``code``: True (once) when it is one of the unused codes."""
        if not code:
            return False
        given = code.encode("utf-8", "replace")
        with self._lock:
            for known in list(self._codes):
                if secrets.compare_digest(given, known.encode()):
                    self._codes.discard(known)
                    return True
        return False

    # -- the host ----------------------------------------------------------------------------------

    def host_allowed(self, header: str | None) -> bool:
        """Whether a ``Host`` header names this server (see the class)."""
        name = host_name(header)
        if name is None:
            return False
        if self._wildcard and _is_ip(name):
            return True
        return name in self._names


# -- the peer's user (Linux) ----------------------------------------------------------------------


def _proc_address(host: str, port: int) -> tuple[str, str] | None:
    """``host:port`` as ``/proc/net/tcp[6]`` writes a socket's address, and which file."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    raw = ip.packed
    # each 32-bit word in the host's byte order (little-endian on the usual machines)
    words = [raw[i : i + 4] for i in range(0, len(raw), 4)]
    order = "little" if sys.byteorder == "little" else "big"
    hexed = "".join(f"{int.from_bytes(w, order):08X}" for w in words)
    table = "tcp" if ip.version == 4 else "tcp6"
    return f"{hexed}:{port:04X}", table


def peer_uid(client: tuple[str, int] | None, server: tuple[str, int] | None) -> int | None:
    """The user id owning the client socket of a TCP connection from this machine, or None
    (not Linux, not a local peer, not found)."""
    if not client or not server or not sys.platform.startswith("linux"):
        return None
    local = _proc_address(str(client[0]), int(client[1]))
    remote = _proc_address(str(server[0]), int(server[1]))
    if local is None or remote is None or local[1] != remote[1]:
        return None
    try:
        with open(f"/proc/net/{local[1]}", "rb") as f:
            table = f.read()
    except OSError:
        return None
    # a line: "  sl: local rem st tx_queue:rx_queue tr:tm->when retrnsmt uid ..."
    at = table.find(f": {local[0]} {remote[0]} ".encode())
    if at < 0:
        return None
    end = table.find(b"\n", at)
    fields = table[at : end if end >= 0 else None].split()
    try:
        return int(fields[7])
    except (IndexError, ValueError):
        return None


class _PeerCache:
    """:func:`peer_uid` of a connection, remembered for :data:`PEER_CACHE_S` seconds (a page's
    requests come over a few kept-alive connections; reading ``/proc/net/tcp`` takes ~1 ms
    per thousand sockets). Short enough that a client port cannot be closed and taken by
    another user's program within it (a browser's kept-alive connection lives longer, and a
    port the client closed stays in TIME_WAIT)."""

    def __init__(self) -> None:
        self._seen: dict[tuple, tuple[int | None, float]] = {}

    def uid(self, client: tuple[str, int] | None, server: tuple[str, int] | None) -> int | None:
        now = time.monotonic()
        key = (tuple(client or ()), tuple(server or ()))
        hit = self._seen.get(key)
        if hit is not None and hit[1] > now:
            return hit[0]
        uid = peer_uid(client, server)
        if len(self._seen) > 1024:
            self._seen = {k: v for k, v in self._seen.items() if v[1] > now}
        self._seen[key] = (uid, now + PEER_CACHE_S)
        return uid


# -- the middleware -------------------------------------------------------------------------------


def _forbidden_page(message: str, status: int = 403) -> HTMLResponse:
    """A refusal for a person: a short page that says what to do (escaped)."""
    body = (
        "<!doctype html><html><head><meta charset='utf-8'><title>biplanar-reg workbench: "
        "access denied</title></head><body style='font-family:sans-serif;margin:3em'>"
        f"<h1>Access denied ({status})</h1><p>{escape(message)}</p></body></html>"
    )
    return HTMLResponse(body, status_code=status, headers={"Cache-Control": "no-store"})


def _signed_in_page() -> HTMLResponse:
    """The answer to a one-time URL (or ``/?token=``): the cookie is set with it, and the page
    replaces itself with the clean ``/`` (the address bar and the history keep no secret)."""
    body = (
        "<!doctype html><html><head><meta charset='utf-8'><meta name='referrer' "
        "content='no-referrer'><title>biplanar-reg workbench</title>"
        "<meta http-equiv='refresh' content='0;url=/'></head><body>"
        "<script>location.replace('/');</script>"
        "<p style='font-family:sans-serif;margin:3em'>Opening the workbench&hellip; "
        "(<a href='/'>continue</a>)</p></body></html>"
    )
    return HTMLResponse(body, headers={"Cache-Control": "no-store"})


def _cross_origin(conn: HTTPConnection, method: str) -> str | None:
    """Why a request is cross-origin (then refused), or None."""
    origin = conn.headers.get("origin")
    own = "http://" + conn.headers.get("host", "").strip().lower()
    if origin is not None and origin.strip().lower() != own:
        return (
            f"origin: a request from {origin[:80]!r} refused (only the workbench's own page, "
            f"{own}, may call it)"
        )
    site = conn.headers.get("sec-fetch-site")
    if site in ("cross-site", "same-site"):
        navigation = (
            method in ("GET", "HEAD")
            and conn.headers.get("sec-fetch-mode") == "navigate"
            and conn.headers.get("sec-fetch-dest", "document") == "document"
        )
        if not navigation:
            return (
                f"sec-fetch-site: a {site} request refused (from another site or another port "
                "of this machine)"
            )
    return None


def _json_type(conn: HTTPConnection) -> str | None:
    """Why a state-changing request's Content-Type is refused, or None."""
    given = conn.headers.get("content-type")
    mime = (given or "").split(";", 1)[0].strip().lower()
    if mime == "application/json":
        return None
    shown = "none" if given is None else repr(given[:60])
    return f"content-type: expected application/json, got {shown}"


class Guard:
    """ASGI middleware applying an :class:`Access` to every connection (see the module)."""

    def __init__(self, app: ASGIApp, access: Access, check_peer: bool = True):
        self.app = app
        self.access = access
        self.check_peer = check_peer
        self._peers = _PeerCache()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind == "lifespan":
            await self.app(scope, receive, send)
            return
        if kind not in ("http", "websocket"):
            raise RuntimeError(f"workbench: refused an ASGI scope of type {kind!r}")
        conn = HTTPConnection(scope)
        method = scope.get("method", "GET") if kind == "http" else "GET"
        refusal = self._refusal(conn, method)
        if refusal is None and kind == "http":
            refusal = self._launch(conn, method)
        if kind == "websocket":
            if refusal is not None:
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": 1008})
                return
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = list(message.get("headers", [])) + SECURITY_HEADERS
            await send(message)

        if refusal is not None:
            await refusal(scope, receive, send_with_headers)
            return
        await self.app(scope, receive, send_with_headers)

    def _deny(self, conn: HTTPConnection, message: str, status: int = 403) -> Response:
        wants_page = not conn.url.path.startswith("/api") and "text/html" in (
            conn.headers.get("accept", "")
        )
        if wants_page:
            return _forbidden_page(message, status)
        return JSONResponse({"error": message}, status_code=status)

    def _refusal(self, conn: HTTPConnection, method: str) -> Response | None:
        """The answer refusing the connection (checks 1-5 of the module), or None."""
        host = conn.headers.get("host")
        if not self.access.host_allowed(host):
            shown = "none" if host is None else repr(host[:80])
            return self._deny(
                conn,
                f"host: {shown} is not this workbench's address (open it as "
                f"http://{_url_host(self.access.host)}:PORT/, the URL it printed)",
            )
        if self.check_peer:
            uid = self._peers.uid(conn.scope.get("client"), conn.scope.get("server"))
            if uid is not None and uid not in (os.getuid(), 0):
                log.warning("refused a connection from another user's program (uid %d)", uid)
                return self._deny(
                    conn,
                    f"peer: the connection comes from another user's program (uid {uid}); the "
                    "workbench answers only its own user",
                )
        why = _cross_origin(conn, method)
        if why is not None:
            return self._deny(conn, why)
        if self._launching(conn, method):
            return None  # a one-time URL is checked by _launch
        given = (
            conn.headers.get(HEADER),
            conn.cookies.get(self.access.cookie),
            conn.query_params.get("token"),
        )
        if method in MUTATING:
            if not self.access.valid(given[0]):
                return self._deny(
                    conn,
                    "token: a request that changes something must carry the workbench token "
                    "in the X-Workbench-Token header (the page sends it)",
                )
            why = _json_type(conn)
            return None if why is None else self._deny(conn, why, 415)
        if not any(self.access.valid(t) for t in given):
            return self._deny(conn, f"token: missing or wrong workbench token ({_TOKEN_HINT})")
        return None

    @staticmethod
    def _launching(conn: HTTPConnection, method: str) -> bool:
        return method == "GET" and conn.url.path == "/" and "launch" in conn.query_params

    def _launch(self, conn: HTTPConnection, method: str) -> Response | None:
        """``GET /?launch=CODE`` and ``GET /?token=TOKEN``: the cookie, then the clean URL."""
        if method != "GET" or conn.url.path != "/":
            return None
        if self._launching(conn, method):
            if self.access.redeem(conn.query_params.get("launch")):
                client = conn.scope.get("client")
                log.warning("a one-time URL was used (from %s)", client[0] if client else "?")
                return self._with_cookie(_signed_in_page())
            if self.access.valid(conn.cookies.get(self.access.cookie)):
                return _signed_in_page()  # this browser is signed in already
            return self._deny(
                conn,
                "launch: this one-time URL was used already (or belongs to another workbench); "
                "a one-time URL signs in one browser once. Press Enter in the terminal of "
                "biplanar-reg workbench for a new one. If you did not use this one, someone "
                "else did: stop the workbench.",
            )
        if self.access.valid(conn.query_params.get("token")):
            return self._with_cookie(_signed_in_page())  # the token leaves the address bar
        return None

    def _with_cookie(self, response: Response) -> Response:
        response.set_cookie(
            self.access.cookie, self.access.token, httponly=True, samesite="strict", path="/"
        )
        return response


def _url_host(host: str) -> str:
    if is_wildcard(host):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def launcher_html(url: str) -> str:
    """A page that sends the browser on to ``url`` (the browser is opened on this file, so that
    its command line holds no secret)."""
    link = escape(url, quote=True)
    return (
        "<!doctype html><html><head><meta charset='utf-8'><meta name='referrer' "
        "content='no-referrer'><title>biplanar-reg workbench</title>"
        f"<meta http-equiv='refresh' content='0;url={link}'></head><body>"
        f"<script>location.replace({json.dumps(url)});</script>"
        "<p style='font-family:sans-serif;margin:3em'>Opening the workbench&hellip;</p>"
        "</body></html>"
    )
