"""The workbench on a shared workstation: what another local page, another port of 127.0.0.1,
another domain resolving to 127.0.0.1 or another user can and cannot do; the launch token
kept off command lines and address bars; stale edits from a second tab refused; bounded
requests (snap radius, GrabCut box). Plain HTTP through Starlette's test client and the real
command in a subprocess; the page's side is in ``test_e2e_security.py``."""

from __future__ import annotations

import json
import os
import re
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from biplanar_reg.cases import CaseError
from biplanar_reg.workbench import Workbench, create_app

TOKEN = "test-token-0123456789"
ROOT = Path(__file__).resolve().parents[2]
BASE = "http://127.0.0.1:8765"  # the address the app believes it is served at
ORIGIN = BASE
OTHER_PORT = "http://127.0.0.1:8888"  # e.g. a notebook or `python -m http.server` there
JSON = {"Content-Type": "application/json"}


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != ".workbench.lock"
    }


@pytest.fixture
def wb(synthetic_case) -> Iterator[Workbench]:
    with Workbench(synthetic_case) as w:
        yield w


def _page_client(wb: Workbench) -> TestClient:
    """A browser that opened the page (it holds the cookie) and sends the header and JSON."""
    c = TestClient(create_app(wb, TOKEN), base_url=BASE)
    assert c.get(f"/?token={TOKEN}").status_code == 200
    assert c.cookies, "the page set no cookie"
    c.headers.update({"X-Workbench-Token": TOKEN, **JSON, "Origin": ORIGIN})
    return c


def _cookie_only(wb: Workbench) -> TestClient:
    """The same browser, as a page of another port sees it: the cookie goes along
    (SameSite ignores the port), but that page cannot read or send the token."""
    c = TestClient(create_app(wb, TOKEN), base_url=BASE)
    assert c.get(f"/?token={TOKEN}").status_code == 200
    return c


def _contours(case: Path, view: str = "cam1") -> list[dict]:
    return json.loads((case / "annotations.json").read_text())["views"][view]["contours"]


# -- cross-site request forgery from another port -------------------------------------------------

POINTS = [[10.0, 10.0], [20.0, 11.0], [30.0, 13.0], [40.0, 16.0]]


def test_cross_port_forms_change_nothing(wb, synthetic_case):
    """A page of 127.0.0.1:8888 posting forms to the workbench (the browser adds the cookie):
    a contour added as text/plain JSON, the registration started, the pose saved, every
    contour erased. All refused; nothing written."""
    c = _cookie_only(wb)
    before = _snapshot(synthetic_case)
    form = {"Origin": OTHER_PORT, "Sec-Fetch-Site": "same-site", "Sec-Fetch-Mode": "navigate"}
    attacks = [
        ("POST", "/api/views/cam1/contours", json.dumps({"uv": POINTS}), "text/plain"),
        ("POST", "/api/register", "", "application/x-www-form-urlencoded"),
        ("POST", "/api/pose-aid/start", "", "application/x-www-form-urlencoded"),
        ("DELETE", "/api/views/cam1/contours/0", "", "text/plain"),
        ("PUT", "/api/views/cam1/landmarks/distal_tip", '{"uv": [5, 5]}', "text/plain"),
    ]
    for method, path, body, ctype in attacks:
        for headers in (form, {}):  # with the browser's headers, and an old browser without
            r = c.request(method, path, content=body, headers={"Content-Type": ctype, **headers})
            assert r.status_code == 403, (method, path, headers, r.text)
            assert "Traceback" not in r.text
    # a same-origin-looking request that still lacks the header (cookie only)
    r = c.post("/api/views/cam1/contours", json={"uv": POINTS}, headers={"Origin": ORIGIN})
    assert r.status_code == 403 and r.json()["error"].startswith("token: ")
    assert "X-Workbench-Token" in r.json()["error"]
    assert _snapshot(synthetic_case) == before
    assert c.get("/api/register").json()["state"] == "idle"


