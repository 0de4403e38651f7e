"""DICOM series, TIFF and NPY volume reading (biplanar_reg.io.volumes)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pydicom
import pytest
import tifffile
from pydicom.data import get_testdata_file
from pydicom.uid import generate_uid

from biplanar_reg.io.volumes import read_dicom_series, read_volume

CT_SMALL = get_testdata_file("CT_small.dcm")


def _write_series(folder: Path, n: int = 5, step: float = 2.5, skip: tuple[int, ...] = ()) -> list:
    """A series from pydicom's bundled CT slice, shifted along the slice normal.

    Files are named in reverse order of position so the reader must sort by position.
    """
    folder.mkdir(parents=True, exist_ok=True)
    base = pydicom.dcmread(CT_SMALL)
    iop = np.array(base.ImageOrientationPatient, dtype=float)
    normal = np.cross(iop[:3], iop[3:])
    pos0 = np.array(base.ImagePositionPatient, dtype=float)
    series_uid = generate_uid()
    written = []
    for k in range(n):
        if k in skip:
            continue
        ds = copy.deepcopy(base)
        ds.SeriesInstanceUID = series_uid
        ds.SOPInstanceUID = generate_uid()
        ds.ImagePositionPatient = [f"{x:.4f}" for x in pos0 + k * step * normal]
        ds.RescaleIntercept = -1024
        ds.RescaleSlope = 1
        # Distinct pixel content per slice so the order can be checked.
        pixels = base.pixel_array.copy()
        pixels[0, 0] = k
        ds.PixelData = pixels.tobytes()
        path = folder / f"img{n - k:03d}.dcm"
        ds.save_as(path, enforce_file_format=True)
        written.append(path)
    return written


def test_dicom_series_sorted_rescaled_and_affine(tmp_path):
    _write_series(tmp_path / "s", n=5, step=2.5)
    vol = read_dicom_series(tmp_path / "s")
    base = pydicom.dcmread(CT_SMALL)
    assert vol.data.shape == (5, base.Rows, base.Columns)
    assert vol.units == "HU"
    # Sorted along the normal: the marker pixel counts 0..4, rescale applied (-1024).
    np.testing.assert_array_equal(vol.data[:, 0, 0], np.arange(5) - 1024.0)
    np.testing.assert_allclose(vol.data[0, 5, 7], float(base.pixel_array[5, 7]) - 1024.0)
    ps = np.array(base.PixelSpacing, dtype=float)
    np.testing.assert_allclose(vol.voxel_size, [ps[1], ps[0], 2.5], atol=1e-3)
    np.testing.assert_allclose(vol.affine[:3, 3], np.array(base.ImagePositionPatient, float))
    # Voxel (i, j, k) of slice k maps to its slice's ImagePositionPatient + in-plane offsets.
    iop = np.array(base.ImageOrientationPatient, dtype=float)
    expect = np.array(base.ImagePositionPatient, float) + 3 * ps[1] * iop[:3] + 2 * ps[0] * iop[3:]
    expect = expect + 4 * 2.5 * np.cross(iop[:3], iop[3:])
    np.testing.assert_allclose(vol.to_mm([[3, 2, 4]])[0], expect, atol=1e-3)


def test_dicom_without_transfer_syntax_uses_fallback(tmp_path):
    files = _write_series(tmp_path / "s", n=3)
    # Strip the transfer syntax from one file's meta header; it must still be read.
    ds = pydicom.dcmread(files[0])
    del ds.file_meta.TransferSyntaxUID
    ds.save_as(files[0], enforce_file_format=False)
    assert "TransferSyntaxUID" not in pydicom.dcmread(files[0], force=True).file_meta
    vol = read_volume(tmp_path / "s")
    assert vol.data.shape[0] == 3


def test_dicom_bad_inputs_name_the_file(tmp_path):
    _write_series(tmp_path / "junk", n=3)
    (tmp_path / "junk" / "notes.txt").write_text("not dicom")
    with pytest.raises(ValueError, match=r"notes\.txt: not a DICOM file"):
        read_dicom_series(tmp_path / "junk")

    _write_series(tmp_path / "gap", n=6, skip=(3,))
    with pytest.raises(ValueError, match=r"1 missing slice\(s\) between img004\.dcm and img002"):
        read_dicom_series(tmp_path / "gap")

    files = _write_series(tmp_path / "uneven", n=5)
    ds = pydicom.dcmread(files[1])  # position index 1 -> move it off the regular grid
    pos = np.array(ds.ImagePositionPatient, dtype=float)
    iop = np.array(ds.ImageOrientationPatient, dtype=float)
    ds.ImagePositionPatient = [f"{x:.4f}" for x in pos + 0.8 * np.cross(iop[:3], iop[3:])]
    ds.save_as(files[1])
    with pytest.raises(ValueError, match="inconsistent slice spacing between img"):
        read_dicom_series(tmp_path / "uneven")

    _write_series(tmp_path / "mixed", n=3)
    other = _write_series(tmp_path / "other", n=2)
    for p in other:
        p.rename(tmp_path / "mixed" / f"b_{p.name}")
    with pytest.raises(
        ValueError, match=r"mixed: mixed series in one folder.*(3 files.*2 files|2 files.*3 files)"
    ):
        read_dicom_series(tmp_path / "mixed")


def test_tiff_and_npy_need_voxel_size(tmp_path):
    arr = np.arange(4 * 5 * 6, dtype=np.uint16).reshape(4, 5, 6)
    tifffile.imwrite(tmp_path / "v.tif", arr, photometric="minisblack")
    np.save(tmp_path / "v.npy", arr)
    with pytest.raises(ValueError, match=r"v\.tif: voxel_size .* is required"):
        read_volume(tmp_path / "v.tif")
    for name in ("v.tif", "v.npy"):
        vol = read_volume(tmp_path / name, voxel_size=(0.5, 0.6, 2.0))
        np.testing.assert_array_equal(vol.data, arr)
        np.testing.assert_allclose(vol.voxel_size, [0.5, 0.6, 2.0])
        np.testing.assert_allclose(vol.to_mm([[1, 1, 1]]), [[0.5, 0.6, 2.0]])
    with pytest.raises(ValueError, match=r"voxel_size\[y\]"):
        read_volume(tmp_path / "v.npy", voxel_size=(1, 0, 1))
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError, match=r"obj\.npy: cannot read"):
        read_volume(tmp_path / "obj.npy", voxel_size=(1, 1, 1))
    np.save(tmp_path / "flat.npy", np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"flat\.npy: expected a 3-D volume"):
        read_volume(tmp_path / "flat.npy", voxel_size=(1, 1, 1))


def test_a_malformed_slice_is_a_named_error(tmp_path):
    """Issue 18: pydicom parses values lazily, so a damaged element (here an unknown VR in
    ``Rows``) failed later with ``NotImplementedError`` wherever the value was first used; the
    reader now converts every element at once and names the file and tag."""
    files = _write_series(tmp_path / "s", n=3)
    data = bytearray(files[1].read_bytes())
    at = data.index(b"\x28\x00\x10\x00US")  # Rows, explicit VR little endian
    data[at + 4 : at + 6] = b"ZZ"
    files[1].write_bytes(bytes(data))
    with pytest.raises(
        ValueError,
        match=rf"{files[1].name}: cannot read as DICOM \(malformed DICOM \(NotImplementedError",
    ):
        read_dicom_series(tmp_path / "s")
