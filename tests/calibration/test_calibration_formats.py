"""Calibration readers/writers: round-trips, detection, and clear errors on bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration import (
    OrthographicView,
    PerspectiveView,
    SlotScanningView,
    detect_format,
    load_calibration,
    save_calibration,
)
from biplanar_reg.calibration.dlt import format_dlt_csv

W, H = 1024, 768
RNG = np.random.default_rng(7)


def _pinhole(seed: int, *, fy_equal: bool = False, skew: float = 0.0, distortion=None):
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    C = rng.normal(size=3) * 40 - rng.uniform(800, 1400) * R[2]
    f = rng.uniform(3000, 7000)
    fy = f if fy_equal else f * rng.uniform(0.99, 1.01)
    K = np.array([[f, skew, rng.uniform(400, 600)], [0, fy, rng.uniform(300, 450)], [0, 0, 1]])
    return PerspectiveView(
        K=K, R=R, t=-R @ C, image_size=(W, H), distortion=distortion, name=f"cam{seed}"
    )


def _scene() -> np.ndarray:
    return RNG.uniform(-50, 50, (100, 3))


def _roundtrip(view, tmp_path: Path, fmt: str, **load_kw):
    path = tmp_path / f"{view.name}_{fmt}.txt"
    save_calibration(view, path, fmt)
    assert detect_format(path) == fmt
    return load_calibration(path, **load_kw)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize(
    ("fmt", "kw"),
    [("mayacam2", {}), ("json", {}), ("dlt", {"image_size": (W, H)}), ("mayacam1", {})],
)
def test_roundtrip_projections_identical(tmp_path: Path, seed: int, fmt: str, kw: dict) -> None:
    # MayaCam 1.0 holds one focal length and no skew: test it on views it can represent
    view = _pinhole(seed, fy_equal=fmt == "mayacam1", skew=0.0 if fmt == "mayacam1" else 1.5)
    back = _roundtrip(view, tmp_path, fmt, **kw)
    X = _scene()
    assert np.abs(back.project(X) - view.project(X)).max() < 1e-6
    assert back.image_size == view.image_size
    np.testing.assert_allclose(back.centre, view.centre, atol=1e-6)


@pytest.mark.parametrize("fmt", ["mayacam2", "json"])
def test_roundtrip_with_distortion(tmp_path: Path, fmt: str) -> None:
    dist = [-0.1, 0.02, 1e-3, -5e-4, 0.003, 0.01, -0.002, 0.0005]
    view = _pinhole(4, distortion=dist)
    back = _roundtrip(view, tmp_path, fmt)
    X = _scene()
    assert np.abs(back.project(X) - view.project(X)).max() < 1e-6
    np.testing.assert_array_equal(back.distortion, view.distortion)


@pytest.mark.parametrize(
    "view",
    [
        OrthographicView(
            K=np.array([[3.0, 0.1, 500.0], [0, 3.2, 400.0], [0, 0, 1]]),
            R=Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix(),
            t=np.array([1.0, 2.0, 3.0]),
            image_size=(W, H),
            name="ortho",
        ),
        SlotScanningView(
            fu=5200.0,
            cu=512.0,
            cv=380.0,
            row_pitch=0.2,
            R=Rotation.from_rotvec([0.1, 1.2, -0.3]).as_matrix(),
            t=np.array([5.0, -3.0, 1300.0]),
            image_size=(W, H),
            name="eos",
        ),
    ],
    ids=["orthographic", "slot_scanning"],
)
def test_json_roundtrip_other_kinds(tmp_path: Path, view) -> None:
    back = _roundtrip(view, tmp_path, "json")
    assert type(back) is type(view)
    X = _scene()
    assert np.abs(back.project(X) - view.project(X)).max() < 1e-6


def test_mayacam2_accepts_comma_separated_translation_and_undistortion(tmp_path: Path) -> None:
    view = _pinhole(5, distortion=[-0.1, 0.02, 1e-3, -5e-4, 0.003, 0.0, 0.0, 0.0])
    text = (
        f"image size\n{W},{H}\n\ncamera matrix\n"
        + "\n".join(",".join(repr(float(x)) for x in r) for r in view.K)
        + "\n\nrotation\n"
        + "\n".join(",".join(repr(float(x)) for x in r) for r in view.R)
        + "\n\ntranslation\n"
        + ",".join(repr(float(x)) for x in view.t)
        + "\n\nundistortion\n"
        + ",".join(repr(float(x)) for x in view.distortion)
        + "\n"
    )
    path = tmp_path / "cam.txt"
    path.write_text(text)
    back = load_calibration(path)
    X = _scene()
    assert np.abs(back.project(X) - view.project(X)).max() < 1e-6


def test_merged_dlt_columns(tmp_path: Path) -> None:
    from biplanar_reg.calibration.dlt import dlt_from_view

    views = [_pinhole(6), _pinhole(7)]
    path = tmp_path / "DLTcoefs.csv"
    path.write_text(format_dlt_csv([dlt_from_view(v) for v in views]))
    with pytest.raises(ValueError, match="2 cameras.*dlt_column"):
        load_calibration(path, image_size=(W, H))
    X = _scene()
    for i, v in enumerate(views):
        back = load_calibration(path, dlt_column=i + 1, image_size=(W, H))
        assert np.abs(back.project(X) - v.project(X)).max() < 1e-6
        assert back.name == f"cam{i + 1}"
    with pytest.raises(ValueError, match="dlt_column=3"):
        load_calibration(path, dlt_column=3, image_size=(W, H))
    with pytest.raises(ValueError, match="image size"):
        load_calibration(path, dlt_column=1)


def test_writers_refuse_what_the_format_cannot_hold(tmp_path: Path) -> None:
    ortho = OrthographicView(K=np.eye(3), R=np.eye(3), t=np.zeros(3), image_size=(W, H))
    with pytest.raises(ValueError, match="orthographic view cannot be written"):
        save_calibration(ortho, tmp_path / "o.txt", "mayacam2")
    dist = _pinhole(8, distortion=[0.1, 0, 0, 0])
    with pytest.raises(ValueError, match="distortion"):
        save_calibration(dist, tmp_path / "d.csv", "dlt")
    with pytest.raises(ValueError, match="distortion"):
        save_calibration(dist, tmp_path / "d1.csv", "mayacam1")
    with pytest.raises(ValueError, match="skew"):
        save_calibration(_pinhole(9, skew=3.0), tmp_path / "s.csv", "mayacam1")
    with pytest.raises(ValueError, match="not representable in DICOM"):
        save_calibration(_pinhole(9), tmp_path / "x", "dicom")
    with pytest.raises(ValueError, match="unknown calibration format"):
        save_calibration(_pinhole(9), tmp_path / "y", "bmp")
    assert not list(tmp_path.iterdir())  # nothing half-written


def format_mayacam2_text(view) -> str:
    from biplanar_reg.calibration.mayacam import format_mayacam2

    return format_mayacam2(view)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda ls: ls[:12], r"missing the 'translation' block"),
        (lambda ls: ls[:5] + ["6167.3,zero,803.7"] + ls[6:], r"line 6 \(camera matrix\).*'zero'"),
        (lambda ls: ls[:9] + ["0.9,0,0"] + ls[10:], "not orthonormal"),
        (lambda ls: ls[:4] + ["0,0,512", "0,4000,384"] + ls[6:], "zero focal"),
        (lambda ls: ["camera parameters"] + ls[1:], r"line 1: expected the 'image size'"),
        (lambda ls: ls[:1] + ["1024"] + ls[2:], r"line 2 \(image size row 1\): expected 2"),
        (lambda ls: ls[:15] + ls[16:], "'translation' has 2 number"),
    ],
    ids=[
        "truncated",
        "non-numeric",
        "not-orthonormal",
        "zero-focal",
        "garbled-header",
        "short-size",
        "short-translation",
    ],
)
def test_bad_mayacam2_files(tmp_path: Path, edit, match: str) -> None:
    lines = format_mayacam2_text(_pinhole(10)).splitlines()
    path = tmp_path / "bad.txt"
    path.write_text("\n".join(edit(lines)) + "\n")
    with pytest.raises(ValueError, match=match) as exc:
        load_calibration(path, "mayacam2")
    assert str(path) in str(exc.value)


@pytest.mark.parametrize(
    ("text", "fmt", "match"),
    [
        ("1,2,3\n4,5,6\n7,8,9\n", "mayacam1", "5 lines of 3 numbers"),
        (
            "1,2,3\n4,5,6\n7,8,9\n800,600,abc\n0.1,1024,768\n",
            "mayacam1",
            r"line 4 \(u0, v0, Z\): 'abc'",
        ),
        ("1,2,3\n4,5,6\n7,8,9\n800,600,0\n0.1,1024,768\n", "mayacam1", "zero focal"),
        ("\n".join(["1,2"] * 10) + "\n", "dlt", "11 numeric rows"),
        ("\n".join(["1,2"] * 10 + ["1"]) + "\n", "dlt", "line 11: 1 column"),
        (
            '{"K": [[1,0,0],[0,1,0],[0,0,1]], "R": [[1,0,0],[0,1,0],[0,0,1]]}',
            "json",
            "missing key 't'",
        ),
        (
            '{"K": [[1,0,0],[0,1,0],[0,0,1]], "R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,0,1],'
            ' "projection": "fisheye"}',
            "json",
            "key 'projection'",
        ),
        (
            '{"K": [[1,0,0],[0,1,0],[0,0,1]], "R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,"a",1]}',
            "json",
            "t: ",
        ),
        ('{"K": [[1,0,0', "json", "not valid JSON"),
    ],
)
def test_bad_other_files(tmp_path: Path, text: str, fmt: str, match: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as exc:
        load_calibration(path, fmt, image_size=(W, H) if fmt == "dlt" else None)
    assert str(path) in str(exc.value)


def test_undetectable_and_missing_files(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("hello\nworld\n")
    with pytest.raises(ValueError, match="cannot detect"):
        load_calibration(path)
    with pytest.raises(FileNotFoundError):
        load_calibration(tmp_path / "nope.txt")
    (tmp_path / "bin.dat").write_bytes(b"\xff\xfe\x00\x81" * 40)
    with pytest.raises(ValueError, match="not a text file|cannot detect"):
        load_calibration(tmp_path / "bin.dat")


def test_json_unknown_key_warns(tmp_path: Path, caplog) -> None:
    view = _pinhole(11)
    path = tmp_path / "c.json"
    save_calibration(view, path, "json")
    data = json.loads(path.read_text())
    data["colour"] = "blue"
    path.write_text(json.dumps(data))
    load_calibration(path)
    assert "unknown key 'colour'" in caplog.text


@pytest.mark.parametrize(
    ("size", "shown"),
    [
        ("[Infinity, 512]", r"\[inf, 512\]"),
        ("[1e400, 512]", r"\[inf, 512\]"),
        ("[NaN, 512]", r"\[nan, 512\]"),
        ("[512.5, 512]", r"\[512\.5, 512\]"),
        ('["wide", 512]', r"\['wide', 512\]"),
    ],
)
def test_a_non_integer_image_size_in_json_is_a_named_error(
    tmp_path: Path, size: str, shown: str
) -> None:
    """Reproducer (issue 18): ``"image_size": [Infinity, 512]`` raised ``OverflowError``
    (``int(inf)``), a traceback; 512.5 was silently truncated to 512."""
    path = tmp_path / "c.json"
    save_calibration(_pinhole(12), path, "json")
    text = path.read_text()
    start = text.index('"image_size": [')
    end = text.index("]", start) + 1
    path.write_text(text[:start] + f'"image_size": {size}' + text[end:])
    with pytest.raises(
        ValueError,
        match=rf"c\.json: image_size: expected two positive whole "
        rf"numbers \(W, H\), got {shown}",
    ) as exc:
        load_calibration(path)
    assert "\n" not in str(exc.value)


def test_deeply_nested_json_calibration_is_a_named_error(tmp_path: Path) -> None:
    path = tmp_path / "deep.json"
    path.write_text('{"K": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ValueError, match=r"deep\.json: not valid JSON \(nested too deeply"):
        load_calibration(path, "json")


def test_an_image_size_above_the_pixel_limit_is_a_named_error(tmp_path: Path) -> None:
    """Found by tests/test_fuzz_parsers.py: a MayaCam 1.0 width of 1e40 raised ``TypeError``;
    an image size is now at most ``MAX_IMAGE_PIXELS`` (its outlines are rasterised)."""
    path = tmp_path / "c.txt"
    save_calibration(_pinhole(13, fy_equal=True), path, "mayacam1")
    lines = path.read_text().splitlines()
    for size, shown in (("1e40,768", "1" + "0" * 16), ("100000,100000", "100000x100000")):
        lines[4] = f"0.1,{size}"
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(ValueError, match=rf"c\.txt: image_size: {shown}.* is above the limit"):
            load_calibration(path)
