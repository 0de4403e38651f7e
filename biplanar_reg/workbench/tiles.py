"""Image pyramid tiles of a radiograph (grey 8-bit PNG), windowed on the raw pixel values.

Level 0 is the full-resolution image; level ``k`` is ``ceil(W / 2^k) x ceil(H / 2^k)`` pixels,
each the area mean of the 2 x 2 block of level ``k - 1`` below it (OpenCV ``INTER_AREA``), so
pixel ``(u, v)`` of level 0 is at ``((u + 0.5) / 2^k - 0.5, (v + 0.5) / 2^k - 0.5)`` in level
``k``. The coarsest level fits in one tile. Tile ``(tx, ty)`` of a level covers its pixels
``[tx * T, (tx + 1) * T) x [ty * T, (ty + 1) * T)`` (``T`` = :data:`TILE_SIZE`; edge tiles are
smaller). Values are mapped linearly from the window ``[lo, hi]`` (raw image units: the DICOM
modality values, the TIFF/PNG grey levels) to 0..255 and inverted for MONOCHROME1 images, so a
tile shows what the annotator sees in ``XrayImage.display``.

Levels are built when first asked for and kept (a 1760 x 1760 image costs ~16 MB as float32).
"""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np

from ..annotation import XrayImage

__all__ = ["TILE_SIZE", "Pyramid"]

#: Tile edge length, pixels.
TILE_SIZE = 256
#: Percentiles of the raw values giving the default window of non-DICOM images.
WINDOW_PERCENTILES = (1.0, 99.0)
#: CLAHE: contrast limit and the size of its cells in level-0 pixels (the same image region
#: per cell at every level, so that the levels look alike).
CLAHE_CLIP = 2.0
CLAHE_CELL_PX = 128
#: Windowed CLAHE levels kept (a few windows of a few levels).
CLAHE_CACHE = 6


def _default_window(image: XrayImage, value_range: tuple[float, float]) -> tuple[float, float]:
    """The display window in raw units: the DICOM window when the file has one, else the
    1st-99th percentile of the values (a radiograph's few extreme pixels, e.g. collimator edges
    or metal, would otherwise wash the bone out)."""
    if image.file_format == "dicom" and image.window is not None:
        centre, width = image.window
        lo, hi = centre - width / 2.0, centre + width / 2.0
    else:
        # every 4th row and column: the percentiles of 1/16 of the pixels are the same to
        # within a grey level and cost a millisecond on a 1760 x 1760 image
        sample = image.pixels[::4, ::4]
        lo, hi = (float(x) for x in np.percentile(sample, WINDOW_PERCENTILES))
    if not hi > lo:
        lo, hi = value_range
    if not hi > lo:
        hi = lo + 1.0
    return float(lo), float(hi)


