"""Undo / redo kept by the server (biplanar_reg/workbench/history.py) through the page's API on
the synthetic case: every kind of edit undone and redone with the files back byte for byte,
the bounded history, a file changed by someone else clearing it; and what an exclusion zone
cut coming back when the zone is removed (zone_restore.py), an erase of no length, an outline
that runs over itself refused."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from _http import page_client
from starlette.testclient import TestClient

from biplanar_reg.annotation import load_annotations, save_annotations
from biplanar_reg.workbench import Workbench, create_app
from biplanar_reg.workbench.history import HISTORY_LIMIT, History, NothingToUndo
from biplanar_reg.workbench.outline_tools import self_overlap

TOKEN = "test-token-0123456789"
VIEW = "cam1"
EDITED = ("annotations.json", ".workbench.json", ".workbench-cleaning.json", "model/landmarks.json")


def _files(case: Path) -> dict[str, object]:
    """The content of every file an edit may write: the case's files byte for byte (None:
    absent), the workbench's own two files as JSON, absent = empty (an undo back to "no zone
    yet" leaves an empty one)."""
    out: dict[str, object] = {}
    for n in EDITED:
        path = case / n
        if n.startswith(".workbench"):
            doc = json.loads(path.read_text()) if path.exists() else {}
            out[n] = {k: v for k, v in doc.items() if k != "format" and v}
        else:
            out[n] = path.read_bytes() if path.exists() else None
    return out


def _contours(case: Path, view: str = VIEW) -> list[dict]:
    return json.loads((case / "annotations.json").read_text())["views"][view]["contours"]


@pytest.fixture
def client(synthetic_case) -> Iterator[tuple[TestClient, Path]]:
    with Workbench(synthetic_case) as wb:
        yield page_client(create_app(wb, TOKEN), TOKEN), synthetic_case


def _ok(response) -> dict:
    assert response.status_code == 200, response.text
    return response.json()


def _zone(c: TestClient, centre, radius: float = 6.0) -> dict:
    body = {"circle": {"center": [float(x) for x in centre], "radius_px": radius}}
    return _ok(c.post(f"/api/views/{VIEW}/exclusions", json=body))


# -- the history itself ------------------------------------------------------------------------


def test_history_records_nested_steps_and_drops_the_oldest_beyond_its_limit():
    state = {"x": (0,)}
    h = History(threading.RLock(), limit=3)
    h.part("x", lambda: state["x"], lambda v: state.__setitem__("x", v))
    for k in range(1, 6):
        with h.step(f"set {k}"), h.step("inner"):  # nested: one step, the outer label
            state["x"] = (k,)
    with h.step("nothing"):
        pass  # no change: no step
    assert h.status()["undo"] == 3 and h.status()["undo_label"] == "set 5"
    assert [h.undo().label for _ in range(3)] == ["set 5", "set 4", "set 3"]
    assert state["x"] == (2,)  # the two oldest steps were dropped
    with pytest.raises(NothingToUndo, match="undo: nothing to undo"):
        h.undo()
    assert h.redo().label == "set 3" and state["x"] == (3,)
    with h.step("set 9"):
        state["x"] = (9,)
    assert h.status()["redo"] == 0  # a new edit ends the redo chain
    h.clear("the file changed")
    with pytest.raises(NothingToUndo, match=r"nothing to undo \(the file changed\)"):
        h.undo()
    with pytest.raises(ValueError, match="limit"):
        History(threading.RLock(), limit=0)


# -- every edit undone and redone -------------------------------------------------------------


