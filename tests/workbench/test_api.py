"""The workbench's HTTP API through Starlette's ASGI test client: the token, every endpoint,
bad input (4xx naming the field, nothing written), tiles, livewire and snapping on the real
wrist radiograph, the registration job with its events, and the CLI as a real server."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from _http import BASE, page_client
from starlette.testclient import TestClient

from biplanar_reg.annotation import load_image
from biplanar_reg.cases import load_case
from biplanar_reg.workbench import Workbench, create_app

TOKEN = "test-token-0123456789"
ROOT = Path(__file__).resolve().parents[2]


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    """``{relative path: (mtime_ns, content)}`` of every file of a folder."""
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _client(wb: Workbench, **kwargs) -> TestClient:
    return page_client(create_app(wb, TOKEN), TOKEN, **kwargs)


@pytest.fixture
def synthetic(synthetic_case) -> Iterator[tuple[TestClient, Path]]:
    with Workbench(synthetic_case) as wb:
        yield _client(wb), synthetic_case


@pytest.fixture
def wrist(wrist_case) -> Iterator[tuple[TestClient, Workbench]]:
    with Workbench(wrist_case) as wb:
        yield _client(wb), wb


# -- the token ------------------------------------------------------------------------------------


def test_every_request_needs_the_token(synthetic_case):
    with Workbench(synthetic_case) as wb:
        anonymous = TestClient(create_app(wb, TOKEN), base_url=BASE)
        for path in ("/", "/api/case", "/static/index.html", "/api/views/cam1/tiles/0/0/0.png"):
            r = anonymous.get(path)
            assert r.status_code == 403 and "token" in r.json()["error"], path
        r = anonymous.put("/api/views/cam1/landmarks/distal_tip", json={"uv": [1, 1]})
        assert r.status_code == 403
        # a browser asking for the page gets a page that says what to do, not raw JSON
        r = anonymous.get("/", headers={"Accept": "text/html,*/*"})
        assert r.status_code == 403 and r.headers["content-type"].startswith("text/html")
        assert "Access denied" in r.text and "token" in r.text
        r = anonymous.get("/api/case", headers={"Accept": "text/html"})
        assert r.status_code == 403 and "token" in r.json()["error"]  # the API stays JSON
        assert anonymous.get("/api/case?token=wrong").status_code == 403
        assert anonymous.get("/api/case", headers={"X-Workbench-Token": "x"}).status_code == 403
        assert anonymous.get("/api/case?token=é").status_code == 403  # not ASCII: no crash
        access = anonymous.app.state.access
        anonymous.cookies.set(access.cookie, "wrong")
        assert anonymous.get("/api/case").status_code == 403
        anonymous.cookies.clear()

        assert anonymous.get(f"/api/case?token={TOKEN}").status_code == 200
        assert anonymous.get("/api/case", headers={"X-Workbench-Token": TOKEN}).status_code == 200
        # the page's URL with the token: the cookie, then the clean URL
        signin = anonymous.get(f"/?token={TOKEN}")
        assert signin.status_code == 200 and signin.headers["cache-control"] == "no-store"
        cookie = signin.headers["set-cookie"]
        assert cookie.startswith(f"{access.cookie}={TOKEN}")
        assert "HttpOnly" in cookie and "samesite=strict" in cookie.lower()
        assert "location.replace('/')" in signin.text and TOKEN not in signin.text
        assert signin.headers["referrer-policy"] == "no-referrer"
        # from now on the cookie alone is enough to read; the page carries the token for its
        # scripts, which send it in a header
        page = anonymous.get("/")
        assert page.status_code == 200 and page.headers["cache-control"] == "no-store"
        assert 'src="static/app.js"' in page.text
        assert f'<meta name="workbench-token" content="{TOKEN}">' in page.text
        assert anonymous.get("/api/case").status_code == 200
        assert anonymous.get("/static/index.html").status_code == 200
    assert not (synthetic_case / ".workbench.lock").exists()


def test_case_endpoint(wrist):
    client, _ = wrist
    case = client.get("/api/case").json()
    assert case["id"] == "wrist_radius"
    assert case["landmark_names"] == [
        "radial_styloid_tip",
        "ulnar_notch_dorsal",
        "ulnar_notch_volar",
        "listers_tubercle",
    ]
    assert (case["poses"], case["silhouettes"]) == ("known", True)
    assert [v["name"] for v in case["views"]] == ["cam01", "cam02"]
    for v in case["views"]:
        assert (v["width"], v["height"], v["has_image"]) == (1760, 1760, True)
        assert v["tile_size"] == 256 and v["levels"] == 4  # 1760 / 8 = 220 px fits one tile
        lo, hi = v["window"]
        assert v["range"][0] <= lo < hi <= v["range"][1]


# -- tiles ----------------------------------------------------------------------------------------


def _png(r: httpx.Response) -> np.ndarray:
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    assert r.headers["cache-control"] == "private, max-age=3600"
    img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint8 and img.ndim == 2  # grey 8 bit
    return img


def test_tiles_sizes_levels_and_window(wrist, wrist_case):
    client, _ = wrist
    pixels = load_image(wrist_case / "data" / "cam01_frame0099.tif").pixels
    for level in range(4):
        size = math.ceil(1760 / 2**level)
        n = math.ceil(size / 256)
        for tx in range(n):
            tile = _png(client.get(f"/api/views/cam01/tiles/{level}/{tx}/{n - 1}.png"))
            assert tile.shape == (size - 256 * (n - 1), min(256, size - 256 * tx))
        assert client.get(f"/api/views/cam01/tiles/{level}/{n}/0.png").status_code == 404
    assert client.get("/api/views/cam01/tiles/4/0/0.png").status_code == 404
    # level 0: raw values mapped linearly from [lo, hi] to [0, 255]
    lo, hi = 40.0, 200.0
    tile = _png(client.get(f"/api/views/cam01/tiles/0/3/5.png?lo={lo}&hi={hi}"))
    raw = pixels[5 * 256 : 6 * 256, 3 * 256 : 4 * 256]
    want = np.round(np.clip((raw - lo) * 255.0 / (hi - lo), 0, 255))
    np.testing.assert_array_equal(tile, want)
    # the default window is the view's
    v = client.get("/api/case").json()["views"][0]
    default = _png(client.get("/api/views/cam01/tiles/0/3/5.png"))
    explicit = client.get(
        f"/api/views/cam01/tiles/0/3/5.png?lo={v['window'][0]}&hi={v['window'][1]}"
    )
    np.testing.assert_array_equal(default, _png(explicit))
    # the coarsest level is the area mean of the image
    top = _png(client.get("/api/views/cam01/tiles/3/0/0.png?lo=0&hi=255")).astype(float)
    means = pixels.reshape(220, 8, 220, 8).mean(axis=(1, 3))
    assert np.abs(top - means).max() <= 1.0
    for query, field in (("lo=5&hi=1", "hi"), ("lo=abc", "lo"), ("lo=nan&hi=3", "lo")):
        r = client.get(f"/api/views/cam01/tiles/0/0/0.png?{query}")
        assert r.status_code == 400 and r.json()["error"].startswith(f"{field}: "), query
    assert client.get("/api/views/cam9/tiles/0/0/0.png").status_code == 404


def test_tiles_of_a_png_case_and_a_view_without_image(synthetic_case):
    with Workbench(synthetic_case) as wb:
        client = _client(wb)
        assert _png(client.get("/api/views/cam2/tiles/0/1/1.png")).shape == (256, 256)
        assert [v["levels"] for v in client.get("/api/case").json()["views"]] == [2, 2]
    toml = synthetic_case / "case.toml"
    toml.write_text(toml.read_text().replace('image = "xray/cam2.png"\n', ""))
    with Workbench(synthetic_case) as wb:
        client = _client(wb)
        cam2 = client.get("/api/case").json()["views"][1]
        assert cam2["has_image"] is False and cam2["levels"] == 0
        assert (cam2["width"], cam2["height"]) == (512, 512)  # from the calibration
        r = client.get("/api/views/cam2/tiles/0/0/0.png")
        assert r.status_code == 404 and "has no image" in r.json()["error"]
        r = client.post("/api/views/cam2/livewire", json={"anchors": [[1, 1], [9, 9]]})
        assert r.status_code == 404
        r = client.put("/api/views/cam2/landmarks/distal_tip", json={"uv": [10, 10]})
        assert r.status_code == 200  # landmarks need no image


# -- path escapes ---------------------------------------------------------------------------------


def test_paths_cannot_leave_the_case_or_the_static_folder(synthetic):
    client, _ = synthetic
    for path in (
        "/static/../session.py",
        "/static/%2e%2e/session.py",
        "/static/..%2Fsession.py",
        "/static/%2e%2e/%2e%2e/cli/workbench.py",
        "/api/views/..%2F..%2Fcase/tiles/0/0/0.png",
        "/api/views/%2e%2e/tiles/0/0/0.png",
    ):
        r = client.get(path)
        assert r.status_code == 404, (path, r.status_code)
        assert "error" in r.json()
        assert "import" not in r.text


# -- annotation edits -----------------------------------------------------------------------------


def test_landmark_and_contour_edits(synthetic):
    client, case_dir = synthetic
    ann_file = case_dir / "annotations.json"
    r = client.put("/api/views/cam1/landmarks/distal_tip", json={"uv": [100.5, 200.25]})
    assert r.status_code == 200
    assert r.json()["landmarks"]["distal_tip"] == {"uv": [100.5, 200.25], "sigma_px": 1.0}
    r = client.put("/api/views/cam1/landmarks/distal_tip", json={"uv": [101, 201], "sigma_px": 3})
    assert r.json()["landmarks"]["distal_tip"] == {"uv": [101.0, 201.0], "sigma_px": 3.0}
    assert client.delete("/api/views/cam2/landmarks/distal_tip").status_code == 200
    assert client.delete("/api/views/cam2/landmarks/distal_tip").status_code == 404

    pts = [[10.0, 10.0], [20.0, 11.0], [30.0, 13.0], [40.0, 16.0]]
    r = client.post("/api/views/cam2/contours", json={"uv": pts, "anchors": [[10, 10], [40, 16]]})
    assert r.status_code == 200
    i = r.json()["index"]
    added = r.json()["view"]["contours"][i]
    assert isinstance(added.pop("id"), str) and isinstance(added.pop("version"), int)
    assert added == {"uv": pts, "closed": False, "anchors": [[10, 10], [40, 16]]}
    # edits name the contour by its id (or index) and the version the client saw
    c = r.json()["view"]["contours"][i]
    r = client.put(f"/api/views/cam2/contours/{c['id']}?version={c['version']}",
                   json={"uv": pts[::-1], "closed": True})  # fmt: skip
    assert r.status_code == 200 and r.json()["view"]["contours"][i]["closed"] is True
    assert r.json()["index"] == i and r.json()["view"]["contours"][i]["id"] == c["id"]
    n = len(r.json()["view"]["contours"])
    first = r.json()["view"]["contours"][0]
    r = client.delete(f"/api/views/cam2/contours/0?version={first['version']}")
    assert r.status_code == 200 and len(r.json()["view"]["contours"]) == n - 1

    saved = json.loads(ann_file.read_text())
    assert saved["format"] == "biplanar-reg/annotations@1"
    assert saved["views"]["cam1"]["landmarks"]["distal_tip"] == {
        "uv": [101.0, 201.0],
        "sigma_px": 3.0,
    }
    assert saved["views"]["cam2"]["contours"][i - 1] == {"uv": pts[::-1], "closed": True}
    assert "anchors" not in json.dumps(saved)  # the anchors live in .workbench.json
    doc = client.get("/api/annotations").json()
    assert doc["format"] == "biplanar-reg/annotations@1"
    assert doc["views"]["cam1"]["landmarks"]["distal_tip"]["uv"] == [101.0, 201.0]
    case = load_case(case_dir)  # `biplanar-reg register` reads the edited case
    assert "distal_tip" not in case.annotations.views["cam2"].landmarks
    assert case.annotations.views["cam2"].contours[i - 1].closed


def test_model_landmark_edits(synthetic):
    client, case_dir = synthetic
    r = client.put("/api/model/landmarks/styloid", json={"vertex": 7})
    assert r.status_code == 200 and r.json()["landmarks"]["styloid"] == 7
    assert json.loads((case_dir / "model" / "landmarks.json").read_text())["styloid"] == 7
    assert "styloid" in client.get("/api/case").json()["landmark_names"]
    assert client.put("/api/views/cam1/landmarks/styloid", json={"uv": [5, 5]}).status_code == 200
    assert client.delete("/api/model/landmarks/styloid").status_code == 409
    assert client.delete("/api/views/cam1/landmarks/styloid").status_code == 200
    assert client.delete("/api/model/landmarks/styloid").status_code == 200
    assert client.delete("/api/model/landmarks/styloid").status_code == 404


BAD_REQUESTS = [
    ("PUT", "/api/views/cam1/landmarks/distal_tip", b"{", 400, "body: not valid JSON"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", b'{"uv": [1, 1], "uv": [2, 2]}', 400,
     "body: not valid JSON"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", b"[1, 2]", 400, "body: expected a JSON object"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", b'{"uv": [NaN, 1]}', 400, "body: not valid"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", {}, 400, "uv: missing"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", {"uv": [1]}, 400, "uv: expected [u, v]"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", {"uv": [1e9, 1]}, 400, "uv: point"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", {"uv": [1, True]}, 400, "uv: expected"),
    ("PUT", "/api/views/cam1/landmarks/distal_tip", {"uv": [1, 1], "sigma_px": 0}, 400,
     "sigma_px: "),
    ("PUT", "/api/views/cam1/landmarks/nosuch", {"uv": [1, 1]}, 400, "name: unknown landmark"),
    ("PUT", "/api/views/cam9/landmarks/distal_tip", {"uv": [1, 1]}, 404, "view: unknown view"),
    ("POST", "/api/views/cam1/contours", {"uv": [[1, 1], [2, 2]]}, 400, "uv: has 2 point"),
    ("POST", "/api/views/cam1/contours", {"uv": "abc"}, 400, "uv: expected a list"),
    ("POST", "/api/views/cam1/contours", {"uv": [[1, 1], [2, 2], [3, -7]]}, 400, "uv[2]: point"),
    ("POST", "/api/views/cam1/contours", {"uv": [[1, 1], [2, 2], [3, 3]], "closed": 1}, 400,
     "closed: "),
    ("POST", "/api/views/cam1/contours", {"uv": [[1, 1], [2, 2], [3, 3]], "anchors": [[1, 1]]},
     400, "anchors: has 1 point"),
    ("PUT", "/api/views/cam1/contours/50?version=1", {"uv": [[1, 1], [2, 2], [3, 3]]}, 404,
     "views.cam1.contours[50]: no such contour"),
    ("PUT", "/api/views/cam1/contours/0?version=1", {"uv": [[1, 1], [2, 2], ["a", 3]]}, 400,
     "uv[2]: "),
    ("PUT", "/api/views/cam1/contours/0", {"uv": [[1, 1], [2, 2], [3, 3]]}, 400,
     "version: missing"),
    ("PUT", "/api/views/cam1/contours/0?version=x", {"uv": [[1, 1], [2, 2], [3, 3]]}, 400,
     "version: expected a whole number"),
    ("PUT", "/api/views/cam1/contours/0?version=99999", {"uv": [[1, 1], [2, 2], [3, 3]]}, 409,
     "views.cam1.contours[0]: changed since version 99999"),
    ("DELETE", "/api/views/cam1/contours/nosuch-7?version=1", None, 409,
     "views.cam1.contours[id nosuch-7]: no longer exists"),
    ("DELETE", "/api/views/cam1/contours/50?version=1", None, 404, "views.cam1.contours[50]"),
    ("POST", "/api/views/cam1/livewire", {"anchors": [[1, 1]]}, 400, "anchors: has 1 point"),
    ("POST", "/api/views/cam1/livewire", {"anchors": [[1, 1], [9, 9]], "closed": True}, 400,
     "anchors: has 2 point"),
    ("POST", "/api/views/cam1/snap", {"uv": [1, 1], "radius_px": -2}, 400, "radius_px: "),
    ("POST", "/api/views/cam1/snap", {"uv": None}, 400, "uv: missing"),
    ("PUT", "/api/model/landmarks/x", {"vertex": -1}, 400, "vertex: expected a vertex index"),
    ("PUT", "/api/model/landmarks/x", {"vertex": 1.5}, 400, "vertex: "),
    ("GET", "/api/nothing", None, 404, "/api/nothing: Not Found"),
    ("PATCH", "/api/views/cam1/landmarks/distal_tip", {"uv": [1, 1]}, 405, "Method Not Allowed"),
]  # fmt: skip


@pytest.mark.parametrize("method, path, body, status, message", BAD_REQUESTS)
def test_bad_requests_name_the_field_and_write_nothing(
    synthetic, method, path, body, status, message
):
    client, case_dir = synthetic
    before = _snapshot(case_dir)
    kwargs = (
        {"content": body} if isinstance(body, bytes) else {} if body is None else {"json": body}
    )
    r = client.request(method, path, **kwargs)
    assert r.status_code == status, r.text
    assert r.json()["error"].startswith(message) or message in r.json()["error"], r.json()
    assert "Traceback" not in r.text
    assert _snapshot(case_dir) == before


def test_a_too_large_body_is_refused(synthetic):
    client, case_dir = synthetic
    before = _snapshot(case_dir)
    r = client.post("/api/views/cam1/contours", content=b" " * (9 * 1024 * 1024))
    assert r.status_code == 413 and r.json()["error"].startswith("body: larger than")
    assert _snapshot(case_dir) == before


def test_an_internal_error_is_one_line_without_traceback(synthetic_case, monkeypatch):
    with Workbench(synthetic_case) as wb:

        def broken():
            raise RuntimeError("something\nbroke")

        monkeypatch.setattr(wb, "case_info", broken)
        r = _client(wb).get("/api/case")
        assert r.status_code == 500
        assert r.json() == {"error": "internal error: RuntimeError: something broke"}


# -- livewire and snapping on the real radiograph ------------------------------------------------


def test_livewire_and_snap_on_the_wrist_radiograph(wrist):
    client, wb = wrist
    anchors = [[916, 1640], [913, 1580]]  # the radius' lateral cortex (docs/annotation.md)
    first = client.post("/api/views/cam01/livewire", json={"anchors": anchors})
    assert first.status_code == 200
    path = np.array(first.json()["uv"])
    assert len(path) >= 55 and path.shape[1] == 2
    assert np.abs(path[:, 0] - 914).max() < 12 and path[:, 1].min() > 1570
    # previews between nearby anchors once the cost image is cached (printed, not asserted)
    times, walls = [], []
    for k in range(10):
        t0 = time.perf_counter()
        r = client.post(
            "/api/views/cam01/livewire", json={"anchors": [[916, 1640], [913 - k % 3, 1580]]}
        )
        walls.append(time.perf_counter() - t0)
        times.append(r.json()["seconds"])
    print(
        f"\nlivewire preview on the 1760 px wrist image: first call {first.json()['seconds']:.3f}"
        f" s (edge cost computed), then median {np.median(times):.3f} s server, "
        f"{np.median(walls):.3f} s round trip (max {max(walls):.3f} s)"
    )
    closed = client.post(
        "/api/views/cam01/livewire",
        json={"anchors": [[850, 1300], [950, 1300], [900, 1400]], "closed": True},
    )
    assert closed.status_code == 200 and len(closed.json()["uv"]) > 100
    r = client.post("/api/views/cam01/snap", json={"uv": [916, 1640]})
    assert r.status_code == 200
    snap = r.json()
    assert snap["clicked"] == [916.0, 1640.0] and snap["mode"] == "corner"
    assert 0 < snap["shift_px"] <= 5 and snap["strength"] > 0
    edge = client.post("/api/views/cam01/snap", json={"uv": [916, 1600], "mode": "edge"}).json()
    assert edge["mode"] == "edge" and edge["shift_px"] <= 5


# -- the registration -----------------------------------------------------------------------------


def _wait_done(client: TestClient, timeout: float = 300) -> dict:
    t0 = time.time()
    while time.time() - t0 < timeout:
        status = client.get("/api/register").json()
        if status["state"] in ("done", "failed"):
            return status
        time.sleep(0.1)
    raise AssertionError("the registration did not finish")


def _events(text: str) -> list[tuple[str | None, str]]:
    """``(event, data)`` of each Server-Sent Event of a stream."""
    out = []
    for block in text.strip().split("\n\n"):
        lines = [line for line in block.split("\n") if not line.startswith(":")]
        if not lines:
            continue
        event = next((x[7:] for x in lines if x.startswith("event: ")), None)
        data = "\n".join(x[6:] for x in lines if x.startswith("data: "))
        out.append((event, data))
    return out


def test_registration_job_result_and_events(synthetic):
    client, case_dir = synthetic
    assert client.get("/api/register").json()["state"] == "idle"
    assert _events(client.get("/api/register/events").text)[-1][0] == "idle"
    r = client.get("/api/result")
    assert r.status_code == 404 and r.json()["error"].startswith("result: no registration")

    assert client.post("/api/register").json()["state"] == "running"
    again = client.post("/api/register")
    assert again.status_code == 409 and "already running" in again.json()["error"]
    # the stream follows the running job to its end
    stream = client.get("/api/register/events")
    assert stream.headers["content-type"].startswith("text/event-stream")
    events = _events(stream.text)
    status = _wait_done(client)
    assert status["state"] == "done", status
    assert events[-1][0] == "done"
    progress = [d for e, d in events if e is None]
    assert progress == status["messages"] and len(progress) >= 4
    assert progress[0] == "loading the case" and progress[-1].startswith("done in")
    assert any(m.startswith("writing registered.ply") for m in progress)
    assert status["result"]["metrics"]["landmark_rms_px"] < 2
    assert json.loads(events[-1][1])["state"] == "done"

    doc = json.loads((case_dir / "out" / "result.json").read_text())
    assert doc["format"] == "biplanar-reg/result@2"
    assert (case_dir / "out" / "registered.ply").is_file()
    result = client.get("/api/result").json()
    assert set(result["views"]) == {"cam1", "cam2"}
    landmarks = json.loads((case_dir / "model" / "landmarks.json").read_text())
    annotated = load_case(case_dir).annotations
    for name, view in result["views"].items():
        lines = view["outline_px"]
        assert lines and all(len(line) >= 3 and len(line[0]) == 2 for line in lines)
        assert set(view["landmarks_px"]) == set(landmarks)
        # the registered landmarks fall near the clicked ones (a good synthetic registration)
        for lm, clicked in annotated.views[name].landmarks.items():
            assert np.linalg.norm(np.subtract(view["landmarks_px"][lm], clicked.uv)) < 3
    assert result["metrics"] == doc["metrics"] and result["flags"] == doc["flags"]
    assert "rejected" in result
    # the report follows the result (the output folder replaced again, with it)
    report = _wait_report(case_dir / "out")
    assert report["html"] == "report.html" and (case_dir / "out" / "report.html").is_file()
    assert all(not m.startswith("report not written") for m in _wait_done(client)["messages"])


def _wait_report(out: Path, timeout: float = 120.0) -> dict:
    """``result.json["report"]`` of ``out`` once it is there (the workbench writes the report
    after the job is done)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:  # the folder is replaced as a whole: a read may fall between the two renames
            report = json.loads((out / "result.json").read_text()).get("report")
        except FileNotFoundError:
            report = None
        if report is not None:
            return report
        time.sleep(0.2)
    raise AssertionError(f"no report in {out} after {timeout:.0f} s")


