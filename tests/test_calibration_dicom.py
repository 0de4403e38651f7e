"""DICOM X-ray geometry on synthetic datasets built here with pydicom."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid

from biplanar_reg.calibration import detect_format, load_calibration
from biplanar_reg.calibration.dicom_geometry import beam_direction

SID, SOD, SP = 1200.0, 800.0, 0.2  # mm, mm, mm per pixel at the detector


def _write(tmp_path: Path, name: str = "xa.dcm", drop: tuple[str, ...] = (), **over) -> Path:
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.12.1"  # XA image storage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    path = tmp_path / name
    ds = FileDataset(str(path), {}, file_meta=meta, preamble=b"\0" * 128)
    ds.PatientName = "Secret^Patient"
    ds.PatientID = "ID-12345"
    ds.Modality = "XA"
    values = {
        "Rows": 1000,
        "Columns": 800,
        "DistanceSourceToDetector": SID,
        "DistanceSourceToPatient": SOD,
        "ImagerPixelSpacing": [SP, SP],
        "PositionerPrimaryAngle": 0.0,
        "PositionerSecondaryAngle": 0.0,
        **over,
    }
    for key, val in values.items():
        if key not in drop:
            setattr(ds, key, val)
    ds.save_as(path, enforce_file_format=True)
    return path


def test_ap_geometry(tmp_path: Path) -> None:
    path = _write(tmp_path)
    assert detect_format(path) == "dicom"
    v = load_calibration(path)
    np.testing.assert_allclose(v.centre, [0.0, SOD, 0.0], atol=1e-9)  # source posterior
    np.testing.assert_allclose(v.principal_ray, [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(v.project(np.zeros(3)), [[399.5, 499.5]], atol=1e-9)
    # 10 mm to the patient's left / towards the feet, at the isocentre: magnified by SID/SOD
    uv = v.project(np.array([[10.0, 0, 0], [0, 0, -10.0]]))
    step = 10 * SID / SOD / SP
    np.testing.assert_allclose(uv, [[399.5 + step, 499.5], [399.5, 499.5 + step]], atol=1e-9)
    assert v.K[0, 0] < 0  # the L/F readout is a mirror image of the pinhole view


def test_oblique_angles_and_orientation(tmp_path: Path) -> None:
    v = load_calibration(
        _write(
            tmp_path,
            PositionerPrimaryAngle=30.0,
            PositionerSecondaryAngle=-20.0,
            PatientOrientation=["R", "F"],
        )
    )
    d = beam_direction(30.0, -20.0)
    np.testing.assert_allclose(
        d,
        [
            np.sin(np.radians(30)) * np.cos(np.radians(20)),
            -np.cos(np.radians(30)) * np.cos(np.radians(20)),
            -np.sin(np.radians(20)),
        ],
        atol=1e-12,
    )
    np.testing.assert_allclose(v.principal_ray, d, atol=1e-12)
    np.testing.assert_allclose(v.centre, -SOD * d, atol=1e-9)
    assert v.K[0, 0] > 0  # R/F is not mirrored
    # rays and projections agree
    uv = np.array([[10.0, 20.0], [700.0, 900.0]])
    o, dirs = v.rays(uv)
    np.testing.assert_allclose(v.project(o + 900 * dirs), uv, atol=1e-8)


def test_pixel_spacing_fallback(tmp_path: Path, caplog) -> None:
    path = _write(tmp_path, drop=("ImagerPixelSpacing",), PixelSpacing=[0.25, 0.25])
    v = load_calibration(path)
    assert abs(abs(v.K[0, 0]) - SID / 0.25) < 1e-9
    assert "PixelSpacing" in caplog.text
    assert "Secret" not in caplog.text and "12345" not in caplog.text


@pytest.mark.parametrize(
    ("drop", "over", "match"),
    [
        (("DistanceSourceToDetector",), {}, r"missing DICOM tag DistanceSourceToDetector"),
        (("PositionerPrimaryAngle",), {}, r"PositionerPrimaryAngle \(0018,1510\)"),
        (("ImagerPixelSpacing",), {}, r"missing DICOM tag ImagerPixelSpacing"),
        ((), {"DistanceSourceToPatient": 1500.0}, "must be smaller"),
        ((), {"PatientOrientation": ["X", "F"]}, "PatientOrientation"),
    ],
)
def test_bad_dicom(tmp_path: Path, drop: tuple, over: dict, match: str) -> None:
    path = _write(tmp_path, drop=drop, **over)
    with pytest.raises(ValueError, match=match) as exc:
        load_calibration(path)
    assert str(path) in str(exc.value)
    assert "Secret" not in str(exc.value)


def test_not_dicom(tmp_path: Path) -> None:
    path = tmp_path / "fake.dcm"
    path.write_text("image size\n")
    with pytest.raises(ValueError, match="not a DICOM file"):
        load_calibration(path, "dicom")
