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
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.views import MAX_IMAGE_PIXELS as _VIEW_MAX_IMAGE_PIXELS
from ..io.dicomfile import DicomReadError, dicom_problem, quiet_pydicom, read_dicom

__all__ = ["XrayImage", "load_image", "read_image_size"]

log = logging.getLogger(__name__)

#: Largest image (one frame, W x H pixels) :func:`load_image` decodes; a larger one is refused
#: from its header, before any decoding, with the memory it would take. 100 Mpx is more than
#: any radiograph detector gives (a 43 cm plate at 50 um is 8600 x 8600 = 74 Mpx). The same
#: limit as the image size a calibration may declare (:mod:`biplanar_reg.calibration.views`).
MAX_IMAGE_PIXELS = _VIEW_MAX_IMAGE_PIXELS
#: Memory an :class:`XrayImage` holds per pixel: float32 ``pixels`` and float32 ``display``
#: (the decoding needs the file's own samples, e.g. 2 bytes for 16-bit, while it runs).
BYTES_PER_PIXEL = 8

_TIFF_SUFFIXES = {".tif", ".tiff"}
_RASTER_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp"}
_DICOM_SUFFIXES = {".dcm", ".dicom", ".ima"}


@dataclass(frozen=True, eq=False)
class XrayImage:
    """A single-frame grey X-ray image.

    Attributes
    ----------
    pixels : (H, W) float32 array
        Stored values after the DICOM modality LUT (rescale slope/intercept); the raw grey levels
        for TIFF/PNG/JPEG (exact for integer samples of up to 24 bits; float32 rather than
        float64 halves the memory of a large radiograph). Pixel ``(u, v)`` (column, row) is
        ``pixels[v, u]``.
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
    """``(pixels - lo) / (hi - lo)`` clipped to [0, 1], float32, with one temporary array."""
    if hi <= lo:
        return np.zeros(pixels.shape, np.float32)
    out = np.subtract(pixels, np.float32(lo), dtype=np.float32)
    out *= np.float32(1.0 / (hi - lo))
    return np.clip(out, 0.0, 1.0, out=out)


def _grey_from_planes(arr: np.ndarray, path: Path) -> np.ndarray:
    """Reduce (H, W), (H, W, 3|4) arrays to (H, W); reject anything else."""
    if arr.size == 0:
        raise ValueError(f"{path}: the image has no pixels (array of shape {arr.shape})")
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        rgb = arr[..., :3]
        if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]):
            return rgb[..., 0].astype(np.float32)
        log.info("%s: colour image converted to grey (luma)", path.name)
        return (rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)).astype(
            np.float32
        )
    if arr.ndim != 2:
        raise ValueError(f"{path}: expected a 2D grey image, got array of shape {arr.shape}")
    return arr.astype(np.float32)


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


def check_pixel_count(path: Path | str, width: int, height: int) -> None:
    """Refuse an image of more than :data:`MAX_IMAGE_PIXELS`, saying what it would take.

    Raises
    ------
    ValueError
        ``<path>: <W>x<H> pixels (<n> Mpx) is above the limit of ... Mpx: loading it would
        take about <m> GB of memory ...``.
    """
    n = int(width) * int(height)
    if n > MAX_IMAGE_PIXELS:
        gb = n * BYTES_PER_PIXEL / 1e9
        raise ValueError(
            f"{path}: {width}x{height} pixels ({n / 1e6:g} Mpx) is above the limit of "
            f"{MAX_IMAGE_PIXELS / 1e6:g} Mpx: loading it would take about {gb:.3g} GB of memory "
            f"({BYTES_PER_PIXEL} bytes per pixel; biplanar_reg.annotation.image.MAX_IMAGE_PIXELS)"
        )


def _raster_size(head: bytes) -> tuple[int, int] | None:
    """``(W, H)`` from the header of a PNG, BMP or JPEG file, ``None`` if not recognised."""
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24 and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])
    if head[:2] == b"BM" and len(head) >= 26:
        if struct.unpack("<I", head[14:18])[0] == 12:  # OS/2 BITMAPCOREHEADER
            return struct.unpack("<HH", head[18:22])
        w, h = struct.unpack("<ii", head[18:26])
        return abs(w), abs(h)
    if head[:2] == b"\xff\xd8":
        return _jpeg_size(head)
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """``(W, H)`` from the first start-of-frame segment of a JPEG stream."""
    i = 2
    while i + 9 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return w, h
        if marker == 0xDA:  # start of scan: no frame header before it
            return None
        i += 2 + struct.unpack(">H", data[i + 2 : i + 4])[0]
    return None


@contextmanager
def _quiet(name: str) -> Iterator[None]:
    """Mute the logger ``name`` (tifffile logs every damaged tag; the error says it all)."""
    logger = logging.getLogger(name)
    disabled, logger.disabled = logger.disabled, True
    try:
        yield
    finally:
        logger.disabled = disabled


def _tiff_page(path: Path, frame: int, decode: bool) -> tuple[tuple[int, int], int, Any]:
    """``((W, H), n_frames, pixels or None)`` of one TIFF page, read page by page (not through
    tifffile's series: a damaged header can make the series analysis run for minutes; a
    multi-page stack is one frame per page); every failure is a ``ValueError`` naming ``path``."""
    import tifffile

    try:
        with _quiet("tifffile"), tifffile.TiffFile(path) as tif:
            n_frames = len(tif.pages)
            _check_frame(path, frame, n_frames)
            page = tif.pages[frame]
            shape = tuple(page.shape)
            if not (len(shape) == 2 or len(shape) == 3 and shape[-1] in (3, 4)):
                raise ValueError(f"{path}: expected a 2D grey image, got a page of shape {shape}")
            check_pixel_count(path, shape[1], shape[0])
            arr = page.asarray() if decode else None
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: unreadable TIFF ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - tifffile/imagecodecs raise anything on bad bytes
        raise ValueError(f"{path}: unreadable TIFF ({type(exc).__name__}: {exc})") from None
    return (int(shape[1]), int(shape[0])), n_frames, arr


def _load_tiff(path: Path, frame: int) -> XrayImage:
    _, n_frames, arr = _tiff_page(path, frame, decode=True)
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
    try:
        data = np.fromfile(path, dtype=np.uint8)  # imdecode: no silent None on odd paths
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    size = _raster_size(data[:65536].tobytes())
    if size is not None:
        check_pixel_count(path, *size)
    try:
        arr = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    except cv2.error as exc:  # e.g. OpenCV's own size limits, a header it cannot parse
        msg = " ".join(str(exc).split())[-120:]
        raise ValueError(f"{path}: unreadable image (OpenCV: {msg})") from None
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


def _pixel_spacing(value: object) -> tuple[float, float] | None:
    """(row, column) spacing from a DICOM value, or None when it is not two positive numbers
    (informational only: a bad tag is ignored, not an error)."""
    try:
        row, col = (float(x) for x in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        return None
    return (row, col) if np.isfinite([row, col]).all() and min(row, col) > 0 else None


def _load_dicom(path: Path, frame: int) -> XrayImage:
    from pydicom.pixels import apply_modality_lut, apply_voi_lut

    try:
        ds = read_dicom(path)
    except DicomReadError as exc:  # "malformed DICOM (...)", "not a DICOM file (...)"
        raise ValueError(f"{path}: unreadable DICOM: {exc.reason}") from None
    try:
        n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        _check_frame(path, frame, n_frames)
        check_pixel_count(path, int(ds.Columns), int(ds.Rows))
        with quiet_pydicom():
            arr = ds.pixel_array
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: unreadable DICOM pixel data ({type(exc).__name__})") from None
    except Exception as exc:  # noqa: BLE001 - pydicom and its decoders raise anything
        raise ValueError(f"{path}: unreadable DICOM ({dicom_problem(exc)})") from None
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
    pixels = np.asarray(apply_modality_lut(arr, ds), dtype=np.float32)
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
    pixel_spacing = _pixel_spacing(spacing)
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


def _checked(path: str | Path, frame: object) -> tuple[Path, str]:
    """The arguments of :func:`load_image`/:func:`read_image_size` checked; the loader kind."""
    path = Path(path)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)):
        raise ValueError(f"frame: expected an integer, got {frame!r}")
    if not path.is_file():
        raise ValueError(f"{path}: image file not found")
    return path, _sniff(path)


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
    path, kind = _checked(path, frame)
    if kind == "tiff":
        return _load_tiff(path, int(frame))
    if kind == "dicom":
        return _load_dicom(path, int(frame))
    return _load_raster(path, int(frame))


def _dicom_size(path: Path, frame: int) -> tuple[int, int]:
    try:
        ds = read_dicom(path, stop_before_pixels=True)
        n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        size = (int(ds.Columns), int(ds.Rows))
    except DicomReadError as exc:
        raise ValueError(f"{path}: unreadable DICOM: {exc.reason}") from None
    except (AttributeError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: unreadable DICOM (no usable Rows/Columns: {exc})") from None
    _check_frame(path, frame, n_frames)
    return size


def read_image_size(path: str | Path, frame: int = 0) -> tuple[int, int]:
    """The size ``(W, H)`` in pixels of one frame of an image file, from its header only.

    What a case needs before any pixel is decoded (the calibration's and the annotations'
    bounds); :func:`load_image` decodes the pixels when something needs them (the report, the
    workbench, a contour recipe), so a case registered without them never holds the image.

    Raises
    ------
    ValueError
        The file is missing, its header is unreadable, the frame does not exist, or the image
        is above :data:`MAX_IMAGE_PIXELS`.
    """
    path, kind = _checked(path, frame)
    if kind == "tiff":
        size = _tiff_page(path, int(frame), decode=False)[0]
    elif kind == "dicom":
        size = _dicom_size(path, int(frame))
    else:
        _check_frame(path, int(frame), 1)
        with path.open("rb") as fh:
            found = _raster_size(fh.read(65536))
        if found is None:  # a format whose header we do not parse: decode it once
            return load_image(path, int(frame)).size
        size = (int(found[0]), int(found[1]))
    check_pixel_count(path, *size)
    return size