def test_another_origin_is_refused_even_with_the_token(wb, synthetic_case):
    c = _page_client(wb)
    before = _snapshot(synthetic_case)
    for origin in (OTHER_PORT, "http://localhost:8765", "http://evil.example", "null"):
        r = c.post("/api/views/cam1/contours", json={"uv": POINTS}, headers={"Origin": origin})
        assert r.status_code == 403 and r.json()["error"].startswith("origin: "), (origin, r.text)
    for site in ("same-site", "cross-site"):
        r = c.post(
            "/api/views/cam1/contours",
            json={"uv": POINTS},
            headers={"Origin": ORIGIN, "Sec-Fetch-Site": site, "Sec-Fetch-Mode": "cors"},
        )
        assert r.status_code == 403 and r.json()["error"].startswith("sec-fetch-site: "), site
        # reading too: another port's fetch() or <img> of the case's data
        r = c.get("/api/annotations", headers={"Sec-Fetch-Site": site, "Origin": OTHER_PORT})
        assert r.status_code == 403
    assert _snapshot(synthetic_case) == before
    # the page itself: same origin
    r = c.post(
        "/api/views/cam1/contours",
        json={"uv": POINTS},
        headers={"Sec-Fetch-Site": "same-origin", "Sec-Fetch-Mode": "cors"},
    )
    assert r.status_code == 200, r.text
    assert len(_contours(synthetic_case)) == 2


def test_state_changes_need_a_json_body(wb, synthetic_case):
    c = _page_client(wb)
    before = _snapshot(synthetic_case)
    text = json.dumps({"uv": [5, 5]})
    for ctype in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data"):
        r = c.put("/api/views/cam1/landmarks/distal_tip", content=text,
                  headers={"Content-Type": ctype})  # fmt: skip
        assert r.status_code == 415, (ctype, r.text)
        assert r.json()["error"].startswith("content-type: expected application/json")
    r = c.delete("/api/views/cam1/landmarks/distal_tip", headers={"Content-Type": ""})
    assert r.status_code == 415
    assert _snapshot(synthetic_case) == before
    r = c.put("/api/views/cam1/landmarks/distal_tip", content=text,
              headers={"Content-Type": "application/json; charset=utf-8"})  # fmt: skip
    assert r.status_code == 200


def test_reads_still_work_with_the_cookie_alone(wb):
    """The page's tiles (<img>) and event stream cannot send a header: the cookie carries them."""
    c = _cookie_only(wb)
    assert c.get("/api/case", headers={"Sec-Fetch-Site": "same-origin"}).status_code == 200
    assert c.get("/api/views/cam1/tiles/0/0/0.png").status_code == 200
    assert c.get("/static/app.js").status_code == 200


# -- the token off the address bar; one-time URLs --------------------------------------------------


def test_the_token_url_is_exchanged_for_the_cookie_and_leaves_the_address_bar(wb):
    c = TestClient(create_app(wb, TOKEN), base_url=BASE)
    r = c.get(f"/?token={TOKEN}", follow_redirects=False)
    assert r.status_code == 200
    # the answer sets the cookie and replaces itself with the clean URL
    assert "location.replace('/')" in r.text and TOKEN not in r.text
    cookie = r.headers["set-cookie"]
    assert "httponly" in cookie.lower() and "samesite=strict" in cookie.lower()
    assert r.headers["cache-control"] == "no-store"
    page = c.get("/")
    assert page.status_code == 200 and "body" in page.text
    assert f'<meta name="workbench-token" content="{TOKEN}">' in page.text  # for the header
    assert "?token=" not in page.text  # no URL of the page carries it


def test_one_time_url_signs_in_once(synthetic_case):
    from biplanar_reg.workbench.access import Access

    access = Access(TOKEN)
    with Workbench(synthetic_case) as wb:
        app = create_app(wb, access)
        code = access.one_time_code()
        browser = TestClient(app, base_url=BASE)
        r = browser.get(f"/?launch={code}", headers={"Accept": "text/html"})
        assert r.status_code == 200 and "location.replace('/')" in r.text
        assert TOKEN not in r.text and browser.cookies
        assert browser.get("/").status_code == 200
        # the same browser opening the used URL again: still signed in
        assert browser.get(f"/?launch={code}").status_code == 200
        # anyone else with the used URL: refused, with what to do
        thief = TestClient(app, base_url=BASE)
        r = thief.get(f"/?launch={code}", headers={"Accept": "text/html"})
        assert r.status_code == 403 and "used already" in r.text and not thief.cookies
        assert thief.get("/api/annotations").status_code == 403
        assert thief.get(f"/?launch={access.one_time_code()}").status_code == 200  # a new one