def test_each_kind_of_edit_is_undone_and_redone_with_the_files_restored(client):
    c, case = client
    assert _ok(c.get("/api/history"))["history"]["limit"] == HISTORY_LIMIT == 200
    states = [_files(case)]
    line = np.asarray(_contours(case)[0]["uv"])
    edits = [
        lambda: c.put(f"/api/views/{VIEW}/landmarks/distal_tip", json={"uv": [10, 12]}),
        lambda: c.put(f"/api/views/{VIEW}/landmarks/distal_tip", json={"uv": [20, 22]}),
        lambda: c.delete(f"/api/views/{VIEW}/landmarks/proximal_tip"),
        lambda: c.post(f"/api/views/{VIEW}/outlines", json={"anchors": [[100, 100], [140, 120]]}),
        lambda: c.post(
            f"/api/views/{VIEW}/contours/0/erase?version={_version(c)}",
            json={"from": line[20].tolist(), "to": line[40].tolist()},
        ),
        lambda: _zone_response(c, line[100]),
        lambda: c.delete(f"/api/views/{VIEW}/exclusions/0"),
        lambda: c.put("/api/model/landmarks/new_point", json={"vertex": 7}),
        lambda: c.delete(f"/api/views/{VIEW}/contours/0?version={_version(c)}"),
    ]
    for edit in edits:
        _ok(edit())
        states.append(_files(case))
        assert states[-1] != states[-2]
    assert _ok(c.get("/api/history"))["history"]["undo"] == len(edits)
    for k in range(len(edits), 0, -1):
        doc = _ok(c.post("/api/history/undo", json={}))
        assert _files(case) == states[k - 1], doc["done"]
        # the answer is what the page shows: the annotations as saved, the model landmarks
        saved = json.loads((case / "annotations.json").read_text())
        for view, va in saved["views"].items():
            assert [x["uv"] for x in doc["annotations"]["views"][view]["contours"]] == [
                x["uv"] for x in va["contours"]
            ]
        assert doc["model_landmarks"] == json.loads((case / "model/landmarks.json").read_text())
    assert c.post("/api/history/undo", json={}).status_code == 409
    for k in range(1, len(edits) + 1):
        _ok(c.post("/api/history/redo", json={}))
        assert _files(case) == states[k]
    assert c.post("/api/history/redo", json={}).json()["error"] == "redo: nothing to redo"
    assert c.post("/api/history/sideways", json={}).status_code == 404


def _version(c: TestClient) -> int:
    return c.get("/api/annotations").json()["views"][VIEW]["contours"][0]["version"]


def _zone_response(c: TestClient, centre):
    body = {"circle": {"center": [float(x) for x in centre], "radius_px": 6.0}}
    return c.post(f"/api/views/{VIEW}/exclusions", json=body)


def test_undo_needs_the_token_header_and_a_json_body(client):
    c, case = client
    _ok(c.put(f"/api/views/{VIEW}/landmarks/distal_tip", json={"uv": [10, 12]}))
    bare = TestClient(c.app, base_url=str(c.base_url))
    bare.cookies.set("x", "y")
    assert bare.post("/api/history/undo", json={}).status_code == 403
    r = c.post("/api/history/undo", content=b"{}", headers={"Content-Type": "text/plain"})
    assert r.status_code == 415
    assert _ok(c.get("/api/history"))["history"]["undo"] == 1


def test_a_file_changed_by_someone_else_clears_the_history(client):
    c, case = client
    _ok(c.put(f"/api/views/{VIEW}/landmarks/distal_tip", json={"uv": [10, 12]}))
    ann = load_annotations(case / "annotations.json")
    del ann.views[VIEW].landmarks["proximal_tip"]
    save_annotations(ann, case / "annotations.json")  # another program's edit
    before = _files(case)
    r = c.post("/api/history/undo", json={})
    assert r.status_code == 409
    assert "annotations.json was changed outside the workbench" in r.json()["error"]
    assert _files(case) == before  # that edit is not overwritten
    status = _ok(c.get("/api/history"))["history"]
    assert status["undo"] == 0 and "cleared" in status["note"]
    # later edits are undoable again, back to the other program's version
    _ok(c.put(f"/api/views/{VIEW}/landmarks/distal_tip", json={"uv": [30, 32]}))
    _ok(c.post("/api/history/undo", json={}))
    assert _files(case) == before


def test_undo_of_the_first_model_landmark_removes_the_file_it_created(synthetic_case):
    (synthetic_case / "model" / "landmarks.json").unlink()
    (synthetic_case / "annotations.json").unlink()
    with Workbench(synthetic_case) as wb:
        wb.set_model_landmark("tip", 481)
        wb.set_landmark("cam1", "tip", [5, 6])
        assert wb.undo()["done"] == "tip placed in cam1"
        assert wb.undo()["model_landmarks"] == {}
        assert not (synthetic_case / "model" / "landmarks.json").exists()
        assert wb.redo()["model_landmarks"] == {"tip": 481}


