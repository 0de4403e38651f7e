"""Read CT volumes: DICOM series (pydicom), multi-page TIFF stacks and ``.npy`` arrays.

A :class:`Volume` holds the voxel array indexed ``data[k, j, i]`` (slice, row, column) and a
4x4 ``affine`` that maps homogeneous voxel indices ``(i, j, k, 1)`` (column, row, slice; 0-based,
at voxel centres) to millimetres. For DICOM the millimetre frame is the patient frame (LPS) of
the series; for TIFF and NPY it is the voxel grid scaled by the given voxel size, origin at the
centre of voxel (0, 0, 0).

DICOM fallback for files without a transfer syntax in their meta header (or without a meta
header at all, e.g. some older exports): the file is read with ``force=True`` and its transfer
syntax is set from the encoding pydicom detected while parsing (implicit VR little endian, the
DICOM default, or explicit VR little/big endian). Patient identifiers are never read into
messages or logs; errors name files and tags only.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import as_array, check_positive
from .dicomfile import DicomReadError, dicom_problem, quiet_pydicom, read_dicom

__all__ = ["Volume", "read_dicom_series", "read_volume"]

log = logging.getLogger(__name__)

_TIFF_SUFFIXES = (".tif", ".tiff")


@dataclass(frozen=True)
class Volume:
    """A scalar volume with its voxel-to-mm affine.

    Attributes
    ----------
    data : (K, J, I) array
        Voxel values indexed (slice, row, column); Hounsfield units for CT DICOM (rescale
        applied), raw intensities otherwise.
    affine : (4, 4) array
        Maps ``(i, j, k, 1)`` = (column, row, slice, 1) voxel indices to mm.
    units : str
        ``"HU"`` or ``"intensity"``.
    source : str
        Where the volume came from (a path), for messages.
    """

    data: np.ndarray
    affine: np.ndarray
    units: str = "intensity"
    source: str = "<array>"
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def voxel_size(self) -> np.ndarray:
        """Spacing along (column, row, slice), mm."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    def to_mm(self, ijk: np.ndarray) -> np.ndarray:
        """Map voxel indices (N, 3) ordered (i, j, k) = (column, row, slice) to mm (N, 3)."""
        ijk = np.asarray(ijk, dtype=float)
        return ijk @ self.affine[:3, :3].T + self.affine[:3, 3]


def grid_affine(voxel_size: object, name: str = "voxel_size") -> np.ndarray:
    """Affine of an axis-aligned grid with spacing (x, y, z) = (column, row, slice) mm."""
    vs = as_array(name, voxel_size, (3,))
    for axis, value in zip("xyz", vs, strict=True):
        check_positive(f"{name}[{axis}]", value)
    affine = np.eye(4)
    affine[:3, :3] = np.diag(vs)
    return affine


def read_volume(
    path: str | os.PathLike, voxel_size: object | None = None, series: str | None = None
) -> Volume:
    """Read a CT volume from a DICOM series folder, a multi-page TIFF or a ``.npy`` file.

    Parameters
    ----------
    path : path-like
        A folder of DICOM files (one series), a ``.tif``/``.tiff`` stack (pages = slices) or a
        ``.npy`` array (K, J, I) (slice, row, column).
    voxel_size : (3,) array_like, optional
        Spacing (x, y, z) = (column, row, slice), mm. Required for TIFF and NPY (they carry
        no reliable spacing); for DICOM it overrides nothing and must be left out.
    series : str, optional
        For a DICOM folder holding several series: the SeriesNumber (or SeriesInstanceUID) to read.
    """
    path = Path(path)
    if path.is_dir():
        if voxel_size is not None:
            raise ValueError(f"{path}: voxel_size is taken from the DICOM headers; leave it out")
        return read_dicom_series(path, series=series)
    if not path.is_file():
        raise ValueError(f"{path}: file or folder not found")
    suffix = path.suffix.lower()
    if suffix not in (*_TIFF_SUFFIXES, ".npy"):
        raise ValueError(
            f"{path}: unsupported volume format {suffix!r} (a DICOM series folder, .tif/.tiff "
            "or .npy); a DICOM series is read from its folder"
        )
    if voxel_size is None:
        raise ValueError(f"{path}: voxel_size (x, y, z) in mm is required for {suffix} volumes")
    affine = grid_affine(voxel_size)
    try:
        if suffix == ".npy":
            data = np.load(path, allow_pickle=False)
        else:
            import tifffile

            data = tifffile.imread(path)
    except Exception as exc:  # parser errors of any kind are bad input
        raise ValueError(f"{path}: cannot read as {suffix[1:].upper()} ({exc})") from None
    if data.ndim != 3 or min(data.shape) < 2:
        raise ValueError(
            f"{path}: expected a 3-D volume (slices, rows, columns) with at least 2 voxels "
            f"per axis, got shape {data.shape}"
        )
    if not (np.issubdtype(data.dtype, np.integer) or np.issubdtype(data.dtype, np.floating)):
        raise ValueError(f"{path}: voxel type {data.dtype} is not numeric")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path}: contains NaN or infinite voxels")
    return Volume(data=data, affine=affine, units="intensity", source=str(path))