# -- host names, DNS rebinding, non-HTTP connections ---------------------------------------------


def test_host_header_must_name_the_workbench(wb):
    """A page of evil.example whose name was re-pointed at 127.0.0.1 (DNS rebinding) reaches
    the port, with its own Host; refused even with the token."""
    app = create_app(wb, TOKEN)
    for base in ("http://evil.example:8765", "http://127.0.0.1.nip.io:8765"):
        c = TestClient(app, base_url=base, headers={"X-Workbench-Token": TOKEN})
        r = c.get("/api/annotations")
        assert r.status_code == 403 and r.json()["error"].startswith("host: "), base
    for base in (BASE, "http://localhost:8765", "http://[::1]:8765", "http://127.0.0.1"):
        c = TestClient(app, base_url=base, headers={"X-Workbench-Token": TOKEN})
        assert c.get("/api/case").status_code == 200, base


def test_host_names_of_other_bind_addresses():
    from biplanar_reg.workbench.access import Access

    anywhere = Access(TOKEN, host="0.0.0.0")
    assert anywhere.host_allowed("192.168.1.20:8765") and anywhere.host_allowed("[::1]:1")
    assert anywhere.host_allowed("localhost:8765")
    assert not anywhere.host_allowed("evil.example:8765")
    one = Access(TOKEN, host="192.168.1.20")
    assert one.host_allowed("192.168.1.20:8765") and not one.host_allowed("127.0.0.1:8765")
    assert Access(TOKEN, host="127.0.0.2").host_allowed("127.0.0.2:8765")
    loop = Access(TOKEN)
    for bad in (None, "", "evil.example", "127.0.0.1.evil.example:80", "[::1"):
        assert not loop.host_allowed(bad), bad


def test_websocket_connections_go_through_the_guard(wb):
    c = TestClient(create_app(wb, TOKEN))
    here, rebound = "ws://127.0.0.1:8765/api/anything", "ws://evil.example:8765/api/anything"
    token = f"?token={TOKEN}"
    refused = [
        (here, {"Origin": ORIGIN}),  # no token
        (rebound + token, {}),  # DNS rebinding
        (here + token, {"Origin": OTHER_PORT}),  # another port's page
    ]
    for url, headers in refused:
        with pytest.raises(WebSocketDisconnect) as info:
            with c.websocket_connect(url, headers=headers):
                pass
        assert info.value.code == 1008, url  # refused before the application saw it
    # with the token: the application's own answer (no such route: closed normally)
    with pytest.raises(WebSocketDisconnect) as info:
        with c.websocket_connect(here + token, headers={"Origin": ORIGIN}):
            pass
    assert info.value.code == 1000


def test_the_peer_socket_owner_is_found_on_linux():
    """The workbench looks up which user owns the other end of a local connection."""
    if not sys.platform.startswith("linux"):
        pytest.skip("Linux only")
    import socket

    from biplanar_reg.workbench.access import peer_uid

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    client = socket.create_connection(server.getsockname())
    conn, addr = server.accept()
    try:
        assert peer_uid(addr, conn.getsockname()) == os.getuid()
        assert peer_uid(("10.1.2.3", 5), conn.getsockname()) is None
        assert peer_uid(("testclient", 50000), ("testserver", 80)) is None
    finally:
        for s in (conn, client, server):
            s.close()


