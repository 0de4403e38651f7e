"""The view aids' routes on the shipped wrist case: epipolar curves (through the projection of
a 3D point, fast enough for mouse moves), marker proposals and CLAHE tiles."""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from _http import page_client
from starlette.testclient import TestClient

from biplanar_reg.annotation.clean import distance_to_polyline
from biplanar_reg.workbench import Workbench, create_app

TOKEN = "t" * 24


@pytest.fixture
def wrist(wrist_case) -> Iterator[tuple[TestClient, Workbench]]:
    with Workbench(wrist_case) as wb:
        yield page_client(create_app(wb, TOKEN), TOKEN), wb


def _distance(p: np.ndarray, pieces: list) -> float:
    """Pixels from ``p`` (2,) to the nearest of the curve's pieces."""
    return min(float(distance_to_polyline(np.asarray(p)[None], line)[0]) for line in pieces)


def test_epipolar_curve_passes_through_the_other_projection(wrist) -> None:
    client, wb = wrist
    cam1, cam2 = (wb.views[n].cv.view for n in ("cam01", "cam02"))
    X = np.array([[120.0, 80.0, 100.0]])  # near the isocentre of the two views
    a, b = cam1.project(X)[0], cam2.project(X)[0]
    r = client.get(f"/api/views/cam01/epipolar?u={a[0]}&v={a[1]}")
    assert r.status_code == 200, r.text
    doc = r.json()
    assert list(doc["curves"]) == ["cam02"]
    assert _distance(b, doc["curves"]["cam02"]) < 0.5
    back = client.get(f"/api/views/cam02/epipolar?u={b[0]}&v={b[1]}").json()
    assert _distance(a, back["curves"]["cam01"]) < 0.5


def test_epipolar_is_fast_enough_for_mouse_moves(wrist) -> None:
    client, _ = wrist
    client.get("/api/views/cam01/epipolar?u=900&v=900")  # the scene sphere, once
    seconds = [
        client.get(f"/api/views/cam01/epipolar?u={600 + 9 * i}&v={1300 - 5 * i}").json()["seconds"]
        for i in range(30)
    ]
    assert statistics.median(seconds) < 0.02, seconds


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("u=x&v=3", "u: expected a number"),
        ("u=3", "v: expected a number"),
        ("u=5000&v=3", "uv: point (5000, 3) is outside"),
        ("u=nan&v=3", "u: must be finite"),
    ],
)
def test_epipolar_bad_input(wrist, query: str, message: str) -> None:
    client, _ = wrist
    r = client.get(f"/api/views/cam01/epipolar?{query}")
    assert r.status_code == 400 and message in r.json()["error"], r.text


def test_markers_propose_the_forearm_beads(wrist) -> None:
    client, _ = wrist
    r = client.get("/api/views/cam02/markers")
    assert r.status_code == 200, r.text
    markers = r.json()["markers"]
    contrasts = [m["contrast"] for m in markers]
    assert contrasts == sorted(contrasts, reverse=True)
    uv = np.array([m["uv"] for m in markers])
    # three forearm beads of cam02, located by eye (benchmarks/markers_wrist.py)
    for bead in [(879, 1434), (602, 1423), (895, 871)]:
        assert np.min(np.linalg.norm(uv - bead, axis=1)) < 3.0
    assert all(m["zone_radius_px"] > m["radius_px"] for m in markers)
    bad = client.get("/api/views/cam02/markers?kind=coins")
    assert bad.status_code == 400 and bad.json()["error"].startswith("kind:")
    bad = client.get("/api/views/cam02/markers?min_contrast=2")
    assert bad.status_code == 400 and bad.json()["error"].startswith("min_contrast:")


def test_clahe_tiles_raise_local_contrast(wrist) -> None:
    client, _ = wrist
    url = "/api/views/cam01/tiles/0/3/5.png?lo=60&hi=220"
    plain, enhanced = client.get(url), client.get(url + "&clahe=1")
    assert plain.status_code == enhanced.status_code == 200
    a = cv2.imdecode(np.frombuffer(plain.content, np.uint8), cv2.IMREAD_GRAYSCALE)
    b = cv2.imdecode(np.frombuffer(enhanced.content, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert a.shape == b.shape

    def local(img: np.ndarray) -> float:  # detail: the image less its 8 px blur
        f = img.astype(float)
        return float(np.std(f - cv2.GaussianBlur(f, (0, 0), 8.0)))

    assert local(b) > 1.2 * local(a), (local(a), local(b))
    t0 = time.perf_counter()
    assert client.get(url.replace("3/5", "4/5") + "&clahe=1").status_code == 200
    assert time.perf_counter() - t0 < 1.0  # the equalised level is kept


def test_window_of_a_box(wrist) -> None:
    client, wb = wrist
    r = client.get("/api/views/cam01/window?box=900,1300,700,1100")
    assert r.status_code == 200, r.text
    doc = r.json()
    raw = wb.views["cam01"].image.pixels[1100:1301, 700:901]
    assert doc["box"] == [700, 1100, 900, 1300] and doc["pixels"] == raw.size
    np.testing.assert_allclose(doc["window"], np.percentile(raw, [1, 99]))
    for box, message in [("1,2,3", "box: expected u0,v0,u1,v1"), ("5,5,5.2,900", "box: at least"),
                         ("x,1,2,3", "box: expected a number")]:  # fmt: skip
        r = client.get(f"/api/views/cam01/window?box={box}")
        assert r.status_code == 400 and r.json()["error"].startswith(message), r.text