# -- DICOM ---------------------------------------------------------------------------------------
def _read_dicom_file(path: Path):  # -> pydicom.Dataset
    from pydicom.uid import ExplicitVRBigEndian, ExplicitVRLittleEndian, ImplicitVRLittleEndian

    try:
        ds = read_dicom(path)
    except DicomReadError as exc:
        if not exc.reason.startswith("not a DICOM file"):
            raise ValueError(f"{path}: cannot read as DICOM ({exc.reason})") from None
        # No preamble / 'DICM' prefix: maybe a raw dataset without meta header (documented
        # fallback); accept it only if it parses into an image with a position.
        try:
            ds = read_dicom(path, force=True)
        except DicomReadError:
            raise ValueError(f"{path}: not a DICOM file") from None
        if "PixelData" not in ds or "ImagePositionPatient" not in ds:
            raise ValueError(f"{path}: not a DICOM file (or not an image)") from None
    if "TransferSyntaxUID" not in ds.file_meta:
        if ds.original_encoding[0]:  # implicit VR: only little endian exists
            ds.file_meta.TransferSyntaxUID = ImplicitVRLittleEndian
        elif ds.original_encoding[1]:
            ds.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
        else:
            ds.file_meta.TransferSyntaxUID = ExplicitVRBigEndian
        log.info(
            "%s: no transfer syntax in the meta header; using %s",
            path.name,
            ds.file_meta.TransferSyntaxUID.name,
        )
    return ds


def _floats(ds, tag: str, n: int, path: Path) -> np.ndarray:
    if tag not in ds or ds[tag].value is None:
        raise ValueError(f"{path}: missing DICOM tag {tag}")
    try:
        values = np.array([float(x) for x in ds[tag].value], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: DICOM tag {tag} is not numeric") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: DICOM tag {tag} should hold {n} numbers, got {ds[tag].value}")
    return values


#: one slice of a series: its file and its pydicom Dataset (imported lazily, hence Any)
_Slice = tuple[Path, Any]


def _series_files(folder: Path) -> list[Path]:
    """The files of a DICOM series folder, sorted by name.

    Hidden files and ``DICOMDIR`` are skipped. Raises ``ValueError`` when ``folder`` is not a
    folder or holds no other file.
    """
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    files = sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.name.upper() != "DICOMDIR"
    )
    if not files:
        raise ValueError(f"{folder}: no files in the DICOM series folder")
    return files


def _select_series(folder: Path, datasets: list[_Slice], series: str | None) -> list[_Slice]:
    """Keep the ``(path, dataset)`` pairs of one series (grouped by SeriesInstanceUID).

    A folder holding several series needs ``series`` (a SeriesNumber or SeriesInstanceUID)
    matching exactly one of them; a folder of one series must match ``series`` when given.

    Raises
    ------
    ValueError
        Mixed series without ``series``, ``series`` not found or ambiguous, or fewer than 2
        slices left; the message summarises the series found (numbers, counts, a file name).
    """
    groups: dict[str, list[_Slice]] = {}
    for p, ds in datasets:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((p, ds))
    if len(groups) > 1:
        summary = "; ".join(
            f"SeriesNumber {items[0][1].get('SeriesNumber', '?')}: {len(items)} files "
            f"(e.g. {items[0][0].name})"
            for items in groups.values()
        )
        if series is None:
            raise ValueError(f"{folder}: mixed series in one folder ({summary}); choose one")
        chosen = [
            items
            for uid, items in groups.items()
            if str(series) in (uid, str(items[0][1].get("SeriesNumber", "")))
        ]
        if len(chosen) != 1:
            raise ValueError(f"{folder}: series {series!r} not found or ambiguous ({summary})")
        datasets = chosen[0]
    elif series is not None and str(datasets[0][1].get("SeriesNumber", "")) != str(series):
        raise ValueError(f"{folder}: series {series!r} not found")
    if len(datasets) < 2:
        raise ValueError(f"{folder}: a volume needs at least 2 slices, found {len(datasets)}")
    return datasets


