"""Tests of X-ray image loading (TIFF incl. the real LZW radiographs, DICOM, PNG)."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pydicom
import pytest
import tifffile

from biplanar_reg.annotation.image import as_display, load_image
from tests.dicom_files import new_dataset

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"


def _write_dicom(path: Path, frames: np.ndarray, photometric: str, **extra) -> None:
    ds = new_dataset(path)
    ds.PatientName = "Doe^Jane"
    ds.PatientID = "SECRET-ID-123"
    ds.Modality = "DX"
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = photometric
    ds.BitsAllocated = 16
    ds.BitsStored = 12
    ds.HighBit = 11
    ds.PixelRepresentation = 0
    if frames.ndim == 3:
        ds.NumberOfFrames = frames.shape[0]
    ds.Rows, ds.Columns = frames.shape[-2:]
    for key, val in extra.items():
        setattr(ds, key, val)
    ds.PixelData = frames.astype(np.uint16).tobytes()
    ds.save_as(path, enforce_file_format=True)


def test_real_lzw_radiograph_loads_bone_dark_on_bright():
    im = load_image(DATA / "cam01_frame0099.tif")
    assert im.size == (1760, 1760)
    assert im.file_format == "tiff"
    assert im.pixels.dtype == np.float32 and im.display.dtype == np.float32
    assert 0.0 <= im.display.min() and im.display.max() <= 1.0
    # the forearm (bone + soft tissue) near the bottom centre is darker than the open field
    forearm = im.display[1400:1500, 760:820].mean()
    field = im.display[1400:1500, 1200:1300].mean()
    assert forearm < 0.6 * field


def test_multipage_tiff_frame_choice(tmp_path):
    stack = np.stack([np.full((8, 10), k * 100, np.uint16) for k in range(3)])
    stack[:, 0, 0] = 0
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, stack, compression="lzw", photometric="minisblack")
    im = load_image(path, frame=2)
    assert im.n_frames == 3 and im.frame == 2
    assert im.pixels[5, 5] == 200
    with pytest.raises(ValueError, match=r"frame 3 out of range .*3 frame"):
        load_image(path, frame=3)


def test_dicom_monochrome1_window_and_no_identifiers(tmp_path, caplog):
    frames = np.zeros((2, 6, 8), np.uint16)
    frames[0] = 1000
    frames[1] = np.arange(48, dtype=np.uint16).reshape(6, 8) * 50
    path = tmp_path / "xray.dcm"
    _write_dicom(
        path,
        frames,
        "MONOCHROME1",
        WindowCenter=1200,
        WindowWidth=801,
        RescaleSlope=1,
        RescaleIntercept=0,
    )
    caplog.set_level(logging.DEBUG)
    im = load_image(path, frame=1)
    assert im.file_format == "dicom" and im.n_frames == 2 and im.frame == 1
    assert im.photometric == "MONOCHROME1"
    np.testing.assert_array_equal(im.pixels, frames[1].astype(float))
    # window 800..1600 (DICOM linear rule), then inverted: high values are dark
    lo, hi = 1200 - 0.5 - 400, 1200 - 0.5 + 400
    expect = 1.0 - np.clip((frames[1] - lo) / (hi - lo), 0, 1)
    np.testing.assert_allclose(im.display, expect, atol=1e-6)
    text = repr(im) + caplog.text + repr(vars(im))
    assert "Doe" not in text and "SECRET" not in text


def test_dicom_modality_rescale_monochrome2(tmp_path):
    frame = np.arange(20, dtype=np.uint16).reshape(4, 5) * 10
    path = tmp_path / "x.dcm"
    _write_dicom(path, frame, "MONOCHROME2", RescaleSlope=2, RescaleIntercept=-5)
    im = load_image(path)
    np.testing.assert_allclose(im.pixels, frame * 2.0 - 5.0)
    assert im.display[0, 0] == 0.0 and im.display[-1, -1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="frame 1 out of range"):
        load_image(path, frame=1)


def test_png_and_bad_files(tmp_path):
    img = np.zeros((5, 7), np.uint8)
    img[2, 3] = 255
    cv2.imwrite(str(tmp_path / "a.png"), img)
    im = load_image(tmp_path / "a.png")
    assert im.size == (7, 5) and im.display[2, 3] == 1.0 and im.file_format == "png"
    (tmp_path / "junk.tif").write_bytes(b"not a tiff at all")
    with pytest.raises(ValueError, match=r"junk\.tif: unreadable TIFF"):
        load_image(tmp_path / "junk.tif")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(ValueError, match=r"junk\.png: unreadable image"):
        load_image(tmp_path / "junk.png")
    (tmp_path / "junk.dcm").write_bytes(b"\0" * 10)
    with pytest.raises(ValueError, match=r"junk\.dcm: unreadable DICOM"):
        load_image(tmp_path / "junk.dcm")
    with pytest.raises(ValueError, match="image file not found"):
        load_image(tmp_path / "missing.tif")
    with pytest.raises(ValueError, match="frame: expected an integer"):
        load_image(tmp_path / "a.png", frame=0.5)


def test_as_display_normalises_arrays():
    d = as_display(np.array([[2.0, 4.0], [6.0, 10.0]]))
    np.testing.assert_allclose(d, [[0, 0.25], [0.5, 1.0]])
    with pytest.raises(ValueError, match="NaN"):
        as_display(np.array([[np.nan, 1.0], [0.0, 1.0]]))
    assert pydicom  # the DICOM writer above needs pydicom itself


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width`` x ``height`` grey pixels (and holds almost none)."""
    import struct
    import zlib

    def chunk(tag: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(tag + data))
        return struct.pack(">I", len(data)) + tag + data + crc

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * 1000)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_an_image_above_the_pixel_limit_is_refused_before_decoding(tmp_path):
    """Reproducer (issue 18): a PNG whose header claims 100000x100000 raised ``cv2.error``
    (OpenCV's own limit) after reading the file: now refused from the header, with the memory
    it would take."""
    from biplanar_reg.annotation.image import MAX_IMAGE_PIXELS

    path = tmp_path / "huge.png"
    path.write_bytes(_png_header_only(100_000, 100_000))
    with pytest.raises(
        ValueError,
        match=r"huge\.png: 100000x100000 pixels \(10000 Mpx\) is above the limit of "
        rf"{MAX_IMAGE_PIXELS // 10**6} Mpx: loading it would take about 80 GB of memory",
    ) as info:
        load_image(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("suffix", [".tif", ".dcm", ".bmp", ".jpg"])
def test_the_pixel_limit_reads_every_format_header(tmp_path, monkeypatch, suffix):
    import biplanar_reg.annotation.image as image_module

    path = tmp_path / f"a{suffix}"
    img = np.zeros((30, 40), np.uint16 if suffix in (".tif", ".dcm") else np.uint8)
    if suffix == ".tif":
        tifffile.imwrite(path, img)
    elif suffix == ".dcm":
        _write_dicom(path, img, "MONOCHROME2")
    else:
        cv2.imwrite(str(path), img)
    assert load_image(path).size == (40, 30)
    monkeypatch.setattr(image_module, "MAX_IMAGE_PIXELS", 1000)
    with pytest.raises(ValueError, match=rf"a\{suffix}: 40x30 pixels .* above the limit"):
        load_image(path)


def test_a_malformed_dicom_image_is_a_named_error(tmp_path):
    """Reproducer (issue 18): an unknown VR in a DICOM image raised ``NotImplementedError``."""
    path = tmp_path / "x.dcm"
    _write_dicom(path, np.zeros((4, 5), np.uint16), "MONOCHROME2")
    data = bytearray(path.read_bytes())
    at = data.index(b"\x28\x00\x10\x00US")  # Rows
    data[at + 4 : at + 6] = b"ZZ"
    path.write_bytes(bytes(data))
    with pytest.raises(
        ValueError, match=r"x\.dcm: unreadable DICOM: malformed DICOM \(NotImplementedError"
    ):
        load_image(path)
