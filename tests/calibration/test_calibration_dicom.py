"""DICOM X-ray geometry on synthetic datasets built here with pydicom: reader and writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pydicom
import pytest
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration import (
    OrthographicView,
    PerspectiveView,
    detect_format,
    load_calibration,
    save_calibration,
)
from biplanar_reg.calibration.dicom_geometry import beam_direction, write_dicom_geometry
from biplanar_reg.cli import main

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"

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
        ((), {"PatientOrientation": ["LR", "F"]}, "PatientOrientation.*opposite"),
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


# ---------------------------------------------------------------------------------------------
# writer


def _scene(seed: int = 3) -> np.ndarray:
    """Random points (mm) around the isocentre, all in front of every source used here."""
    return np.random.default_rng(seed).uniform(-120, 120, (200, 3))


@pytest.mark.parametrize(
    ("primary", "secondary"),
    [(0.0, 0.0), (30.0, -20.0), (-135.5, 42.25), (90.0, 0.0), (179.0, -89.0), (12.3456789, 90.0)],
)
@pytest.mark.parametrize("orientation", [None, ["R", "F"], ["L", "H"], ["R", "H"]])
def test_roundtrip_load_save_load(
    tmp_path: Path, primary: float, secondary: float, orientation: list[str] | None
) -> None:
    over = {"PositionerPrimaryAngle": primary, "PositionerSecondaryAngle": secondary}
    if orientation is not None:
        over["PatientOrientation"] = orientation
    over["ImagerPixelSpacing"] = [0.21, SP]  # non-square pixels: fy != fx
    view = load_calibration(_write(tmp_path, **over))
    out = tmp_path / "out.dcm"
    save_calibration(view, out, "dicom")
    assert detect_format(out) == "dicom"
    back = load_calibration(out)
    X = _scene()
    assert np.abs(back.project(X) - view.project(X)).max() < 1e-6
    assert back.image_size == view.image_size == (800, 1000)
    assert np.sign(back.K[0, 0]) == np.sign(view.K[0, 0])  # mirrored stays mirrored
    np.testing.assert_allclose(back.centre, view.centre, atol=1e-9)
    ds = pydicom.dcmread(out)
    assert float(ds.DistanceSourceToPatient) == SOD
    if abs(secondary) < 90:  # at the pole the primary angle is only defined up to a flip
        assert float(ds.PositionerPrimaryAngle) == pytest.approx(primary, abs=1e-9)
    assert float(ds.PositionerSecondaryAngle) == pytest.approx(secondary, abs=1e-9)


def test_mirrored_flag_follows_orientation(tmp_path: Path) -> None:
    # the default AP readout is mirrored; R/F is not - the writer must keep both apart
    mirrored = load_calibration(_write(tmp_path, name="a.dcm"))
    plain = load_calibration(_write(tmp_path, name="b.dcm", PatientOrientation=["R", "F"]))
    assert mirrored.K[0, 0] < 0 < plain.K[0, 0]
    for view, letters in ((mirrored, ["L", "F"]), (plain, ["R", "F"])):
        save_calibration(view, tmp_path / "o.dcm", "dicom")
        assert list(pydicom.dcmread(tmp_path / "o.dcm").PatientOrientation) == letters


def test_written_file_is_a_minimal_xa_image(tmp_path: Path) -> None:
    view = load_calibration(_write(tmp_path, PositionerPrimaryAngle=-25.0))
    out = tmp_path / "o.dcm"
    save_calibration(view, out, "dicom")
    ds = pydicom.dcmread(out)  # no force=True: preamble, DICM and file meta are present
    assert ds.file_meta.TransferSyntaxUID == pydicom.uid.DeflatedExplicitVRLittleEndian
    assert ds.SOPClassUID == ds.file_meta.MediaStorageSOPClassUID
    assert ds.SOPClassUID == pydicom.uid.XRayAngiographicImageStorage
    assert ds.SOPInstanceUID == ds.file_meta.MediaStorageSOPInstanceUID
    assert ds.Modality == "XA"
    px = ds.pixel_array
    assert px.shape == (1000, 800) and not px.any()  # all-zero placeholder of the view's size
    assert out.stat().st_size < 20_000  # deflated


def test_written_file_has_no_patient_identifiers(tmp_path: Path) -> None:
    src = _write(tmp_path, PatientOrientation=["R", "F"])
    view = load_calibration(src, name="Secret")
    out = tmp_path / "o.dcm"
    save_calibration(view, out, "dicom")
    ds = pydicom.dcmread(out)
    for key in ("PatientName", "PatientID", "PatientBirthDate", "PatientSex"):
        assert key in ds and not ds[key].value  # type 2: present, empty
    values = " ".join(str(e.value) for e in ds.iterall() if e.keyword != "PixelData")
    values += " ".join(str(e.value) for e in ds.file_meta)
    for secret in ("Secret", "12345"):
        assert secret not in values
        assert secret.encode() not in out.read_bytes()
    assert b"Secret" in src.read_bytes()  # the check above can fail


def _representable() -> PerspectiveView:
    return PerspectiveView(
        K=np.array([[-6000.0, 0, 511.5], [0, 6000.0, 383.5], [0, 0, 1]]),
        R=np.array([[-1.0, 0, 0], [0, 0, -1], [0, -1, 0]]),  # AP, source posterior
        t=np.array([0.0, 0.0, 800.0]),
        image_size=(1024, 768),
    )


def _modified(**kw) -> PerspectiveView:
    v = _representable()
    args = {"K": v.K, "R": v.R, "t": v.t, "image_size": v.image_size, **kw}
    return PerspectiveView(**args)


@pytest.mark.parametrize(
    ("view", "match"),
    [
        (_modified(K=_representable().K + [[0, 0, 0.5], [0, 0, 0], [0, 0, 0]]), "principal point"),
        (_modified(K=_representable().K + [[0, 2.0, 0], [0, 0, 0], [0, 0, 0]]), "skew"),
        (_modified(t=np.array([0.0, 1.0, 800.0])), "isocentre.*central ray"),
        (_representable(), None),
        (_modified(distortion=[0.1, 0, 0, 0]), "distortion"),
        (_modified(image_size=None), "image_size"),
        (_modified(t=np.array([0.0, 0.0, -800.0])), "not in front of the source"),
        (
            OrthographicView(K=np.eye(3), R=np.eye(3), t=np.zeros(3), image_size=(10, 10)),
            "orthographic view cannot be written",
        ),
    ],
)
def test_not_representable_raises_and_writes_nothing(
    tmp_path: Path, view: object, match: str | None
) -> None:
    out = tmp_path / "o.dcm"
    out.write_bytes(b"previous")
    if match is None:
        save_calibration(view, out, "dicom")  # control: the unmodified view is representable
        assert detect_format(out) == "dicom"
        return
    with pytest.raises(ValueError, match=match):
        save_calibration(view, out, "dicom")
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["o.dcm"]  # no temporary file left


def test_in_plane_rotation_is_not_representable(tmp_path: Path) -> None:
    base = _representable()
    # turn the detector 0.5 deg about the beam (camera z): no positioner angle does that
    turn = Rotation.from_rotvec([0, 0, np.radians(0.5)]).as_matrix()
    with pytest.raises(ValueError, match=r"turned 0\.5 deg about the beam"):
        save_calibration(_modified(R=turn @ base.R), tmp_path / "o.dcm", "dicom")
    assert not list(tmp_path.iterdir())


def test_detector_distance_option(tmp_path: Path) -> None:
    view = _representable()
    write_dicom_geometry(view, tmp_path / "a.dcm", source_detector_distance=1000.0)
    ds = pydicom.dcmread(tmp_path / "a.dcm")
    assert float(ds.DistanceSourceToDetector) == 1000.0
    # a DICOM decimal string holds at most 16 characters: 0.16666666666667
    assert [float(x) for x in ds.ImagerPixelSpacing] == [pytest.approx(1 / 6, rel=1e-13)] * 2
    X = _scene()
    assert np.abs(load_calibration(tmp_path / "a.dcm").project(X) - view.project(X)).max() < 1e-6
    with pytest.raises(ValueError, match="source_detector_distance=700.0 mm must exceed"):
        write_dicom_geometry(view, tmp_path / "b.dcm", source_detector_distance=700.0)
    assert not (tmp_path / "b.dcm").exists()


def test_cli_convert_json_to_dicom(tmp_path: Path, capsys) -> None:
    view = load_calibration(
        _write(tmp_path, PositionerPrimaryAngle=40.0, PositionerSecondaryAngle=15.0)
    )
    save_calibration(view, tmp_path / "cam.json", "json")
    out = tmp_path / "cam.dcm"
    argv = ["calibration", "convert", str(tmp_path / "cam.json"), str(out), "--to", "dicom"]
    assert main(argv) == 0
    X = _scene()
    assert np.abs(load_calibration(out).project(X) - view.project(X)).max() < 1e-6
    # a real lab calibration (free pose, principal point off-centre) is refused: exit 2
    capsys.readouterr()
    bad_out = tmp_path / "wrist.dcm"
    argv = ["calibration", "convert", str(DATA / "cam01_calibration_mayacam2.txt"), str(bad_out)]
    assert main([*argv, "--to", "dicom"]) == 2
    assert "not representable in DICOM" in capsys.readouterr().err
    assert not bad_out.exists()


def _element_at(data: bytes, group: int, elem: int, vr: bytes) -> int:
    """Offset of an explicit-VR little-endian element header (tag, VR) in a file's bytes."""
    return data.index(group.to_bytes(2, "little") + elem.to_bytes(2, "little") + vr)


