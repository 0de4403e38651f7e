"""``biplanar-reg calibration convert`` and ``show``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from biplanar_reg.calibration import load_calibration
from biplanar_reg.cli import main

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"
CAM1 = DATA / "cam01_calibration_mayacam2.txt"
CAM2 = DATA / "cam02_calibration_mayacam2.txt"


def test_convert_and_back(tmp_path: Path, capsys) -> None:
    assert main(["calibration", "convert", str(CAM1), str(tmp_path / "c.csv"), "--to", "dlt"]) == 0
    assert (
        main(
            [
                "calibration",
                "convert",
                str(tmp_path / "c.csv"),
                str(tmp_path / "c.json"),
                "--to",
                "json",
                "--image-size",
                "1760",
                "1760",
            ]
        )
        == 0
    )
    a, b = load_calibration(CAM1), load_calibration(tmp_path / "c.json")
    X = np.random.default_rng(0).uniform(50, 150, (50, 3))
    assert np.abs(a.project(X) - b.project(X)).max() < 1e-6
    # DLT input without the image size: bad input, exit 2, message says what to pass
    capsys.readouterr()
    assert main(["calibration", "show", str(tmp_path / "c.csv")]) == 2
    assert "--image-size" in capsys.readouterr().err


def test_show_two_views(capsys) -> None:
    assert main(["--json", "calibration", "show", str(CAM1), str(CAM2)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert len(info["views"]) == 2
    for v in info["views"]:
        assert 800 < v["source_distance_mm"] < 1500
    assert info["pair"]["principal_rays_distance_mm"] < 30
    assert 60 < info["pair"]["angle_deg"] < 150
    assert main(["calibration", "show", str(CAM1), str(CAM2)]) == 0
    out = capsys.readouterr().out
    assert "source position" in out and "angle between the principal rays" in out


def test_bad_file_exit_code(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("image size\n1760,1760\n\ncamera matrix\n1,0,0\n")
    assert main(["calibration", "show", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err
