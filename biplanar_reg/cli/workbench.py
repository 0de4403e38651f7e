"""CLI: ``biplanar-reg workbench [--new] CASE_DIR [--port N] [--host H [--allow-remote]]
[--no-browser]``.

``--new`` scaffolds the folder's ``case.toml`` first (:mod:`biplanar_reg.workbench.scaffold`):
from ``--model`` and two or more ``--view NAME=CALIBRATION[,IMAGE]`` when given, otherwise
from a form in the page listing the folder's files; the workbench then opens on the new case.

Serves the workbench of one case folder (:mod:`biplanar_reg.workbench`) with uvicorn in this
process, prints a one-time URL (one line starting with ``http://``: it signs one browser in,
once; the launch token itself is never printed nor put on a command line) and opens the
browser on a file only this user can read, which forwards to another one-time URL (a
browser's command line is visible to every local user in ``ps``). Enter in the terminal
prints a new one-time URL. It listens on 127.0.0.1 unless told otherwise; an address that
other machines can reach needs ``--allow-remote``. Ctrl-C or SIGTERM stops it; the case's lock
file and the browser's file are removed on the way out. Exit codes: 2 a bad case folder or
address or the workbench extra missing (``pip install 'biplanar-reg[workbench]'``), 1 the
folder is open in another workbench, 130 stopped.
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

#: The server stack that ``pip install 'biplanar-reg[workbench]'`` adds; only the workbench
#: imports it, so the rest of the package runs without it.
SERVER_MODULES = ("starlette", "uvicorn")


def _check_extra() -> None:
    """Raise ``ValueError`` (exit 2, one line) naming the install command when the workbench
    extra is missing, before anything of the workbench is imported."""
    import importlib

    missing = []
    for name in SERVER_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise ValueError(
            f"biplanar-reg workbench needs {' and '.join(missing)} (the workbench extra): "
            "pip install 'biplanar-reg[workbench]'"
        )


def _check_host(host: str, allow_remote: bool) -> None:
    """``--host``: this machine only, unless ``--allow-remote`` (ValueError: exit 2)."""
    from ..workbench.access import is_loopback

    if not host.strip():
        raise ValueError(
            "--host: empty; give an address: 127.0.0.1 (this machine only, the default), or "
            "one that other machines reach (0.0.0.0, this machine's address) with --allow-remote"
        )
    if not is_loopback(host) and not allow_remote:
        raise ValueError(
            f"--host {host}: other machines could connect to it, and the workbench speaks plain "
            "HTTP (the images, the annotations and the token unencrypted); prefer an SSH tunnel "
            "(ssh -L 8765:127.0.0.1:8765 THIS_MACHINE, then --port 8765 here), or pass "
            "--allow-remote to listen there anyway"
        )


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


def _base_url(host: str, port: int) -> str:
    """The page's address: 127.0.0.1 (::1) for a server on every interface."""
    from ..workbench.access import is_wildcard

    if is_wildcard(host):
        host = "::1" if ":" in host else "127.0.0.1"
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def _launcher(url: str) -> Any:
    """A page only this user can read (a new 0700 folder, the file 0600) that forwards the
    browser to ``url``: the browser's command line then holds only its path."""
    import os
    import tempfile
    from pathlib import Path

    from ..workbench.access import launcher_html

    folder = Path(tempfile.mkdtemp(prefix="biplanar-wb-"))
    path = folder / "open-workbench.html"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(launcher_html(url))
    return path


def _new_urls_on_enter(access: Any, base: str) -> None:
    """Enter in the terminal prints a new one-time URL (a second browser, a lost cookie)."""
    import threading

    if not sys.stdin or not sys.stdin.isatty():
        return

    def loop() -> None:
        for _ in sys.stdin:
            print(f"{base}/?launch={access.one_time_code()}", flush=True)

    threading.Thread(target=loop, name="workbench-new-url", daemon=True).start()


@contextlib.contextmanager
def _announced(args: argparse.Namespace, port: int, access: Any) -> Iterator[None]:
    """Print the one-time URL, open the browser on its own, remove its file afterwards."""
    import shutil
    import webbrowser

    from ..workbench.access import is_loopback

    base = _base_url(args.host, port)
    if not is_loopback(args.host):
        print(
            f"warning: listening on {args.host} (--allow-remote): other machines can connect, "
            "over plain HTTP; each request still needs the token",
            file=sys.stderr,
        )
    enter = " (press Enter here for a new one)" if sys.stdin and sys.stdin.isatty() else ""
    print(f"biplanar-reg workbench: the URL below signs one browser in, once{enter}",
          file=sys.stderr)  # fmt: skip
    print(f"{base}/?launch={access.one_time_code()}", flush=True)
    launcher = None
    try:
        if not args.no_browser:
            launcher = _launcher(f"{base}/?launch={access.one_time_code()}")
            webbrowser.open(launcher.as_uri())
        _new_urls_on_enter(access, base)
        yield
    finally:
        if launcher is not None:
            shutil.rmtree(launcher.parent, ignore_errors=True)


def _open(wb: Any, access: Any, port: int) -> Any:
    """The workbench's app, its caches warming up in the background."""
    import threading

    from ..workbench import create_app

    wb.set_port(port)
    app = create_app(wb, access)
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


def _cmd_new_form(args: argparse.Namespace, sock: Any, access: Any) -> int:
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
        switch.app = _open(wb, access, port)

    switch.app = create_new_case_app(Path(args.case_dir).resolve(), access, open_case)
    try:
        with _announced(args, port, access):
            _serve(switch, sock)
    finally:
        for wb in opened:
            wb.close()
    return 0


def _cmd_workbench(args: argparse.Namespace) -> int:
    _check_extra()
    from ..workbench import Workbench
    from ..workbench.access import Access

    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port: expected 0..65535, got {args.port}")
    _check_host(args.host, args.allow_remote)
    access = Access(host=args.host)  # the token: never printed, never on a command line
    if args.new and not _new_case(args):
        return _cmd_new_form(args, _bind(args.host, args.port), access)
    wb = Workbench(args.case_dir)
    try:
        sock = _bind(args.host, args.port)
        port = sock.getsockname()[1]
        app = _open(wb, access, port)
        with _announced(args, port, access):
            _serve(app, sock)
        return 0
    finally:
        wb.close()


def _build_workbench(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("case_dir", help="case folder holding case.toml")
    p.add_argument("--port", type=int, default=0, help="port (default 0: a free one)")
    p.add_argument(
        "--host", default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only)",
    )  # fmt: skip
    p.add_argument(
        "--allow-remote", action="store_true",
        help="allow a --host that other machines can reach (plain HTTP: prefer an SSH tunnel)",
    )  # fmt: skip
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
        "edit is saved in the case folder (annotations.json, model/landmarks.json). Prints a "
        "one-time URL (Enter prints another); Ctrl-C stops it.",
    )