OTHER_USER = """
import encodings.idna, os, socket, sys  # (nothing can be imported once "nobody")
host, port, token = sys.argv[1], int(sys.argv[2]), sys.argv[3]
if sys.argv[4] == "other":
    os.setgid(65534)
    os.setuid(65534)  # nobody
s = socket.create_connection((host, port))
s.sendall(f"GET /api/annotations HTTP/1.1\\r\\nHost: {host}:{port}\\r\\n"
          f"X-Workbench-Token: {token}\\r\\nConnection: close\\r\\n\\r\\n".encode())
data = b""
while chunk := s.recv(65536):
    data += chunk
print(data.decode(errors="replace"))
"""


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.geteuid() != 0,
    reason="needs Linux and root (to act as another user)",
)
def test_another_users_program_is_refused_even_with_the_token(synthetic_case):
    """The token leaked (say, the cookie sent to another user's server on another port):
    that user's program still gets nothing."""
    server = _Server([str(synthetic_case), "--no-browser"])
    try:
        base = server.url.split("/?", 1)[0]
        with httpx.Client() as browser:
            assert browser.get(server.url, timeout=30).status_code == 200
            token = _token_of(base, browser)
        port = base.rsplit(":", 1)[1]
        answers = {}
        for who in ("other", "same"):
            r = subprocess.run(
                [sys.executable, "-c", OTHER_USER, "127.0.0.1", port, token, who],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            answers[who] = r.stdout
        assert answers["other"].startswith("HTTP/1.1 403"), answers["other"]
        assert '"error":"peer: ' in answers["other"] and "cam1" not in answers["other"]
        assert answers["same"].startswith("HTTP/1.1 200"), answers["same"]
        assert "another user's program" in "".join(server.errors)  # logged on the server's side
    finally:
        server.stop()


# -- stale edits from a second tab -----------------------------------------------------------------


def _view(c: TestClient, view: str = "cam1") -> dict:
    return c.get("/api/annotations").json()["views"][view]


def test_contours_carry_an_id_and_a_version(wb, synthetic_case):
    c = _page_client(wb)
    first = _view(c)["contours"][0]
    assert isinstance(first["id"], str) and isinstance(first["version"], int)
    r = c.post("/api/views/cam1/contours", json={"uv": POINTS})
    added = r.json()["view"]["contours"][1]
    assert added["id"] != first["id"]
    # an unrelated edit keeps both
    c.put("/api/views/cam1/landmarks/distal_tip", json={"uv": [5, 5]})
    assert [(k["id"], k["version"]) for k in _view(c)["contours"]] == [
        (first["id"], first["version"]),
        (added["id"], added["version"]),
    ]
    # a change keeps the id with a new version
    r = c.put(f"/api/views/cam1/contours/{added['id']}?version={added['version']}",
              json={"uv": POINTS[::-1]})  # fmt: skip
    assert r.status_code == 200, r.text
    changed = r.json()["view"]["contours"][1]
    assert changed["id"] == added["id"] and changed["version"] != added["version"]
    # the file keeps its format: no ids, no versions
    assert all(set(k) == {"uv", "closed"} for k in _contours(synthetic_case))
    # an edit outside the workbench: the untouched contour keeps its id, the new file is re-read
    doc = json.loads((synthetic_case / "annotations.json").read_text())
    doc["views"]["cam1"]["contours"][1]["uv"] = POINTS
    time.sleep(0.01)
    (synthetic_case / "annotations.json").write_text(json.dumps(doc))
    now = _view(c)["contours"]
    assert now[0]["id"] == first["id"] and now[0]["version"] == first["version"]
    assert (now[1]["id"], now[1]["version"]) != (changed["id"], changed["version"])


def test_a_stale_tab_cannot_remove_or_overwrite_another_contour(wb, synthetic_case):
    """Two tabs show contours A (0) and B (1); tab 2 removes A; tab 1, not reloaded, then
    removes "contour 0" (A for it) and overwrites it: both 409, B untouched."""
    tab1, tab2 = _page_client(wb), _page_client(wb)
    tab1.post("/api/views/cam1/contours", json={"uv": POINTS})
    a, b = _view(tab1)["contours"]
    assert tab2.delete(f"/api/views/cam1/contours/{a['id']}?version={a['version']}").status_code \
        == 200  # fmt: skip
    before = _snapshot(synthetic_case)
    stale = [
        tab1.delete(f"/api/views/cam1/contours/{a['id']}?version={a['version']}"),
        tab1.put(f"/api/views/cam1/contours/{a['id']}?version={a['version']}",
                 json={"uv": POINTS}),
        tab1.delete(f"/api/views/cam1/contours/0?version={a['version']}"),  # by index
        tab1.put(f"/api/views/cam1/contours/0?version={a['version']}", json={"uv": POINTS}),
        tab1.post(f"/api/views/cam1/contours/{a['id']}/erase?version={a['version']}",
                  json={"from": [10, 10], "to": [20, 11]}),
        tab1.put(f"/api/views/cam1/contours/{a['id']}/anchors?version={a['version']}",
                 json={"anchors": [[10, 10], [40, 16]]}),
    ]  # fmt: skip
    for r in stale:
        assert r.status_code == 409, r.text
        assert "reload" in r.json()["error"] and "\n" not in r.json()["error"]
    assert _snapshot(synthetic_case) == before
    assert _contours(synthetic_case) == [{"uv": b["uv"], "closed": b["closed"]}]
    # B changed by tab 2, then tab 1 edits B at its old version: refused too
    r = tab2.put(f"/api/views/cam1/contours/{b['id']}?version={b['version']}",
                 json={"uv": POINTS[::-1]})  # fmt: skip
    assert r.status_code == 200
    r = tab1.delete(f"/api/views/cam1/contours/{b['id']}?version={b['version']}")
    assert r.status_code == 409 and "changed" in r.json()["error"]
    assert len(_contours(synthetic_case)) == 1
    # an edit by index without a version is refused: it could hit another contour
    r = tab1.delete("/api/views/cam1/contours/0")
    assert r.status_code == 400 and r.json()["error"].startswith("version: ")
    assert len(_contours(synthetic_case)) == 1


# -- bounded requests ------------------------------------------------------------------------------


def test_snap_radius_is_bounded(wrist_case):
    with Workbench(wrist_case) as wb:
        c = _page_client(wb)
        r = c.post("/api/views/cam01/snap", json={"uv": [916, 1640], "radius_px": 1000})
        assert r.status_code == 400, r.text
        msg = r.json()["error"]
        assert msg.startswith("radius_px: ") and "50" in msg and "\n" not in msg
        ok = c.post("/api/views/cam01/snap", json={"uv": [916, 1640], "radius_px": 50})
        assert ok.status_code == 200 and ok.json()["shift_px"] <= 50
        # a click a few pixels from the image's edge (the corner window used to overflow)
        for uv in ([2, 900], [1757, 900], [900, 1]):
            r = c.post("/api/views/cam01/snap", json={"uv": uv})
            assert r.status_code == 200, (uv, r.text)
            assert r.json()["shift_px"] <= 5


def test_grabcut_box_is_bounded(wb, synthetic_case):
    c = _page_client(wb)
    before = _snapshot(synthetic_case)
    r = c.post("/api/views/cam1/grabcut", json={"box": [0, 0, 511, 511]})  # the whole image
    assert r.status_code == 400, r.text
    msg = r.json()["error"]
    assert msg.startswith("box: ") and "background" in msg and "\n" not in msg
    assert _snapshot(synthetic_case) == before


def test_grabcut_box_area_is_bounded(wrist_case):
    with Workbench(wrist_case) as wb:
        c = _page_client(wb)
        r = c.post("/api/views/cam01/grabcut", json={"box": [300, 300, 1300, 1300]})
        assert r.status_code == 400, r.text
        msg = r.json()["error"]
        assert msg.startswith("box: ") and "640000" in msg and "\n" not in msg


# -- messages ------------------------------------------------------------------------------------


def test_a_file_outside_the_case_is_refused_without_a_missing_option(synthetic_case, tmp_path):
    outside = tmp_path / "elsewhere.png"
    outside.write_bytes((synthetic_case / "xray" / "cam2.png").read_bytes())
    toml = synthetic_case / "case.toml"
    toml.write_text(toml.read_text().replace('"xray/cam2.png"', '"../elsewhere.png"'))
    with pytest.raises(CaseError) as info:
        Workbench(synthetic_case)
    msg = str(info.value)
    assert "outside the case folder" in msg and "--allow-outside" not in msg
    assert "into the case folder" in msg
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "biplanar_reg.cli", "workbench", str(synthetic_case)]
    r = subprocess.run([*cmd, "--no-browser"], capture_output=True, text=True, env=env,
                       timeout=120)  # fmt: skip
    assert r.returncode == 2 and "--allow-outside" not in r.stderr, r.stderr
    assert "outside the case folder" in r.stderr