@dataclass(frozen=True, eq=False)
class _SliceGeometry:
    """Geometry shared by the slices of a series (patient frame, LPS, mm).

    Attributes
    ----------
    row_dir, col_dir : (3,) arrays
        Unit directions along an image row (increasing column) and along a column (increasing
        row), from ImageOrientationPatient.
    normal : (3,) array
        ``cross(row_dir, col_dir)``, the slice normal.
    pixel_spacing : (2,) array
        PixelSpacing: (row spacing, column spacing), mm.
    positions : (N, 3) array
        ImagePositionPatient of each slice (centre of its first pixel), mm, in file order.
    """

    row_dir: np.ndarray
    col_dir: np.ndarray
    normal: np.ndarray
    pixel_spacing: np.ndarray
    positions: np.ndarray


def _slice_geometry(datasets: list[_Slice]) -> _SliceGeometry:
    """Read and cross-check the geometry of the ``(path, dataset)`` slices of one series.

    The first slice's ImageOrientationPatient must be two orthonormal directions (to 1e-3);
    every slice must be single-frame and share the first one's orientation and PixelSpacing
    (to 1e-4) and image size (Rows, Columns). Raises ``ValueError`` naming the file.
    """
    p0, ds0 = datasets[0]
    iop0 = _floats(ds0, "ImageOrientationPatient", 6, p0)
    row_dir, col_dir = iop0[:3], iop0[3:]
    normal = np.cross(row_dir, col_dir)
    if abs(np.linalg.norm(normal) - 1.0) > 1e-3 or abs(row_dir @ col_dir) > 1e-3:
        raise ValueError(f"{p0}: ImageOrientationPatient is not two orthonormal directions")
    spacing0 = _floats(ds0, "PixelSpacing", 2, p0)
    shape0 = (int(ds0.get("Rows", 0)), int(ds0.get("Columns", 0)))
    positions = []
    for p, ds in datasets:
        if int(ds.get("NumberOfFrames", 1) or 1) > 1:
            raise ValueError(f"{p}: multi-frame DICOM is not supported (one slice per file)")
        if np.max(np.abs(_floats(ds, "ImageOrientationPatient", 6, p) - iop0)) > 1e-4:
            raise ValueError(f"{p}: ImageOrientationPatient differs from {p0.name}")
        if np.max(np.abs(_floats(ds, "PixelSpacing", 2, p) - spacing0)) > 1e-4:
            raise ValueError(f"{p}: PixelSpacing differs from {p0.name}")
        if (int(ds.get("Rows", 0)), int(ds.get("Columns", 0))) != shape0:
            raise ValueError(f"{p}: image size differs from {p0.name}")
        positions.append(_floats(ds, "ImagePositionPatient", 3, p))
    return _SliceGeometry(row_dir, col_dir, normal, spacing0, np.array(positions))


