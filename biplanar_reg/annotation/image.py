"""Loading X-ray images (DICOM, TIFF, PNG, JPEG) as float arrays with display metadata.

Every loader returns an :class:`XrayImage` whose ``display`` array is what an annotator sees:
floats in [0, 1] with 0 = black, after the DICOM VOI LUT / window and after inverting
MONOCHROME1 data. The semi-automatic tools (livewire, GrabCut, snapping) work on ``display`` so
that "an edge" means the same thing on screen and in the algorithms.

Patient privacy: from a DICOM file only technical tags are copied (photometric interpretation,
window, pixel spacing, frame count); the dataset itself is dropped and nothing identifying is
stored or logged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["XrayImage", "load_image"]

log = logging.getLogger(__name__)

_TIFF_SUFFIXES = {".tif", ".tiff"}
_RASTER_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp"}
_DICOM_SUFFIXES = {".dcm", ".dicom", ".ima"}


@dataclass(frozen=True, eq=False)
class XrayImage:
    """A single-frame grey X-ray image.

    Attributes
    ----------
    pixels : (H, W) float64 array
        Stored values after the DICOM modality LUT (rescale slope/intercept); the raw grey levels
        for TIFF/PNG/JPEG. Pixel ``(u, v)`` (column, row) is ``pixels[v, u]``.
    display : (H, W) float32 array
        Display values in [0, 1], 0 = black: window / VOI LUT applied, MONOCHROME1 inverted.
    source : str
        The file the image was read from (a path; no patient data).
    file_format : str
        ``"dicom"``, ``"tiff"``, ``"png"`` or ``"jpeg"`` (``"bmp"`` for bitmaps).
    frame : int
        Which frame of a multi-frame file this is (0-based).
    n_frames : int
        Number of frames in the file.
    photometric : str
        ``"MONOCHROME1"`` (high values display dark) or ``"MONOCHROME2"``.
    window : (center, width) or None
        The linear display window applied to ``pixels``, in ``pixels`` units; ``None`` when a
        non-linear VOI LUT was used.
    pixel_spacing_mm : (row, column) spacing in mm, or None
        From DICOM (Imager/Pixel Spacing) when present; informational only (the calibration, not
        this tag, defines the geometry).
    """

    pixels: np.ndarray
    display: np.ndarray
    source: str
    file_format: str
    frame: int = 0
    n_frames: int = 1
    photometric: str = "MONOCHROME2"
    window: tuple[float, float] | None = None
    pixel_spacing_mm: tuple[float, float] | None = None

    @property
    def size(self) -> tuple[int, int]:
        """Image size ``(W, H)`` in pixels (the order used by calibrations)."""
        h, w = self.pixels.shape
        return (int(w), int(h))

    def display_uint8(self) -> np.ndarray:
        """The display image as (H, W) uint8 (0..255)."""
        return np.round(np.clip(self.display, 0.0, 1.0) * 255.0).astype(np.uint8)

    def __repr__(self) -> str:  # short: never dump arrays (or anything else) into logs
        w, h = self.size
        return (
            f"XrayImage({Path(self.source).name!r}, {w}x{h}, {self.file_format}, "
            f"frame {self.frame}/{self.n_frames}, {self.photometric})"
        )


def as_display(image: XrayImage | np.ndarray, name: str = "image") -> np.ndarray:
    """Return a (H, W) float64 display array in [0, 1] from an XrayImage or a 2D array.

    A plain array is min-max normalised (a constant array becomes zeros).
    """
    if isinstance(image, XrayImage):
        return image.display.astype(np.float64)
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        arr = arr[..., :3].mean(axis=2)
    if arr.ndim != 2 or min(arr.shape) < 2:
        raise ValueError(f"{name}: expected a 2D grey image, got shape {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    lo, hi = float(arr.min()), float(arr.max())
    return (arr - lo) / (hi - lo) if hi > lo else np.zeros_like(arr)


def _window_display(pixels: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if hi <= lo:
        return np.zeros(pixels.shape, np.float32)
    return np.clip((pixels - lo) / (hi - lo), 0.0, 1.0).astype(np.float32)


def _grey_from_planes(arr: np.ndarray, path: Path) -> np.ndarray:
    """Reduce (H, W), (H, W, 3|4) arrays to (H, W); reject anything else."""
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        rgb = arr[..., :3].astype(np.float64)
        if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]):
            return rgb[..., 0]
        log.info("%s: colour image converted to grey (luma)", path.name)
        return rgb @ np.array([0.299, 0.587, 0.114])
    if arr.ndim != 2:
        raise ValueError(f"{path}: expected a 2D grey image, got array of shape {arr.shape}")
    return arr.astype(np.float64)


def _integer_range(dtype: np.dtype, data: np.ndarray) -> tuple[float, float]:
    """Display range of a non-DICOM image: the full range of its integer type, else min/max."""
    if np.issubdtype(dtype, np.integer) and dtype.itemsize == 1:
        info = np.iinfo(dtype)
        return float(info.min), float(info.max)
    # 16-bit radiographs rarely use the full 0..65535 range: show min..max instead
    return float(np.min(data)), float(np.max(data))


def _check_frame(path: Path, frame: int, n_frames: int) -> None:
    if not 0 <= frame < n_frames:
        raise ValueError(f"{path}: frame {frame} out of range (the file has {n_frames} frame(s))")


def _load_tiff(path: Path, frame: int) -> XrayImage:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            shape = series.shape
            # a multi-page grey stack is (pages, H, W); an RGB page is (H, W, 3)
            is_stack = len(shape) == 3 and shape[-1] not in (3, 4) or len(shape) == 4
            n_frames = int(shape[0]) if is_stack else 1
            _check_frame(path, frame, n_frames)
            arr = series.asarray(key=frame) if is_stack else series.asarray()
    except ValueError as exc:
        if "frame" in str(exc) and str(path) in str(exc):
            raise
        raise ValueError(f"{path}: unreadable TIFF ({exc})") from None
    except (OSError, tifffile.TiffFileError, IndexError, KeyError) as exc:
        raise ValueError(f"{path}: unreadable TIFF ({exc})") from None
    pixels = _grey_from_planes(np.asarray(arr), path)
    lo, hi = _integer_range(np.asarray(arr).dtype, pixels)
    return XrayImage(
        pixels=pixels,
        display=_window_display(pixels, lo, hi),
        source=str(path),
        file_format="tiff",
        frame=frame,
        n_frames=n_frames,
        window=((lo + hi) / 2.0, hi - lo),
    )


def _load_raster(path: Path, frame: int) -> XrayImage:
    import cv2

    _check_frame(path, frame, 1)
    data = np.fromfile(path, dtype=np.uint8)  # imdecode: no silent None on odd paths
    arr = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if arr is None:
        raise ValueError(f"{path}: unreadable image (not a valid PNG/JPEG/BMP file)")
    if arr.ndim == 3:  # OpenCV decodes colour as BGR(A)
        arr = arr[..., [2, 1, 0]] if arr.shape[2] == 3 else arr[..., [2, 1, 0, 3]]
    pixels = _grey_from_planes(arr, path)
    lo, hi = _integer_range(arr.dtype, pixels)
    fmt = "jpeg" if path.suffix.lower() in {".jpg", ".jpeg"} else path.suffix.lower()[1:]
    return XrayImage(
        pixels=pixels,
        display=_window_display(pixels, lo, hi),
        source=str(path),
        file_format=fmt,
        window=((lo + hi) / 2.0, hi - lo),
    )


def _first_float(value: object) -> float | None:
    """First element of a DICOM multi-value (or the value itself) as float."""
    if value is None:
        return None
    try:
        seq = list(value)  # type: ignore[call-overload]
    except TypeError:
        seq = [value]
    try:
        return float(seq[0]) if seq else None
    except (TypeError, ValueError):
        return None


def _load_dicom(path: Path, frame: int) -> XrayImage:
    import pydicom
    from pydicom.errors import InvalidDicomError
    from pydicom.pixels import apply_modality_lut, apply_voi_lut

    try:
        ds = pydicom.dcmread(path)
        n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        _check_frame(path, frame, n_frames)
        arr = ds.pixel_array
    except ValueError as exc:
        if "frame" in str(exc) and str(path) in str(exc):
            raise
        raise ValueError(f"{path}: unreadable DICOM pixel data ({type(exc).__name__})") from None
    except (InvalidDicomError, OSError, AttributeError, KeyError, RuntimeError) as exc:
        # the exception text of pydicom never contains element values, only tags/structure
        raise ValueError(f"{path}: unreadable DICOM ({type(exc).__name__}: {exc})") from None
    photometric = str(getattr(ds, "PhotometricInterpretation", "MONOCHROME2")).strip()
    if photometric not in ("MONOCHROME1", "MONOCHROME2"):
        raise ValueError(
            f"{path}: PhotometricInterpretation {photometric!r} is not a grey X-ray "
            "(expected MONOCHROME1 or MONOCHROME2)"
        )
    if n_frames > 1:
        arr = arr[frame]
    if arr.ndim != 2:
        raise ValueError(f"{path}: expected 2D frames, got pixel array of shape {arr.shape}")
    pixels = np.asarray(apply_modality_lut(arr, ds), dtype=np.float64)
    window: tuple[float, float] | None = None
    center = _first_float(getattr(ds, "WindowCenter", None))
    width = _first_float(getattr(ds, "WindowWidth", None))
    if "VOILUTSequence" in ds:
        voi = np.asarray(apply_voi_lut(pixels, ds, index=0), dtype=np.float64)
        lo, hi = float(voi.min()), float(voi.max())
        display = _window_display(voi, lo, hi)
    else:
        if center is not None and width is not None and width > 1:
            lo, hi = center - 0.5 - (width - 1) / 2, center - 0.5 + (width - 1) / 2
        else:
            lo, hi = float(pixels.min()), float(pixels.max())
        window = ((lo + hi) / 2.0, hi - lo)
        display = _window_display(pixels, lo, hi)
    if photometric == "MONOCHROME1":  # high values are dark on screen
        display = (1.0 - display).astype(np.float32)
    spacing = getattr(ds, "ImagerPixelSpacing", None) or getattr(ds, "PixelSpacing", None)
    pixel_spacing = None
    if spacing is not None and len(spacing) == 2:
        pixel_spacing = (float(spacing[0]), float(spacing[1]))
    return XrayImage(
        pixels=pixels,
        display=display,
        source=str(path),
        file_format="dicom",
        frame=frame,
        n_frames=n_frames,
        photometric=photometric,
        window=window,
        pixel_spacing_mm=pixel_spacing,
    )


def _sniff(path: Path) -> str:
    """Pick a loader from the suffix, else from the file's first bytes."""
    suffix = path.suffix.lower()
    if suffix in _TIFF_SUFFIXES:
        return "tiff"
    if suffix in _RASTER_SUFFIXES:
        return "raster"
    if suffix in _DICOM_SUFFIXES:
        return "dicom"
    with path.open("rb") as fh:
        head = fh.read(132)
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return "tiff"
    if head[128:132] == b"DICM":
        return "dicom"
    return "raster"


def load_image(path: str | Path, frame: int = 0) -> XrayImage:
    """Load one frame of an X-ray image.

    Parameters
    ----------
    path : str or Path
        A DICOM (``.dcm`` or a file with the ``DICM`` preamble), TIFF (any compression that
        ``tifffile``/``imagecodecs`` read, LZW included), PNG, JPEG or BMP file.
    frame : int
        Which frame of a multi-frame DICOM or multi-page TIFF to load (0-based).

    Returns
    -------
    XrayImage
        Pixel values, display image and metadata; pixel ``(u, v)`` is ``pixels[v, u]``.

    Raises
    ------
    ValueError
        The file is missing or unreadable, the frame does not exist, or the image is not grey.
    """
    path = Path(path)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)):
        raise ValueError(f"frame: expected an integer, got {frame!r}")
    if not path.is_file():
        raise ValueError(f"{path}: image file not found")
    kind = _sniff(path)
    if kind == "tiff":
        return _load_tiff(path, int(frame))
    if kind == "dicom":
        return _load_dicom(path, int(frame))
    return _load_raster(path, int(frame))