# -- the command: addresses, the printed URL, the browser's command line -----------------------


def _run(args: list[str], **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), **kwargs.pop("env", {})}
    cmd = [sys.executable, "-m", "biplanar_reg.cli", "workbench", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120, **kwargs)


@pytest.mark.parametrize(
    "host, expected",
    [("0.0.0.0", "--allow-remote"), ("::", "--allow-remote"), ("", "--host: empty")],
)
def test_listening_beyond_this_machine_needs_a_flag(synthetic_case, host, expected):
    r = _run([str(synthetic_case), "--no-browser", "--host", host])
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert expected in r.stderr and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (synthetic_case / ".workbench.lock").exists()


class _Server:
    """``biplanar-reg workbench CASE`` running; ``lines`` its stdout, ``errors`` its stderr."""

    def __init__(self, args: list[str], env: dict | None = None):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "biplanar_reg.cli", "workbench", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})},
            cwd=ROOT,
        )
        self.lines: list[str] = []
        self.errors: list[str] = []
        threading.Thread(target=lambda: self.errors.extend(self.proc.stderr), daemon=True).start()
        self.url = self.proc.stdout.readline().strip()
        threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True).start()

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def _token_of(base: str, client: httpx.Client) -> str:
    page = client.get(f"{base}/", timeout=30)
    assert page.status_code == 200, page.text
    return re.search(r'name="workbench-token" content="([^"]+)"', page.text).group(1)