class Pyramid:
    """The tiles of one radiograph.

    Parameters
    ----------
    image : XrayImage
        The loaded radiograph (:func:`biplanar_reg.annotation.load_image`).
    tile_size : int
        Tile edge length, pixels.

    Attributes
    ----------
    width, height : int
        Size of level 0, pixels.
    levels : int
        Number of levels; level ``levels - 1`` fits in one tile.
    range : (float, float)
        Minimum and maximum raw value.
    window : (float, float)
        Default window ``(lo, hi)``, raw units.
    inverted : bool
        MONOCHROME1: high values are shown dark.
    """

    def __init__(self, image: XrayImage, tile_size: int = TILE_SIZE):
        self.tile_size = int(tile_size)
        self.width, self.height = image.size
        self.levels = 1
        while max(self._level_size(self.levels - 1)) > self.tile_size:
            self.levels += 1
        self.range = (float(image.pixels.min()), float(image.pixels.max()))
        self.window = _default_window(image, self.range)
        self.inverted = image.photometric == "MONOCHROME1"
        self._data: list[np.ndarray] = [np.ascontiguousarray(image.pixels, dtype=np.float32)]
        self._lock = threading.Lock()
        self._clahe: dict[tuple[int, float, float], np.ndarray] = {}
        self._clahe_lock = threading.Lock()

    def _level_size(self, level: int) -> tuple[int, int]:
        f = 2**level
        return math.ceil(self.width / f), math.ceil(self.height / f)

    def level_size(self, level: int) -> tuple[int, int]:
        """``(W, H)`` of a level, pixels."""
        self._check_level(level)
        return self._level_size(level)

    def tiles(self, level: int) -> tuple[int, int]:
        """Number of tiles ``(columns, rows)`` of a level."""
        w, h = self.level_size(level)
        return math.ceil(w / self.tile_size), math.ceil(h / self.tile_size)

    def _check_level(self, level: int) -> None:
        if not 0 <= level < self.levels:
            raise LookupError(f"level: {level} is not in 0..{self.levels - 1}")

    def level(self, level: int) -> np.ndarray:
        """The raw values of a level, (H_k, W_k) float32 (built on first use)."""
        self._check_level(level)
        with self._lock:  # two tile requests must not build the same level twice
            while len(self._data) <= level:
                prev = self._data[-1]
                w, h = self._level_size(len(self._data))
                self._data.append(cv2.resize(prev, (w, h), interpolation=cv2.INTER_AREA))
            return self._data[level]

    def _windowed(self, block: np.ndarray, lo: float, hi: float) -> np.ndarray:
        """Raw values -> display grey levels 0..255 (float), inverted for MONOCHROME1."""
        grey = np.clip((block - lo) * (255.0 / (hi - lo)), 0.0, 255.0)
        return 255.0 - grey if self.inverted else grey

    def enhanced_level(self, level: int, lo: float, hi: float) -> np.ndarray:
        """A whole level windowed to 8 bits and equalised by CLAHE (OpenCV
        ``createCLAHE``), uint8; kept for the last :data:`CLAHE_CACHE` (level, window) pairs.
        Computed on the whole level, not per tile, so that tiles join without seams."""
        key = (level, float(lo), float(hi))
        # one computation at a time: the page asks for a level's tiles at once, and all but
        # the first find the equalised level made
        with self._clahe_lock:
            with self._lock:
                hit = self._clahe.pop(key, None)
                if hit is not None:
                    self._clahe[key] = hit  # most recently used last
                    return hit
            grey = np.round(self._windowed(self.level(level), lo, hi)).astype(np.uint8)
            w, h = self.level_size(level)
            grid = (max(1, math.ceil(self.width / CLAHE_CELL_PX)),
                    max(1, math.ceil(self.height / CLAHE_CELL_PX)))  # fmt: skip
            grid = (min(grid[0], w), min(grid[1], h))
            out = cv2.createCLAHE(clipLimit=CLAHE_CLIP, tileGridSize=grid).apply(grey)
            with self._lock:
                self._clahe[key] = out
                while len(self._clahe) > CLAHE_CACHE:
                    self._clahe.pop(next(iter(self._clahe)))
            return out

    def tile(
        self,
        level: int,
        tx: int,
        ty: int,
        lo: float | None = None,
        hi: float | None = None,
        clahe: bool = False,
    ) -> bytes:
        """One tile as a grey 8-bit PNG.

        Parameters
        ----------
        level, tx, ty : int
            The level and the tile's column and row in it.
        lo, hi : float, optional
            The window, raw units (default :attr:`window`); ``hi > lo``.
        clahe : bool
            Equalise the windowed level by CLAHE (:meth:`enhanced_level`): display only.

        Raises
        ------
        LookupError
            No such level or tile.
        ValueError
            A bad window (names ``lo`` or ``hi``).
        """
        lo = self.window[0] if lo is None else lo
        hi = self.window[1] if hi is None else hi
        for name, value in (("lo", lo), ("hi", hi)):
            if not math.isfinite(value):
                raise ValueError(f"{name}: must be a finite number, got {value!r}")
        if not hi > lo:
            raise ValueError(f"hi: must be greater than lo ({lo:g}), got {hi:g}")
        cols, rows = self.tiles(level)
        if not (0 <= tx < cols and 0 <= ty < rows):
            raise LookupError(
                f"tile: ({tx}, {ty}) is outside level {level}'s {cols} x {rows} tiles"
            )
        t = self.tile_size
        cut = (slice(ty * t, (ty + 1) * t), slice(tx * t, (tx + 1) * t))
        if clahe:
            out = np.ascontiguousarray(self.enhanced_level(level, lo, hi)[cut])
        else:
            out = np.round(self._windowed(self.level(level)[cut], lo, hi)).astype(np.uint8)
        # fast compression: a tile is encoded per request and sent over the loopback
        ok, png = cv2.imencode(".png", out, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:  # pragma: no cover - OpenCV encodes every uint8 array
            raise RuntimeError("PNG encoding failed")
        return png.tobytes()