def _check_slice_steps(folder: Path, depth: np.ndarray, names: list[str]) -> None:
    """Check that the sorted slice depths (mm along the normal) are evenly spaced.

    Raises ``ValueError`` naming the two files of the first pair at the same position (step
    below 1e-3 mm), or of the first step off the median by more than max(0.01 mm, 5 %) (told
    as missing slices when it is close to a whole multiple of the median step).
    """
    steps = np.diff(depth)
    dup = np.flatnonzero(steps < 1e-3)
    if dup.size:
        i = int(dup[0])
        raise ValueError(f"{folder}: {names[i]} and {names[i + 1]} are at the same slice position")
    step = float(np.median(steps))
    bad = np.flatnonzero(np.abs(steps - step) > max(0.01, 0.05 * step))
    if bad.size:
        i = int(bad[0])
        ratio = steps[i] / step
        kind = (
            f"{round(ratio) - 1} missing slice(s)"
            if ratio > 1.5 and abs(ratio - round(ratio)) < 0.1
            else "inconsistent slice spacing"
        )
        raise ValueError(
            f"{folder}: {kind} between {names[i]} and {names[i + 1]} "
            f"(step {steps[i]:.4g} mm, typical {step:.4g} mm)"
        )


def _stack_slices(datasets: list[_Slice]) -> np.ndarray:
    """Decode the slices' pixels and apply RescaleSlope / RescaleIntercept (float32, (K, J, I)).

    Raises ``ValueError`` naming a file whose pixel data cannot be decoded.
    """
    slices = []
    for p, ds in datasets:
        try:
            with quiet_pydicom():
                pixels = ds.pixel_array.astype(np.float32)
        except Exception as exc:  # noqa: BLE001 - pydicom and its decoders raise anything
            raise ValueError(f"{p}: cannot decode the pixel data ({dicom_problem(exc)})") from None
        slope = float(ds.get("RescaleSlope", 1.0) or 1.0)
        intercept = float(ds.get("RescaleIntercept", 0.0) or 0.0)
        slices.append(pixels * np.float32(slope) + np.float32(intercept))
    return np.stack(slices)


def _series_affine(geometry: _SliceGeometry) -> np.ndarray:
    """Voxel (i, j, k, 1) -> patient mm affine of slices sorted along the normal.

    The slice axis is the mean step between the first and last slice positions, so a gantry
    tilt (positions not along the normal) is honoured.
    """
    row_dir, col_dir, spacing = geometry.row_dir, geometry.col_dir, geometry.pixel_spacing
    positions = geometry.positions
    affine = np.eye(4)
    affine[:3, 0] = row_dir * spacing[1]  # column index i moves along the row direction
    affine[:3, 1] = col_dir * spacing[0]  # row index j moves along the column direction
    affine[:3, 2] = (positions[-1] - positions[0]) / (len(positions) - 1)
    affine[:3, 3] = positions[0]
    return affine


def read_dicom_series(folder: str | os.PathLike, series: str | None = None) -> Volume:
    """Read one DICOM series (a folder of single-frame slices) into a :class:`Volume` in HU.

    Slices are sorted by their position along the slice normal
    (``cross(row direction, column direction)`` from ImageOrientationPatient); the affine uses
    PixelSpacing and the measured slice step (so gantry tilt is honoured); RescaleSlope and
    RescaleIntercept are applied per slice.

    Parameters
    ----------
    folder : path-like
        Folder of DICOM files. Hidden files and ``DICOMDIR`` are skipped; any other non-DICOM
        file is an error.
    series : str, optional
        SeriesNumber (or SeriesInstanceUID) to read when the folder holds several series.

    Raises
    ------
    ValueError
        Non-DICOM files, mixed series (without ``series``), differing orientation / size /
        pixel spacing, duplicate positions, missing slices or inconsistent slice spacing; the
        message names the file(s).
    """
    folder = Path(folder)
    datasets = [(p, _read_dicom_file(p)) for p in _series_files(folder)]
    datasets = _select_series(folder, datasets, series)
    geometry = _slice_geometry(datasets)
    ds0 = datasets[0][1]  # the first file (by name) of the series names the modality
    depth = geometry.positions @ geometry.normal
    order = np.argsort(depth, kind="stable")
    datasets = [datasets[i] for i in order]
    geometry = replace(geometry, positions=geometry.positions[order])
    names = [p.name for p, _ in datasets]
    _check_slice_steps(folder, depth[order], names)
    data = _stack_slices(datasets)
    units = "HU" if str(ds0.get("Modality", "")) == "CT" else "intensity"
    return Volume(
        data=data,
        affine=_series_affine(geometry),
        units=units,
        source=str(folder),
        meta={"files": names, "modality": str(ds0.get("Modality", ""))},
    )
