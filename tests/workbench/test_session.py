"""The open case behind the workbench (:class:`biplanar_reg.workbench.Workbench`): the lock, the
case loader's path rules, edits saved in the documented formats, the files re-read when they
change on disk."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.annotation import load_annotations, save_annotations
from biplanar_reg.cases import CaseError, load_case, read_case_setup
from biplanar_reg.workbench import Workbench, WorkbenchError
from biplanar_reg.workbench.session import Conflict, NotFound, StaleContour


def _dead_pid() -> int:
    """The pid of a process that has exited."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    """``{relative path: (mtime_ns, content)}`` of every file of a folder."""
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


# -- the lock -------------------------------------------------------------------------------------


def test_second_workbench_is_refused_naming_the_lock(synthetic_case):
    lock = synthetic_case / ".workbench.lock"
    with Workbench(synthetic_case) as wb:
        assert wb.lock_path == lock
        assert json.loads(lock.read_text()) == {"pid": os.getpid(), "port": 0}
        wb.set_port(8123)
        assert json.loads(lock.read_text())["port"] == 8123
        with pytest.raises(WorkbenchError) as info:
            Workbench(synthetic_case)
        msg = str(info.value)
        assert str(lock) in msg and "another workbench" in msg and "\n" not in msg
        assert lock.exists()  # the refused one did not remove the holder's lock
    assert not lock.exists()
    Workbench(synthetic_case).close()  # free again
    assert not lock.exists()


def test_stale_lock_is_taken_over(synthetic_case):
    lock = synthetic_case / ".workbench.lock"
    lock.write_text(json.dumps({"pid": _dead_pid(), "port": 4242}))
    with Workbench(synthetic_case):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists()
    # an unreadable lock: someone's being written (refused) or old debris (taken over)
    lock.write_text("")
    with pytest.raises(WorkbenchError, match="another workbench"):
        Workbench(synthetic_case)
    old = time.time() - 60
    os.utime(lock, (old, old))
    Workbench(synthetic_case).close()
    assert not lock.exists()


def test_a_lock_whose_flock_nobody_holds_is_stale_even_if_its_pid_lives(synthetic_case):
    """The workbench holds the lock's ``flock`` while it runs: a lock file without it is a
    killed workbench's, whatever process its PID now names (here: a live one)."""
    lock = synthetic_case / ".workbench.lock"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock.write_text(json.dumps({"pid": sleeper.pid, "port": 4242}))
        with Workbench(synthetic_case):
            assert json.loads(lock.read_text())["pid"] == os.getpid()
        # a live holder, seen through its flock: refused, in another process too
        with Workbench(synthetic_case):
            code = (
                "from biplanar_reg.workbench import Workbench, WorkbenchError\n"
                "try:\n"
                f"    Workbench({str(synthetic_case)!r})\n"
                "except WorkbenchError as exc:\n"
                "    print('refused:', exc)\n"
            )
            env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
            run = subprocess.run(
                [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
            )
            refused = f"refused: {lock}: the case is open in another workbench (pid {os.getpid()},"
            assert refused in run.stdout, run.stderr[-500:]
    finally:
        sleeper.kill()
        sleeper.wait()
    assert not lock.exists()


def test_bad_case_and_escaping_paths_are_refused_without_a_lock(synthetic_case, tmp_path):
    toml = synthetic_case / "case.toml"
    text = toml.read_text()
    (tmp_path / "outside.json").write_text("{}")
    toml.write_text(text.replace('file = "annotations.json"', 'file = "../outside.json"'))
    with pytest.raises(CaseError, match=r"\[annotations\] file: '../outside.json' points outside"):
        Workbench(synthetic_case)
    # a symlink inside the folder that leads out of it is an escape too
    os.symlink(tmp_path / "outside.json", synthetic_case / "link.json")
    toml.write_text(text.replace('file = "annotations.json"', 'file = "link.json"'))
    with pytest.raises(CaseError, match="points outside the case folder"):
        Workbench(synthetic_case)
    toml.write_text(text.replace('image = "xray/cam1.png"', 'image = "/etc/hostname"'))
    with pytest.raises(CaseError, match=r"\(cam1\) image: '/etc/hostname' points outside"):
        Workbench(synthetic_case)
    assert not (synthetic_case / ".workbench.lock").exists()
    with pytest.raises(CaseError, match="case.toml: file not found"):
        Workbench(tmp_path)


def test_read_case_setup_agrees_with_load_case(wrist_case):
    setup = read_case_setup(wrist_case)
    case = load_case(wrist_case)
    assert [v.name for v in setup.views] == [v.name for v in case.views]
    assert [v.image_size for v in setup.views] == [(1760, 1760)] * 2
    assert setup.landmarks == case.landmarks
    assert setup.n_vertices == case.model.n_vertices
    assert (setup.poses, setup.silhouettes, setup.id) == ("known", True, "wrist_radius")
    assert setup.annotations_path == case.annotations_path
    assert setup.landmarks_path == wrist_case / "model" / "landmarks.json"


# -- edits ----------------------------------------------------------------------------------------


def test_edits_land_in_the_documented_files_and_the_case_still_loads(synthetic_case):
    ann_file = synthetic_case / "annotations.json"
    lm_file = synthetic_case / "model" / "landmarks.json"
    before = load_annotations(ann_file)
    with Workbench(synthetic_case) as wb:
        doc = wb.set_landmark("cam1", "distal_tip", [100.25, 200.5], 2.5)
        assert doc["landmarks"]["distal_tip"] == {"uv": [100.25, 200.5], "sigma_px": 2.5}
        # moving keeps the landmark's sigma
        doc = wb.set_landmark("cam1", "distal_tip", [101.0, 201.0])
        assert doc["landmarks"]["distal_tip"]["sigma_px"] == 2.5
        wb.delete_landmark("cam2", "proximal_x_min")
        pts = [[10.0, 10.0], [20.0, 12.0], [30.0, 15.5], [40.0, 20.0]]
        i, doc = wb.add_contour("cam2", pts, False, [[10, 10], [40, 20]])
        assert i == len(before.views["cam2"].contours)
        added = doc["contours"][i]
        assert {k: added[k] for k in ("uv", "closed", "anchors")} == {
            "uv": pts, "closed": False, "anchors": [[10, 10], [40, 20]]
        }  # fmt: skip
        doc = wb.replace_contour("cam2", i, pts[:3], True)
        assert doc["contours"][i]["id"] == added["id"]  # the same contour, a new version
        assert doc["contours"][i]["version"] != added["version"]
        assert "anchors" not in doc["contours"][i]  # no anchors given
        with pytest.raises(StaleContour):  # by id, at the version it had before
            wb.delete_contour("cam2", added["id"], version=added["version"])
        wb.delete_contour("cam1", 0)
        assert wb.set_model_landmark("styloid", 17)["landmarks"]["styloid"] == 17
        wb.set_landmark("cam2", "styloid", [300, 301])

    raw = json.loads(ann_file.read_text())
    assert raw["format"] == "biplanar-reg/annotations@1"
    assert raw["views"]["cam1"]["landmarks"]["distal_tip"] == {
        "uv": [101.0, 201.0],
        "sigma_px": 2.5,
    }
    assert "proximal_x_min" not in raw["views"]["cam2"]["landmarks"]
    assert raw["views"]["cam2"]["contours"][-1] == {"uv": pts[:3], "closed": True}
    assert len(raw["views"]["cam1"]["contours"]) == len(before.views["cam1"].contours) - 1
    assert json.loads(lm_file.read_text())["styloid"] == 17  # {"name": vertex index}
    case = load_case(synthetic_case)  # what `biplanar-reg register` reads
    assert case.landmarks["styloid"] == 17
    np.testing.assert_allclose(case.annotations.views["cam2"].landmarks["styloid"].uv, [300, 301])


def test_anchors_survive_a_restart_and_are_dropped_when_the_contour_changes(synthetic_case):
    pts = [[10.0, 10.0], [20.0, 12.0], [30.0, 15.5]]
    with Workbench(synthetic_case) as wb:
        i, _ = wb.add_contour("cam1", pts, False, [[10, 10], [30, 15.5]])
    with Workbench(synthetic_case) as wb:  # a restart: nothing lost
        assert wb.view_document("cam1")["contours"][i]["anchors"] == [[10, 10], [30, 15.5]]
        ann = load_annotations(synthetic_case / "annotations.json")
        ann.views["cam1"].contours[i] = type(ann.views["cam1"].contours[i])(
            np.array(pts) + 1.0, False
        )
        save_annotations(ann, synthetic_case / "annotations.json")  # edited outside
        assert "anchors" not in wb.view_document("cam1")["contours"][i]


def test_missing_annotation_and_landmark_files_are_created_by_the_first_edit(synthetic_case):
    (synthetic_case / "annotations.json").unlink()
    (synthetic_case / "model" / "landmarks.json").unlink()
    with Workbench(synthetic_case) as wb:
        info = wb.case_info()
        assert info["landmark_names"] == [] and info["n_vertices"] == 482
        assert wb.annotations_document()["views"] == {
            "cam1": {"landmarks": {}, "contours": []},
            "cam2": {"landmarks": {}, "contours": []},
        }
        with pytest.raises(ValueError, match="name: unknown landmark 'tip'"):
            wb.set_landmark("cam1", "tip", [1, 1])
        assert not (synthetic_case / "annotations.json").exists()
        wb.set_model_landmark("tip", 481)
        wb.set_landmark("cam1", "tip", [5, 6])
    assert json.loads((synthetic_case / "model" / "landmarks.json").read_text()) == {"tip": 481}
    ann = load_annotations(synthetic_case / "annotations.json", known_landmarks={"tip"})
    np.testing.assert_allclose(ann.views["cam1"].landmarks["tip"].uv, [5, 6])


def test_a_file_changed_on_disk_is_re_read_or_refused(synthetic_case):
    ann_file = synthetic_case / "annotations.json"
    with Workbench(synthetic_case) as wb:
        ann = load_annotations(ann_file)
        del ann.views["cam1"].landmarks["distal_tip"]
        save_annotations(ann, ann_file)
        assert "distal_tip" not in wb.view_document("cam1")["landmarks"]
        ann_file.write_text('{"format": "biplanar-reg/annotations@1", "views": {"cam9": {}}}')
        snap = _snapshot(synthetic_case)
        with pytest.raises(Conflict, match="changed outside the workbench.*views.cam9"):
            wb.set_landmark("cam1", "distal_tip", [1, 1])
        assert _snapshot(synthetic_case) == snap


def test_bad_edits_raise_naming_the_field_and_write_nothing(synthetic_case):
    with Workbench(synthetic_case) as wb:
        snap = _snapshot(synthetic_case)
        bad = [
            (ValueError, "uv: missing", lambda: wb.set_landmark("cam1", "distal_tip", None)),
            (ValueError, r"uv: point \(600, 1\) is outside the 512x512 image",
             lambda: wb.set_landmark("cam1", "distal_tip", [600, 1])),
            (ValueError, "sigma_px: expected a positive number",
             lambda: wb.set_landmark("cam1", "distal_tip", [1, 1], -1)),
            (ValueError, r"uv\[1\]: expected \[u, v\]",
             lambda: wb.add_contour("cam1", [[1, 1], [2, "x"], [3, 3]])),
            (ValueError, "uv: has 2 point", lambda: wb.add_contour("cam1", [[1, 1], [2, 2]])),
            (ValueError, "closed: expected true or false",
             lambda: wb.add_contour("cam1", [[1, 1], [2, 2], [3, 3]], "yes")),
            (ValueError, r"anchors\[0\]: point",
             lambda: wb.add_contour("cam1", [[1, 1], [2, 2], [3, 3]], False, [[-9, 0], [1, 1]])),
            (NotFound, r"views.cam1.contours\[99\]", lambda: wb.delete_contour("cam1", 99)),
            (NotFound, "view: unknown view 'cam9'", lambda: wb.set_landmark("cam9", "x", [1, 1])),
            (NotFound, "not placed", lambda: wb.delete_landmark("cam1", "nope")),
            (ValueError, r"vertex: expected a vertex index in 0..481",
             lambda: wb.set_model_landmark("x", 482)),
            (Conflict, "still placed in view", lambda: wb.delete_model_landmark("distal_tip")),
            (ValueError, "mode: expected 'corner' or 'edge'",
             lambda: wb.snap("cam1", [10, 10], "blob")),
            (ValueError, "anchors: has 2 point",
             lambda: wb.livewire("cam1", [[1, 1], [5, 5]], True)),
        ]  # fmt: skip
        for exc, pattern, call in bad:
            with pytest.raises(exc, match=pattern):
                call()
        assert _snapshot(synthetic_case) == snap


# -- tiles ---------------------------------------------------------------------------------------


def test_pyramid_of_an_odd_sized_monochrome1_dicom_like_image():
    import cv2

    from biplanar_reg.annotation import XrayImage
    from biplanar_reg.workbench.tiles import Pyramid

    rng = np.random.default_rng(0)
    pixels = rng.uniform(0, 4000, (517, 300))
    image = XrayImage(
        pixels=pixels,
        display=np.zeros(pixels.shape, np.float32),
        source="x.dcm",
        file_format="dicom",
        photometric="MONOCHROME1",
        window=(1000.0, 500.0),
    )
    p = Pyramid(image)
    assert (p.width, p.height, p.levels) == (300, 517, 3)  # 517 -> 259 -> 130 px
    assert [p.level_size(k) for k in range(3)] == [(300, 517), (150, 259), (75, 130)]
    assert p.tiles(0) == (2, 3) and p.tiles(2) == (1, 1)
    assert p.window == (750.0, 1250.0) and p.inverted  # the DICOM window, MONOCHROME1
    tile = cv2.imdecode(np.frombuffer(p.tile(0, 1, 2), np.uint8), cv2.IMREAD_UNCHANGED)
    assert tile.shape == (5, 44)
    raw = pixels[512:, 256:]
    want = 255 - np.round(np.clip((raw - 750.0) * 255.0 / 500.0, 0, 255))
    assert np.abs(tile.astype(float) - want).max() <= 1  # high values dark
    with pytest.raises(LookupError, match="level: 3 is not in 0..2"):
        p.tile(3, 0, 0)
    with pytest.raises(ValueError, match="hi: must be greater than lo"):
        p.tile(0, 0, 0, 10.0, 10.0)