@pytest.mark.parametrize(
    ("damage", "match"),
    [
        ("unknown VR", r"malformed DICOM \(NotImplementedError: .*tag \(0028,0010\)"),
        ("odd length", r"malformed DICOM \(BytesLengthException, tag \(0028,0010\)\)"),
    ],
)
def test_malformed_dicom_is_a_named_error(tmp_path: Path, damage: str, match: str, caplog) -> None:
    """Reproducer (issue 18): pydicom's ``NotImplementedError`` ("Unknown Value Representation")
    and ``BytesLengthException`` escaped ``load_calibration``: tracebacks. The message names
    the file and the tag, never an element's value (pydicom's own message quotes raw bytes)."""
    path = _write(tmp_path)
    data = bytearray(path.read_bytes())
    at = _element_at(data, 0x0028, 0x0010, b"US")  # Rows
    if damage == "unknown VR":
        data[at + 4 : at + 6] = b"ZZ"
    else:  # a US value of 3 bytes: Rows swallows the first byte of the next element
        data[at + 6 : at + 8] = (3).to_bytes(2, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=match) as exc:
        load_calibration(path, "dicom")
    text = str(exc.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    assert "Secret" not in text and "12345" not in text and "received" not in text
    assert "Secret" not in caplog.text and "12345" not in caplog.text


def test_dicom_warnings_quoting_patient_data_are_not_shown(tmp_path: Path, caplog, recwarn):
    """A damaged meta header makes pydicom warn with the raw bytes that follow it (the
    patient's name among them): the reader keeps those warnings and log records to itself."""
    path = _write(tmp_path)
    data = bytearray(path.read_bytes())
    at = _element_at(data, 0x0002, 0x0010, b"UI")  # TransferSyntaxUID: its length grows
    data[at + 6 : at + 8] = (165).to_bytes(2, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError):
        load_calibration(path, "dicom")
    assert "Secret" not in caplog.text
    assert not any("Secret" in str(w.message) for w in recwarn)