# -- exclusion zones give back what they cut; an erase of no length ----------------------------


def test_removing_a_zone_restores_what_it_cut_even_under_another_zone(client):
    c, case = client
    original = _files(case)["annotations.json"]
    line = np.asarray(_contours(case)[0]["uv"])
    _zone(c, line[60])
    _zone(c, line[150])
    assert len(_contours(case)) == 3  # cut by both
    gone = _ok(c.delete(f"/api/views/{VIEW}/exclusions/0"))
    assert (gone["restored"], gone["not_restored"]) == (1, 0)
    (a, b) = _contours(case)  # only the second zone cuts it now
    assert len(a["uv"]) + len(b["uv"]) < len(line)
    assert np.array_equal(np.asarray(a["uv"]), line[: len(a["uv"])])
    _ok(c.delete(f"/api/views/{VIEW}/exclusions/0"))
    assert _files(case)["annotations.json"] == original  # the contour exactly as it was
    doc = json.loads((case / ".workbench-cleaning.json").read_text())
    assert doc["views"] == {}  # no zone, nothing left to restore


def test_a_piece_edited_since_is_not_restored(client):
    c, case = client
    line = np.asarray(_contours(case)[0]["uv"])
    _zone(c, line[60])
    first = _ok(c.get("/api/annotations"))["views"][VIEW]["contours"][0]
    piece = np.asarray(first["uv"])
    at = f"/api/views/{VIEW}/contours/{first['id']}/erase?version={first['version']}"
    _ok(c.post(at, json={"from": piece[5].tolist(), "to": piece[15].tolist()}))
    n = len(_contours(case))
    gone = _ok(c.delete(f"/api/views/{VIEW}/exclusions/0"))
    assert (gone["restored"], gone["not_restored"]) == (0, 1)
    assert len(_contours(case)) == n
    # undo brings the zone back, and the cut contour with it
    _ok(c.post("/api/history/undo", json={}))
    assert len(c.get(f"/api/views/{VIEW}/exclusions").json()["zones"]) == 1


def test_an_erase_of_no_length_changes_nothing(client):
    c, case = client
    first = _ok(c.get("/api/annotations"))["views"][VIEW]["contours"][0]
    point = first["uv"][50]
    before = {n: (case / n).stat().st_mtime_ns for n in ("annotations.json",)}
    at = f"/api/views/{VIEW}/contours/{first['id']}/erase?version={first['version']}"
    doc = _ok(c.post(at, json={"from": point, "to": [point[0] + 0.2, point[1]]}))
    assert doc["pieces"] == 1
    assert doc["view"]["contours"][0]["uv"] == first["uv"]
    assert doc["view"]["contours"][0]["version"] == first["version"]
    assert (case / "annotations.json").stat().st_mtime_ns == before["annotations.json"]
    assert _ok(c.get("/api/history"))["history"]["undo"] == 0


def test_an_outline_running_over_itself_is_refused(client):
    c, case = client
    uv = np.asarray(_contours(case)[0]["uv"])
    a, b, d = uv[40].tolist(), uv[120].tolist(), uv[200].tolist()
    before = _files(case)
    for anchors in ([a, b, a, b], [a, b, d, b, a]):  # back and forth along the same edge
        r = c.post(f"/api/views/{VIEW}/outlines", json={"anchors": anchors})
        assert r.status_code == 400
        assert r.json()["error"].startswith("anchors: the outline runs over itself (")
    assert _files(case) == before
    _ok(c.post(f"/api/views/{VIEW}/outlines", json={"anchors": [a, b, d]}))  # once: fine
    line = np.c_[np.arange(100.0), np.zeros(100)]
    assert self_overlap(line, False) == 0.0
    assert self_overlap(np.vstack([line, line[::-1], line]), False) > 0.9
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    assert self_overlap(np.c_[50 * np.cos(t), 50 * np.sin(t)], True) == 0.0  # closed: its ends
