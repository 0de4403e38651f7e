"""What a DICOM image that cannot be decoded says: the file and what is missing (a decoder and
how to install it, or the pixel data itself), not only "unreadable DICOM (RuntimeError)"."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.encaps import encapsulate
from pydicom.pixels import get_decoder
from pydicom.uid import ExplicitVRLittleEndian, JPEGLSLossless, generate_uid

from biplanar_reg.annotation import load_image
from biplanar_reg.cases import CaseError, load_case
from biplanar_reg.cli import main
from biplanar_reg.io.dicomfile import dicom_problem, pixel_data_problem
from biplanar_reg.simulate import write_synthetic_case

needs_no_jpegls = pytest.mark.skipif(
    get_decoder(JPEGLSLossless).is_available, reason="a JPEG-LS decoder is installed"
)


def _dicom(path: Path, syntax, pixels: bool = True, size=(8, 8)) -> Path:
    """A minimal 16-bit grey X-ray DICOM; compressed syntaxes get an encapsulated frame (not a
    valid codestream: it is never decoded without a decoder)."""
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.12.1"
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = syntax
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = meta.MediaStorageSOPClassUID
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Columns, ds.Rows = size
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 12, 11, 0
    if pixels and syntax == ExplicitVRLittleEndian:
        ds.PixelData = np.zeros(size[::-1], np.uint16).tobytes()
    elif pixels:
        ds.PixelData = encapsulate([b"\xff\xd8" + bytes(64) + b"\xff\xd9"])
        ds["PixelData"].VR = "OB"
    ds.save_as(path, enforce_file_format=True)
    return path


@needs_no_jpegls
def test_jpeg_ls_without_a_decoder_says_how_to_install_one(tmp_path):
    """Reproducer: "unreadable DICOM (RuntimeError)"."""
    path = _dicom(tmp_path / "jls.dcm", JPEGLSLossless)
    with pytest.raises(ValueError) as info:
        load_image(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    assert "needs a JPEG-LS Lossless Image Compression decoder" in msg, msg
    assert "pip install pylibjpeg pylibjpeg-libjpeg" in msg
    assert pixel_data_problem(path) in msg


def test_missing_pixel_data_says_so(tmp_path):
    """Reproducer: "unreadable DICOM (AttributeError)"."""
    path = _dicom(tmp_path / "nopix.dcm", ExplicitVRLittleEndian, pixels=False)
    with pytest.raises(ValueError) as info:
        load_image(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and "no pixel data (no PixelData element" in msg, msg
    assert pixel_data_problem(path).startswith("no pixel data (no PixelData element")


def test_a_plain_dicom_has_no_pixel_problem(tmp_path):
    path = _dicom(tmp_path / "ok.dcm", ExplicitVRLittleEndian)
    assert pixel_data_problem(path) is None
    assert load_image(path).size == (8, 8)


def test_damaged_compressed_pixel_data_names_the_decoders_that_failed(tmp_path):
    """Reproducer: "unreadable DICOM (RuntimeError)" for JPEG 2000 data pillow cannot read."""
    from pydicom.uid import JPEG2000Lossless

    if not get_decoder(JPEG2000Lossless).is_available:
        pytest.skip("no JPEG 2000 decoder installed")
    path = _dicom(tmp_path / "j2k.dcm", JPEG2000Lossless)  # not a JPEG 2000 codestream
    assert pixel_data_problem(path) is None  # a decoder is there; the data are damaged
    with pytest.raises(ValueError, match=r"pixel data that the installed decoders \(.+\) could"):
        load_image(path)


def test_dicom_problem_names_a_missing_element_and_keeps_other_messages_value_free():
    assert dicom_problem(AttributeError("'FileDataset' object has no attribute 'Rows'")) == (
        "no Rows element"
    )
    # a message that may quote element values is reduced to its type
    assert dicom_problem(RuntimeError("bad value 'DOE^JOHN'")) == "RuntimeError"


@needs_no_jpegls
def test_a_case_with_an_undecodable_dicom_image_is_refused_at_loading(tmp_path, capsys):
    """The case loader reads only the image headers; a DICOM whose pixels need a decoder that
    is not installed, or that has none, is refused before the registration runs."""
    case = write_synthetic_case(tmp_path / "c", 0, image_size=(256, 256), silhouettes=False)
    _dicom(case / "xray/cam1.dcm", JPEGLSLossless, size=(256, 256))
    text = (case / "case.toml").read_text().replace("xray/cam1.png", "xray/cam1.dcm")
    (case / "case.toml").write_text(text)
    with pytest.raises(CaseError, match=r"\[\[views\]\]\[0\] \(cam1\) image: .*cam1.dcm: needs a"):
        load_case(case)
    assert main(["register", str(case)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install pylibjpeg pylibjpeg-libjpeg" in err[0], err
    assert not (case / "out").exists()
    shutil.rmtree(case / "xray")  # a missing image is still "file not found", as before
    with pytest.raises(CaseError, match="file not found"):
        load_case(case)