def test_the_printed_url_works_once_and_is_not_the_token(synthetic_case):
    server = _Server([str(synthetic_case), "--no-browser"])
    try:
        url = server.url
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/\?launch=[A-Za-z0-9_-]{20,}", url), url
        base = url.split("/?", 1)[0]
        with httpx.Client() as browser:
            r = browser.get(url, timeout=30)
            assert r.status_code == 200 and "location.replace('/')" in r.text
            token = _token_of(base, browser)
            assert token not in url and token not in "".join(server.errors)
            r = browser.put(f"{base}/api/views/cam1/landmarks/distal_tip", json={"uv": [5, 5]},
                            headers={"X-Workbench-Token": token, "Origin": base})  # fmt: skip
            assert r.status_code == 200, r.text
        with httpx.Client() as other:
            assert other.get(url, timeout=30).status_code == 403  # used
            assert other.get(f"{base}/api/annotations", timeout=30).status_code == 403
        # the server's own command line holds neither
        cmdline = Path(f"/proc/{server.proc.pid}/cmdline").read_bytes().decode()
        assert token not in cmdline and url.split("=")[-1] not in cmdline
    finally:
        server.stop()
    assert server.lines == []  # exactly one line on stdout


FAKE_BROWSER = """
import json, sys
with open(sys.argv[1], "a") as f:
    f.write(json.dumps(sys.argv[2:]) + "\\n")
"""


def test_the_browser_is_opened_without_a_secret_on_its_command_line(synthetic_case, tmp_path):
    """webbrowser.open runs the browser with the URL as an argument, which every local user
    sees in `ps`: it gets a file only this user can read, which forwards to a one-time URL."""
    record = tmp_path / "argv.jsonl"
    fake = tmp_path / "fake_browser.py"
    fake.write_text(FAKE_BROWSER)
    browser = f"{sys.executable} {fake} {record} %s"
    server = _Server([str(synthetic_case)], env={"BROWSER": browser})
    try:
        t0 = time.time()
        while not record.exists() and time.time() - t0 < 60:
            time.sleep(0.1)
        argv = json.loads(record.read_text().splitlines()[0])
        base = server.url.split("/?", 1)[0]
        with httpx.Client() as client:
            token = _token_of(base, client) if client.get(server.url).status_code == 200 else ""
        assert token and all(token not in a for a in argv)
        assert all("launch=" not in a and "token=" not in a for a in argv), argv
        assert len(argv) == 1 and argv[0].startswith("file://"), argv
        launcher = Path(argv[0][len("file://") :])
        assert stat.S_IMODE(launcher.stat().st_mode) == 0o600
        assert stat.S_IMODE(launcher.parent.stat().st_mode) == 0o700
        code = re.search(r"launch=([A-Za-z0-9_-]+)", launcher.read_text()).group(1)
        assert code not in server.url  # its own one-time code
        with httpx.Client() as client:
            assert client.get(f"{base}/?launch={code}").status_code == 200
            assert client.get(f"{base}/api/case").status_code == 200  # signed in
        with httpx.Client() as client:
            assert client.get(f"{base}/?launch={code}").status_code == 403  # once
    finally:
        server.stop()
    assert not launcher.exists() and not launcher.parent.exists()  # removed on the way out
