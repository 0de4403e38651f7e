"""CLI: ``biplanar-reg workbench [--new] CASE_DIR [--port N] [--host H] [--no-browser]``.

``--new`` scaffolds the folder's ``case.toml`` first (:mod:`biplanar_reg.workbench.scaffold`):
from ``--model`` and two or more ``--view NAME=CALIBRATION[,IMAGE]`` when given, otherwise
from a form in the page listing the folder's files; the workbench then opens on the new case.

Serves the workbench of one case folder (:mod:`biplanar_reg.workbench`) with uvicorn in this
process, prints its URL with the launch token (one line starting with ``http://``) and opens
the browser. Ctrl-C or SIGTERM stops it; the case's lock file is removed on the way out.
Exit codes: 2 a bad case folder, 1 the folder is open in another workbench, 130 stopped.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator
from typing import Any

from ._parsing import Wanted, add_command

__all__ = ["register"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _bind(host: str, port: int) -> Any:
    """A listening socket on ``host:port`` (port 0: a free one), before the server starts, so
    that the printed URL has the real port and early requests wait in the backlog."""
    import socket

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ValueError(
            f"--host/--port: cannot listen on {host}:{port} ({exc.strerror})"
        ) from None
    sock.listen(128)
    return sock


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt, like Ctrl-C.

    uvicorn shuts down gracefully on SIGTERM and then re-raises it with the handler it found;
    with the default one the process would die there, before the lock file is removed.
    """

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _serve(app: Any, sock: Any) -> None:
    import uvicorn

    # an open event stream would otherwise hold a graceful shutdown until it ends
    config = uvicorn.Config(app, log_level="warning", lifespan="off", timeout_graceful_shutdown=3)
    with _sigterm_as_interrupt():
        uvicorn.Server(config).run(sockets=[sock])


def _announce(args: argparse.Namespace, port: int, token: str) -> None:
    import webbrowser

    host = f"[{args.host}]" if ":" in args.host else args.host
    url = f"http://{host}:{port}/?token={token}"
    if args.host not in LOOPBACK:
        print(
            f"warning: listening on {args.host}: other machines can connect (each request "
            "still needs the token)",
            file=sys.stderr,
        )
    print(url, flush=True)
    if not args.no_browser:
        webbrowser.open(url)


def _open(wb: Any, token: str, port: int) -> Any:
    """The workbench's app, its caches warming up in the background."""
    import threading

    from ..workbench import create_app

    wb.set_port(port)
    app = create_app(wb, token)
    # tiles and livewire costs are built while the browser loads the page
    threading.Thread(target=wb.warm_up, name="workbench-warm-up", daemon=True).start()
    return app


def _new_case(args: argparse.Namespace) -> bool:
    """``--new``: write ``case.toml`` from the options; False when the form must ask."""
    from pathlib import Path

    from ..workbench.scaffold import parse_view_option, scaffold_case

    folder = Path(args.case_dir)
    if (folder / "case.toml").exists():
        raise ValueError(f"--new: {folder / 'case.toml'} exists already; open it without --new")
    if not folder.is_dir():
        raise ValueError(f"CASE_DIR: {folder}: not a folder (create it and put the files in it)")
    views = [parse_view_option(v) for v in args.view or []]
    if args.model is None or len(views) < 2:
        return False
    scaffold_case(folder, model=args.model, views=views, landmarks=args.landmarks,
                  poses=args.poses)  # fmt: skip
    return True


def _cmd_new_form(args: argparse.Namespace, sock: Any, token: str) -> int:
    """Serve the "new case" form; the workbench replaces it once the case is written."""
    from pathlib import Path

    from ..workbench import Workbench
    from ..workbench.scaffold import Switch, create_new_case_app

    opened: list[Any] = []
    port = sock.getsockname()[1]
    switch = Switch(None)

    def open_case(setup: Any) -> None:
        wb = Workbench(setup.case_dir, port=port)
        opened.append(wb)
        switch.app = _open(wb, token, port)

    switch.app = create_new_case_app(Path(args.case_dir).resolve(), token, open_case)
    _announce(args, port, token)
    try:
        _serve(switch, sock)
    finally:
        for wb in opened:
            wb.close()
    return 0


def _cmd_workbench(args: argparse.Namespace) -> int:
    import secrets

    from ..workbench import Workbench

    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port: expected 0..65535, got {args.port}")
    token = secrets.token_urlsafe(24)
    if args.new and not _new_case(args):
        return _cmd_new_form(args, _bind(args.host, args.port), token)
    wb = Workbench(args.case_dir)
    try:
        sock = _bind(args.host, args.port)
        port = sock.getsockname()[1]
        app = _open(wb, token, port)
        _announce(args, port, token)
        _serve(app, sock)
        return 0
    finally:
        wb.close()


def _build_workbench(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("case_dir", help="case folder holding case.toml")
    p.add_argument("--port", type=int, default=0, help="port (default 0: a free one)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument(
        "--no-browser", action="store_true", help="print the URL only, do not open a browser"
    )
    new = p.add_argument_group("a new case (--new)")
    new.add_argument(
        "--new", action="store_true",
        help="write CASE_DIR/case.toml first: from --model and --view, or in the page",
    )  # fmt: skip
    new.add_argument("--model", help="shape model (.npz) or template mesh, inside CASE_DIR")
    new.add_argument(
        "--view", action="append", metavar="NAME=CALIBRATION[,IMAGE]",
        help="a view's calibration and image files, inside CASE_DIR (twice or more)",
    )  # fmt: skip
    new.add_argument("--landmarks", help="model landmark file (default: beside the model)")
    new.add_argument("--poses", default="known", choices=["known", "unknown", "refine"])
    p.set_defaults(func=_cmd_workbench)


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add ``workbench`` to the ``biplanar-reg`` parser."""
    add_command(
        subparsers,
        "workbench",
        _build_workbench,
        wanted,
        help="annotate, register and review a case in the browser",
        description="Serve a local web page for one case folder: zoomable radiographs, "
        "landmarks, livewire outlines, registration with live progress and its result. Every "
        "edit is saved in the case folder (annotations.json, model/landmarks.json). Prints the "
        "URL with its access token; Ctrl-C stops it.",
    )
