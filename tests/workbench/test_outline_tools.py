"""The outline tools' API (biplanar_reg/workbench/outline_tools.py) through Starlette's test
client on the synthetic case (512 x 512 radiographs): exclusion zones (circle, polygon, brush)
cutting the saved contours so that the case loader sees the cut contour, anchors re-traced,
a stretch erased, GrabCut, per-contour quality and residuals; bad input is a 4xx naming the
field and writes nothing."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from _http import page_client
from matplotlib.path import Path as MplPath
from starlette.testclient import TestClient

from biplanar_reg.cases import load_case
from biplanar_reg.workbench import Workbench, create_app
from biplanar_reg.workbench.outline_tools import (
    CLEANING_NAME,
    brush_polygons,
    circle_polygon,
    erase_stretch,
    piece_anchors,
)

TOKEN = "test-token-0123456789"
VIEW = "cam1"


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture
def client(synthetic_case) -> Iterator[tuple[TestClient, Path]]:
    with Workbench(synthetic_case) as wb:
        c = page_client(create_app(wb, TOKEN), TOKEN)
        yield c, synthetic_case


def _saved(case: Path, view: str = VIEW) -> list[dict]:
    return json.loads((case / "annotations.json").read_text())["views"][view]["contours"]


# -- pure helpers ------------------------------------------------------------------------------


def test_circle_polygon_contains_its_circle():
    poly = circle_polygon(np.array([10.0, 20.0]), 5.0)
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = np.c_[10 + 4.999 * np.cos(t), 20 + 4.999 * np.sin(t)]
    assert MplPath(poly).contains_points(ring).all()
    assert not MplPath(poly).contains_points([[10 + 5.3, 20]]).any()  # 1/cos(pi/32) - 1 ~ 0.5%


def test_brush_polygon_covers_the_stroke_width():
    (poly,) = brush_polygons(np.array([[10.0, 10.0], [40.0, 10.0]]), 3.0)
    inside = MplPath(poly).contains_points([[25, 12.5], [10, 7.5], [40, 12.5], [8, 10]])
    assert inside.all()
    assert not MplPath(poly).contains_points([[25, 14], [25, 6], [45, 10]]).any()


def test_erase_stretch_open_and_closed():
    line = np.c_[np.arange(20.0), np.zeros(20)]
    pieces = erase_stretch(line, False, np.array([5.2, 0.0]), np.array([9.9, 1.0]))
    assert [len(p) for p in pieces] == [5, 9]  # 5..10 dropped
    assert pieces[0][-1][0] == 4 and pieces[1][0][0] == 11
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    ring = np.c_[np.cos(t), np.sin(t)] * 10
    (rest,) = erase_stretch(ring, True, ring[38], ring[2])  # the short way round, over index 0
    assert len(rest) == 40 - 5
    assert np.allclose(rest[0], ring[3]) and np.allclose(rest[-1], ring[37])


def test_piece_anchors_keep_the_inner_ones_and_add_the_ends():
    piece = np.c_[np.arange(10.0, 30.0), np.zeros(20)]
    anchors = np.array([[0.0, 0], [15.0, 1.0], [25.0, -2.0], [40.0, 0]])
    got = piece_anchors(piece, False, anchors)
    assert got == [[10.0, 0.0], [15.0, 1.0], [25.0, -2.0], [29.0, 0.0]]


# -- exclusion zones -------------------------------------------------------------------------------


def test_circle_zone_cuts_the_saved_contour_and_the_loader_sees_it(client):
    c, case = client
    before = np.asarray(_saved(case)[0]["uv"])
    centre = before[len(before) // 2]
    r = c.post(
        f"/api/views/{VIEW}/exclusions",
        json={"circle": {"center": centre.tolist(), "radius_px": 6}},
    )
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["added"] == 1 and doc["cut"] == [0] and len(doc["zones"]) == 1
    after = _saved(case)
    assert len(after) == 2  # the open contour in two pieces, none of its points in the circle
    for piece in after:
        uv = np.asarray(piece["uv"])
        assert np.all(np.hypot(*(uv - centre).T) > 6)
    assert sum(len(p["uv"]) for p in after) == len(before) - np.sum(
        MplPath(np.asarray(doc["zones"][0])).contains_points(before)
    )
    # the pieces keep anchors (their ends at least), for editing
    assert all(len(p["anchors"]) >= 2 for p in doc["view"]["contours"])
    # the zone file, in the recipes' "cleaning" layout
    zfile = json.loads((case / CLEANING_NAME).read_text())
    assert zfile["views"][VIEW]["cleaning"]["exclusion_zones"] == doc["zones"]
    # the case loader (= register) reads the cut contours
    loaded = load_case(case).annotations.views[VIEW].contours
    assert [len(x.uv) for x in loaded] == [len(p["uv"]) for p in after]
    # a contour traced afterwards across the zone is cut too
    anchors = [before[len(before) // 2 - 20].tolist(), before[len(before) // 2 + 20].tolist()]
    r = c.post(f"/api/views/{VIEW}/outlines", json={"anchors": anchors})
    assert r.status_code == 200, r.text
    assert r.json()["pieces"] == 2
    for piece in _saved(case)[2:]:
        assert np.all(np.hypot(*(np.asarray(piece["uv"]) - centre).T) > 6)
    # zones listed, removed: what it cut comes back whole (tests/workbench/test_history.py)
    assert len(c.get(f"/api/views/{VIEW}/exclusions").json()["zones"]) == 1
    gone = c.delete(f"/api/views/{VIEW}/exclusions/0").json()
    assert (gone["zones"], gone["restored"], gone["not_restored"]) == ([], 2, 0)
    back = _saved(case)
    assert len(back) == 2
    assert np.array_equal(np.asarray(back[0]["uv"]), before)
    assert c.delete(f"/api/views/{VIEW}/exclusions/0").status_code == 404


def test_brush_and_polygon_zones(client):
    c, case = client
    uv = np.asarray(_saved(case)[0]["uv"])
    k = len(uv) // 3
    stroke = uv[k : k + 10 : 3].tolist()
    r = c.post(f"/api/views/{VIEW}/exclusions", json={"brush": {"points": stroke, "radius_px": 3}})
    assert r.status_code == 200, r.text
    assert r.json()["cut"] == [0]
    p = uv[-6] + np.array([[-4, -4], [4, -4], [4, 4], [-4, 4]])
    r = c.post(f"/api/views/{VIEW}/exclusions", json={"polygon": p.tolist()})
    assert r.status_code == 200, r.text
    assert len(r.json()["zones"]) == 2
    for piece in _saved(case):
        pts = np.asarray(piece["uv"])
        assert not MplPath(p).contains_points(pts).any()


@pytest.mark.parametrize(
    "body, field",
    [
        ({}, "body: give exactly one"),
        (
            {"circle": {"center": [10, 10], "radius_px": 5}, "polygon": [[0, 0], [1, 0], [1, 1]]},
            "body: give exactly one",
        ),
        ({"circle": {"center": [10, 10]}}, "circle.radius_px"),
        ({"circle": {"center": [10, 10], "radius_px": -1}}, "circle.radius_px"),
        ({"circle": {"center": [900, 10], "radius_px": 3}}, "circle.center"),
        ({"circle": [10, 10, 3]}, "circle: expected an object"),
        ({"polygon": [[0, 0], [1, 1]]}, "polygon: has 2 point(s)"),
        ({"brush": {"points": [], "radius_px": 2}}, "brush.points"),
    ],
)
def test_bad_zone_is_400_and_writes_nothing(client, body, field):
    c, case = client
    before = _files(case)
    r = c.post(f"/api/views/{VIEW}/exclusions", json=body)
    assert r.status_code == 400, r.text
    assert r.json()["error"].startswith(field)
    assert _files(case) == before
    assert c.post("/api/views/cam9/exclusions", json=body).status_code == 404


# -- anchors, erase, GrabCut -------------------------------------------------------------------


def test_retrace_with_edited_anchors(client):
    c, case = client
    uv = np.asarray(_saved(case)[0]["uv"])
    anchors = uv[np.linspace(0, len(uv) - 1, 5).round().astype(int)].tolist()
    r = c.post(f"/api/views/{VIEW}/outlines", json={"anchors": anchors})
    assert r.status_code == 200, r.text
    i = r.json()["index"]
    assert i == 1 and np.allclose(r.json()["view"]["contours"][1]["anchors"], anchors, atol=1e-3)
    # delete an anchor, move one: the contour is traced again between neighbours
    edited = [anchors[0], anchors[1], [anchors[3][0] + 1, anchors[3][1]], anchors[4]]
    traced = r.json()["view"]["contours"][1]
    at = f"/api/views/{VIEW}/contours/{traced['id']}/anchors?version={traced['version']}"
    r = c.put(at, json={"anchors": edited})
    assert r.status_code == 200, r.text
    got = r.json()["view"]["contours"]
    assert len(got) == 2 and np.allclose(got[1]["anchors"], edited, atol=1e-3)
    assert got[1]["id"] == traced["id"] and got[1]["version"] != traced["version"]
    assert c.put(at, json={"anchors": edited}).status_code == 409  # that version is gone
    version = got[1]["version"]
    new = np.asarray(_saved(case)[1]["uv"])
    # the synthetic outline is the same edge: the re-traced path follows the old contour
    d = np.min(np.linalg.norm(new[:, None] - uv[None], axis=2), axis=1)
    assert np.median(d) < 1.5
    before = _files(case)
    bad = c.put(f"/api/views/{VIEW}/contours/{i}/anchors?version={version}",
                json={"anchors": [anchors[0]]})  # fmt: skip
    assert bad.status_code == 400 and bad.json()["error"].startswith("anchors:")
    assert c.put(f"/api/views/{VIEW}/contours/7/anchors?version={version}",
                 json={"anchors": edited}).status_code == 404  # fmt: skip
    assert _files(case) == before


def test_erase_a_stretch(client):
    c, case = client
    uv = np.asarray(_saved(case)[0]["uv"])
    a, b = uv[100], uv[120]
    first = c.get("/api/annotations").json()["views"][VIEW]["contours"][0]
    at = f"/api/views/{VIEW}/contours/0/erase?version={first['version']}"
    r = c.post(at, json={"from": a.tolist(), "to": b.tolist()})
    assert r.status_code == 200, r.text
    assert r.json()["pieces"] == 2
    got = _saved(case)
    assert [len(p["uv"]) for p in got] == [100, len(uv) - 121]
    before = _files(case)
    r = c.post(at, json={"from": a.tolist(), "to": b.tolist()})
    assert r.status_code == 409, r.text  # contour 0 is another (a piece) now
    piece = c.get("/api/annotations").json()["views"][VIEW]["contours"][0]
    at = f"/api/views/{VIEW}/contours/{piece['id']}/erase?version={piece['version']}"
    r = c.post(at, json={"from": [1, 2]})
    assert r.status_code == 400 and r.json()["error"].startswith("to:")
    assert _files(case) == before


def test_grabcut_box(client):
    c, case = client
    uv = np.asarray(_saved(case)[0]["uv"])
    lm = json.loads((case / "annotations.json").read_text())["views"][VIEW]["landmarks"]
    pts = np.vstack([uv, [m["uv"] for m in lm.values()]])
    box = [*(pts.min(axis=0) - 15), *(pts.max(axis=0) + 15)]
    r = c.post(f"/api/views/{VIEW}/grabcut", json={"box": box})
    assert r.status_code == 200, r.text
    out = _saved(case)[r.json()["index"]]
    assert out["closed"] and len(out["uv"]) > 100
    # the bone's outline: the annotated (open) outline lies on it
    seg = np.asarray(out["uv"])
    d = np.min(np.linalg.norm(uv[:, None] - seg[None], axis=2), axis=1)
    assert np.median(d) < 2.0
    before = _files(case)
    for body, field in [({"box": [1, 2, 3]}, "box:"), ({"box": [10, 10, 12, 12]}, "box:"),
                        ({"box": box, "iterations": 0}, "iterations:")]:  # fmt: skip
        r = c.post(f"/api/views/{VIEW}/grabcut", json=body)
        assert r.status_code == 400 and r.json()["error"].startswith(field), r.text
    assert _files(case) == before


# -- quality and residuals -----------------------------------------------------------------------


def test_quality_tells_an_edge_from_a_trace_off_the_edge(client):
    c, case = client
    uv = np.asarray(_saved(case)[0]["uv"])
    off = uv + 12 * np.array([1.0, 0.0])  # the same shape, off the edge
    c.post(f"/api/views/{VIEW}/contours", json={"uv": off.tolist()})
    q = c.get(f"/api/views/{VIEW}/quality").json()["contours"]
    assert [x["index"] for x in q] == [0, 1]
    assert len(q[0]["strength"]) == len(uv)
    assert q[0]["verdict"] == "ok" and q[0]["median"] > 2 * q[1]["median"]
    assert q[1]["verdict"] == "faint"
    assert c.get("/api/views/cam9/quality").status_code == 404


def test_contour_residuals_need_a_result(client, tmp_path):
    c, case = client
    r = c.get("/api/result/contours")
    assert r.status_code == 404 and r.json()["error"].startswith("result:")
