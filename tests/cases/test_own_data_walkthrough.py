"""docs/your_own_data.md, run as written: CT -> template -> case folder -> register.

The walk-through quotes what its commands printed; this test runs the same steps on the
shipped wrist data and checks the quoted figures, so the page cannot drift from the code.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from biplanar_reg.cli import main
from biplanar_reg.workbench.scaffold import NewView, scaffold_case

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "sample_cases" / "wrist_radius" / "data"
DOC = ROOT / "docs" / "your_own_data.md"
REAL = ROOT / "benchmarks" / "real_wrist"


def _quoted(pattern: str) -> re.Match[str]:
    found = re.search(pattern, DOC.read_text(encoding="utf-8"))
    assert found, f"docs/your_own_data.md no longer quotes {pattern!r}"
    return found


def _template(case: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main([
        "template", "from-ct", str(DATA / "radius_ct.tif"), "--voxel-size", "0.39625",
        "0.39625", "0.625", "--target-vertices", "2000", "-o", str(case / "model" / "radius.ply"),
    ])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    quoted = _quoted(r"# wrote radius/model/radius\.ply: (\d+) vertices, (\d+) faces")
    assert f"{quoted[1]} vertices, {quoted[2]} faces" in out


def test_walkthrough_as_documented(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    case = tmp_path / "radius"
    for sub in ("model", "calib", "xray"):
        (case / sub).mkdir(parents=True)
    for cam in ("cam01", "cam02"):
        shutil.copy(DATA / f"{cam}_calibration_mayacam2.txt", case / "calib")
        shutil.copy(DATA / f"{cam}_frame0099.tif", case / "xray")
    _template(case, capsys)
    landmarks = json.loads((REAL / "models" / "radius_landmarks.json").read_text())
    assert _quoted(r"# (\{\"radial_styloid_tip\": \d+, \"ulnar_corner\": \d+\})")[1] == (
        json.dumps(landmarks)
    )
    (case / "model" / "landmarks.json").write_text(json.dumps(landmarks))
    views = [
        NewView(c, f"calib/{c}_calibration_mayacam2.txt", f"xray/{c}_frame0099.tif")
        for c in ("cam01", "cam02")
    ]
    scaffold_case(case, model="model/radius.ply", views=views, landmarks="model/landmarks.json")
    shutil.copy(REAL / "annotations" / "radius_b.json", case / "annotations.json")
    assert main(["register", str(case), "--no-report"]) == 0
    result = json.loads((case / "out" / "result.json").read_text())
    quoted = _quoted(r"radius: done \(landmark_rms_px ([\d.]+), contour_rms_px ([\d.]+)\)")
    assert f"{result['metrics']['landmark_rms_px']:.3g}" == quoted[1]
    assert f"{result['metrics']['contour_rms_px']:.3g}" == quoted[2]
    assert result["flags"] == []
    sigmas = [g["sigma_px"] for g in result["noise"]["groups"]]
    quoted = _quoted(r"landmarks ([\d.]+) and ([\d.]+) px, outlines ([\d.]+) and ([\d.]+) px")
    assert [f"{s:.1f}" for s in sigmas] == list(quoted.groups())
