"""Bad annotations that the case loader refuses before any work: a view whose only annotation
is a contour too small to be an outline, and a landmark the model does not have. Each is one
line naming the file and key, exit 2 from ``biplanar-reg register``, nothing in ``--out``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.cases import load_case
from biplanar_reg.cli import main
from biplanar_reg.simulate import write_synthetic_case


@pytest.fixture(scope="module")
def base_case(tmp_path_factory) -> Path:
    return write_synthetic_case(tmp_path_factory.mktemp("bad") / "case0", 0, image_size=(256, 256))


@pytest.fixture()
def case(base_case, tmp_path) -> Path:
    dst = tmp_path / "case"
    shutil.copytree(base_case, dst)
    return dst


def _edit_annotations(case: Path, fn) -> None:
    path = case / "annotations.json"
    doc = json.loads(path.read_text())
    fn(doc["views"])
    path.write_text(json.dumps(doc))


def _with_start(case: Path) -> None:
    """A start pose (the model's own frame): outlines alone may then register, so the loader
    does not ask for landmarks in two views first."""
    (case / "start.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0, 0, 0]}))
    toml = case / "case.toml"
    toml.write_text(
        toml.read_text().replace("[registration]\n", '[registration]\nstart = "start.json"\n', 1)
    )


def _register(case: Path, tmp_path: Path, capsys) -> tuple[int, str, Path]:
    out = tmp_path / "out"
    rc = main(["register", str(case), "--out", str(out)])
    return rc, capsys.readouterr().err.strip(), out


def _tiny_outline(views, across_px: float) -> None:
    views["cam2"] = {
        "landmarks": {},
        "contours": [
            {"uv": [[100.0, 100.0], [100.0 + across_px, 100.3], [100.4, 100.0 + across_px]]}
        ],
    }


def test_a_view_whose_only_annotation_is_a_tiny_contour_is_refused(case, tmp_path, capsys):
    _with_start(case)
    _edit_annotations(case, lambda v: _tiny_outline(v, 1.5))
    rc, err, out = _register(case, tmp_path, capsys)
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert (
        "annotations.json: views.cam2.contours[0]: the view's only annotation is a contour" in err
    )
    assert "1.5 px across" in err and "at least 2 px" in err
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_a_contour_of_two_pixels_is_an_outline(case, capsys):
    _with_start(case)
    _edit_annotations(case, lambda v: _tiny_outline(v, 2.0))
    loaded = load_case(case)  # not refused by the loader
    assert len(loaded.annotations.views["cam2"].contours) == 1


def test_a_tiny_contour_beside_landmarks_loads(case):
    def shrink(views):
        views["cam2"]["contours"] = [{"uv": [[100.0, 100.0], [101.0, 100.0], [100.0, 101.0]]}]

    _edit_annotations(case, shrink)
    assert load_case(case).annotations.views["cam2"].landmarks  # loads


def test_a_landmark_the_model_does_not_have_is_refused(case, tmp_path, capsys):
    _edit_annotations(case, lambda v: v["cam2"]["landmarks"].update(stylion={"uv": [50.0, 60.0]}))
    rc, err, out = _register(case, tmp_path, capsys)
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert "case.toml: [annotations] file: annotations.json: views.cam2.landmarks.stylion" in err
    assert "unknown landmark" in err
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_too_few_landmarks_for_the_pose_mode_name_the_annotations_file(case, tmp_path, capsys):
    """The annotations hold too little for ``poses = "unknown"`` (2 + 1 landmarks): refused by
    the registration's check, named by the annotations file rather than ``[registration]``."""
    toml = case / "case.toml"
    assert 'poses = "known"' in toml.read_text()
    toml.write_text(toml.read_text().replace('poses = "known"', 'poses = "unknown"', 1))

    def keep(views):
        for name, n in (("cam1", 2), ("cam2", 1)):
            marks = views[name]["landmarks"]
            views[name]["landmarks"] = dict(list(marks.items())[:n])

    _edit_annotations(case, keep)
    rc, err, out = _register(case, tmp_path, capsys)
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert "case.toml: annotations.json: poses = 'unknown' starts the registration" in err
    assert "got 3 of 2" in err
    assert not out.exists() and not list(tmp_path.glob(".out*"))
