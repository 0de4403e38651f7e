"""The one case pipeline (``biplanar_reg.cases.pipeline.write_bone``): a bone in one frame and
a bone over frames take the same path: the result and the meshes first (``on_written``), then
the report; the registration's failures as one-line errors; the patient identifiers of every
frame's images with ``include_phi``.

The outputs themselves are checked against the sample cases' expectations by
tests/cases/test_sample_cases.py.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from biplanar_reg.cases import CaseError, CaseFailure, bone_fit, load_case, run_case_dir
from biplanar_reg.cases.case import to_frame_observations
from biplanar_reg.cases.documents import dicom_identifiers
from biplanar_reg.errors import SolverFailure
from biplanar_reg.simulate import write_synthetic_case
from tests.dicom_files import new_dataset

SAMPLES = Path(__file__).resolve().parents[2] / "sample_cases"
FRAMES_CASE = SAMPLES / "wrist_radius_frames"


@pytest.fixture(scope="module")
def one_frame(tmp_path_factory) -> Path:
    """A small synthetic case of one bone in one frame (no silhouettes: fast)."""
    root = tmp_path_factory.mktemp("one_frame")
    return write_synthetic_case(root / "k1", 1, image_size=(192, 192), silhouettes=False)


@pytest.fixture(scope="module")
def frames_case(tmp_path_factory) -> Path:
    """A copy of the sample case of one bone over three frames."""
    dst = tmp_path_factory.mktemp("frames") / FRAMES_CASE.name
    return Path(shutil.copytree(FRAMES_CASE, dst, ignore=shutil.ignore_patterns("out")))


@pytest.mark.parametrize("which", ["one_frame", "frames_case"])
def test_on_written_sees_the_result_before_the_report(which, request, tmp_path):
    """``on_written`` gets the outcome when ``out`` holds the result and the meshes and no
    report yet; the report follows, and ``result.json`` then says where it is."""
    case = request.getfixturevalue(which)
    out = tmp_path / "out"
    seen = []

    def written(outcome):
        doc = json.loads((outcome.out_dir / "result.json").read_text())
        files = sorted(p.name for p in outcome.out_dir.iterdir())
        seen.append((files, doc["report"], outcome.result.report))

    outcome = run_case_dir(case, out, on_written=written)
    ((files, doc_report, result_report),) = seen
    assert "registered.ply" in files and "result.json" in files and "report.html" not in files
    assert doc_report is None and result_report is None
    assert ("registered_model.ply" in files) == (which == "frames_case")
    doc = json.loads((out / "result.json").read_text())
    assert (out / "report.html").is_file() and doc["report"]["html"] == "report.html"
    assert outcome.result.report == doc["report"]
    assert outcome.result.shape["frames"] == (["0"] if which == "one_frame" else ["f0", "f1", "f2"])


@pytest.mark.parametrize("which", ["one_frame", "frames_case"])
def test_registration_failures_are_one_line_errors(which, request, monkeypatch):
    """The library's failures: a solver or numerical failure is a :class:`CaseFailure`, a
    rejected input a :class:`CaseError` naming the case file and its table."""
    case = load_case(request.getfixturevalue(which))
    frames = to_frame_observations(case)
    entry = "register_frames" if case.frames else "register_views"
    table = "[[frames]]" if case.frames else "[registration]"
    for exc, kind, text in [
        (SolverFailure("no convergence"), CaseFailure, "registration failed: no convergence"),
        (
            np.linalg.LinAlgError("singular"),
            CaseFailure,
            "registration failed (numerical): singular",
        ),
        (ValueError("bad\n  input"), CaseError, f"{table}: bad input"),
    ]:

        def fail(*args, exc=exc, **kwargs):
            raise exc

        monkeypatch.setattr(bone_fit, entry, fail)
        with pytest.raises(kind) as err:
            bone_fit.fit_bone(case, frames, lambda msg: None)
        assert str(err.value) == f"{case.case_file}: {text}"


def _dicom(path: Path, patient: str) -> Path:
    """A minimal DICOM file (no pixels) with a patient name."""
    ds = new_dataset(path)
    ds.PatientName = patient
    ds.save_as(path, enforce_file_format=True)
    return path


def test_patient_identifiers_of_every_frame(tmp_path):
    """``include_phi``: the identifiers of the DICOM images of the case's views and of every
    frame's, each file once, by path relative to the case folder; other files are skipped."""
    first, later = _dicom(tmp_path / "f0.dcm", "Doe^Jane"), _dicom(tmp_path / "f1.dcm", "Roe^Ann")
    png = tmp_path / "f0.png"
    png.write_bytes(b"not an image")

    def views(*paths):
        return [SimpleNamespace(image_path=p, calibration=None) for p in paths]

    case = SimpleNamespace(
        case_dir=tmp_path,
        views=views(first, png),
        frames=[SimpleNamespace(views=views(first, png)), SimpleNamespace(views=views(later))],
    )
    assert dicom_identifiers(case) == {
        "f0.dcm": {"PatientName": "Doe^Jane"},
        "f1.dcm": {"PatientName": "Roe^Ann"},
    }
    assert dicom_identifiers(SimpleNamespace(case_dir=tmp_path, views=views(png), frames=[])) == {}