def test_a_failed_registration_says_why(synthetic):
    client, _ = synthetic
    names = list(client.get("/api/annotations").json()["views"]["cam1"]["landmarks"])
    for view in ("cam1", "cam2"):
        for name in names:
            client.delete(f"/api/views/{view}/landmarks/{name}")
    client.post("/api/register")
    status = _wait_done(client)
    assert status["state"] == "failed"
    assert "landmark observation(s)" in status["error"] and "annotations.json" in status["error"]
    events = _events(client.get("/api/register/events").text)
    assert events[-1][0] == "failed"
    assert json.loads(events[-1][1])["error"] == status["error"]
    assert client.get("/api/result").status_code == 404


# -- the command line -----------------------------------------------------------------------------


def test_cli_serves_the_case_and_removes_its_lock(synthetic_case):
    lock = synthetic_case / ".workbench.lock"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "biplanar_reg.cli", "workbench", str(synthetic_case)]
    proc = subprocess.Popen(
        [*cmd, "--no-browser", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:") and "/?launch=" in url, url
        base = url.split("/?", 1)[0]
        assert httpx.get(f"{base}/api/case", timeout=30).status_code == 403
        with httpx.Client() as browser:  # the one-time URL signs it in
            assert browser.get(url, timeout=30).status_code == 200
            r = browser.get(f"{base}/api/case", timeout=30)
            assert r.status_code == 200 and r.json()["id"] == "case"
        assert json.loads(lock.read_text())["port"] == int(base.rsplit(":", 1)[1])
        second = subprocess.run(
            [*cmd, "--no-browser"], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60
        )
        assert second.returncode == 1 and str(lock) in second.stderr
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert not lock.exists()
    assert proc.stdout.read() == ""  # exactly one line on stdout
