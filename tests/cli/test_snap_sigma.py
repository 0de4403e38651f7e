"""``biplanar-reg annotate snap --sigma PX``: the sigma written for the snapped landmarks."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from biplanar_reg.annotation.annotations import load_annotations
from biplanar_reg.cli import main


@pytest.fixture(scope="module")
def square(tmp_path_factory) -> tuple[Path, Path]:
    """A dark square on a bright 96 x 96 image (corners at (30, 30) and (65, 65)) and a points
    file with two clicks near its corners."""
    folder = tmp_path_factory.mktemp("snap")
    img = np.full((96, 96), 220, np.uint8)
    cv2.rectangle(img, (30, 30), (65, 65), 40, thickness=-1)
    img = cv2.GaussianBlur(img, (5, 5), 1.0)
    png = folder / "sq.png"
    cv2.imwrite(str(png), img)
    points = folder / "p.json"
    points.write_text(json.dumps({"a": [31.5, 28.8], "b": [64.0, 66.5]}))
    return png, points


def _snap(png: Path, points: Path, out: Path, *extra: str) -> int:
    argv = ["annotate", "snap", str(png), "--points", str(points), "--view", "cam1"]
    return main([*argv, *extra, "-o", str(out)])


def test_snap_writes_the_given_sigma(square, tmp_path, capsys):
    png, points = square
    assert _snap(png, points, tmp_path / "s.json", "--sigma", "2.5") == 0
    lms = load_annotations(tmp_path / "s.json").views["cam1"].landmarks
    assert sorted(lms) == ["a", "b"]
    assert all(lm.sigma_px == 2.5 for lm in lms.values())
    assert _snap(png, points, tmp_path / "d.json") == 0  # default: 1 px
    lms = load_annotations(tmp_path / "d.json").views["cam1"].landmarks
    assert all(lm.sigma_px == 1.0 for lm in lms.values())
    capsys.readouterr()


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("0", "argument --sigma: must be > 0, got 0"),
        ("-1", "argument --sigma: must be > 0, got -1"),
        ("nan", "argument --sigma: expected a finite number, got 'nan'"),
        ("inf", "argument --sigma: expected a finite number, got 'inf'"),
        ("wide", "argument --sigma: expected a number, got 'wide'"),
    ],
)
def test_a_bad_sigma_exits_2_naming_the_option(square, tmp_path, capsys, value, message):
    png, points = square
    with pytest.raises(SystemExit) as info:
        _snap(png, points, tmp_path / "s.json", f"--sigma={value}")
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(message)
    assert not (tmp_path / "s.json").exists()
