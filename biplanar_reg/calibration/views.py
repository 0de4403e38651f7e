"""Camera models of X-ray views: pixels to world rays and world points to pixels.

Conventions (see ``docs/case-format.md``):

* pixels ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel, v down;
* extrinsics follow OpenCV: a world point ``X`` (mm) has camera coordinates ``R @ X + t``;
* a ray is ``(origin, unit direction)`` in the world frame (mm).

Every view has ``rays(uv) -> (origins, directions)`` and ``project(X) -> uv``; these are exact
inverses of each other (a point projected and back-projected lies on its ray).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, check_positive, check_rotation
from .pinhole import as_distortion, pixels_to_normalized, project_camera_points

__all__ = ["View", "PerspectiveView", "OrthographicView", "SlotScanningView"]

#: Largest image, in pixels (W x H), a view may declare; also the largest image
#: :func:`biplanar_reg.annotation.load_image` decodes. Beyond it a view's image would not fit
#: in memory (outlines are rasterised at the image size).
MAX_IMAGE_PIXELS = 100_000_000


def _as_rows(values: object, name: str, width: int) -> np.ndarray:
    """Validate (K, width) or (width,) finite floats; a single row becomes (1, width)."""
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    return as_array(name, arr, (None, width))


def _as_uv(uv: object, name: str = "uv") -> np.ndarray:
    """Validate pixel coordinates: (K, 2) or (2,) finite floats; returns (K, 2)."""
    return _as_rows(uv, name, 2)


def _as_points(X: object, name: str = "X") -> np.ndarray:
    """Validate 3D points: (K, 3) or (3,) finite floats; returns (K, 3)."""
    return _as_rows(X, name, 3)


def _check_intrinsics(K: object, *, orthographic: bool) -> np.ndarray:
    K = as_array("K", K, (3, 3))
    if abs(K[0, 0]) < 1e-12 or abs(K[1, 1]) < 1e-12:
        raise ValueError(f"K: zero focal length / scale (K[0,0]={K[0, 0]}, K[1,1]={K[1, 1]})")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f"K: third row must be [0, 0, 1], got {K[2].tolist()}")
    if abs(K[1, 0]) > 1e-12:
        raise ValueError(f"K: must be upper triangular (K[1,0]={K[1, 0]})")
    return K


def _whole_positive(x: object) -> bool:
    """True for a positive whole number (int, or float with an integer value), not a bool."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
        return False
    try:
        f = float(x)
    except OverflowError:  # an int beyond the float range
        return False
    return math.isfinite(f) and f.is_integer() and f > 0


def _check_image_size(value: object) -> tuple[int, int]:
    """``(W, H)`` as two positive ints of at most :data:`MAX_IMAGE_PIXELS` pixels in all;
    ``ValueError`` for anything else (inf, 512.5, "x", 10**40)."""
    try:
        items = list(value)  # type: ignore[call-overload]
    except TypeError:
        items = []
    if len(items) != 2 or not all(_whole_positive(x) for x in items):
        shown = repr(items if len(items) == 2 else value)[:60]
        raise ValueError(f"image_size: expected two positive whole numbers (W, H), got {shown}")
    w, h = int(items[0]), int(items[1])
    if w * h > MAX_IMAGE_PIXELS:
        raise ValueError(
            f"image_size: {w}x{h} pixels is above the limit of {MAX_IMAGE_PIXELS:,} pixels"
        )
    return (w, h)


@dataclass(frozen=True, eq=False, kw_only=True)
class View:
    """Base class: extrinsics shared by all view kinds.

    Parameters
    ----------
    R : (3, 3) array
        World-to-camera rotation (OpenCV convention).
    t : (3,) array
        World-to-camera translation, mm.
    image_size : (W, H) or None
        Image width and height in pixels, when known.
    name : str
        The view's name (e.g. ``"cam1"``).
    """

    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int] | None = None
    name: str = ""

    #: the projection kind, as named in the native JSON ("perspective", ...)
    kind = "abstract"

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", check_rotation("R", self.R))
        object.__setattr__(self, "t", as_array("t", self.t, (3,)))
        if self.image_size is not None:
            object.__setattr__(self, "image_size", _check_image_size(self.image_size))

    # -- frames ---------------------------------------------------------------------------------
    def to_camera(self, X: object) -> np.ndarray:
        """World points (K, 3) mm -> camera coordinates (K, 3) mm."""
        return _as_points(X) @ self.R.T + self.t

    def to_world(self, Xc: np.ndarray) -> np.ndarray:
        """Camera coordinates (K, 3) -> world points (K, 3)."""
        return (np.asarray(Xc, dtype=float) - self.t) @ self.R

    def _to_camera_in_front(self, X: object) -> np.ndarray:
        """World points (K, 3) mm -> camera coordinates (K, 3) mm, all in front of the source.

        For the views with a point source (perspective, slot-scanning), where a point at camera
        depth ``z <= 0`` has no image. Raises ``ValueError`` naming the first (up to 10) such
        points.
        """
        Xc = self.to_camera(X)
        z = Xc[:, 2]
        if np.any(z <= 0):
            bad = np.flatnonzero(z <= 0)[:10].tolist()
            raise ValueError(f"X: point(s) {bad} lie behind the source of view {self.name!r}")
        return Xc

    def _rays_camera(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def rays(self, uv: object) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to world rays.

        Parameters
        ----------
        uv : (K, 2) array
            Pixel coordinates (column, row), 0-based.

        Returns
        -------
        origins : (K, 3) array
            Ray origins in the world frame, mm.
        directions : (K, 3) array
            Unit ray directions in the world frame, pointing from the source into the scene.
        """
        uv = _as_uv(uv)
        oc, dc = self._rays_camera(uv)
        dc = dc / np.linalg.norm(dc, axis=1, keepdims=True)
        return self.to_world(oc), dc @ self.R

    def project(self, X: object) -> np.ndarray:
        """Project world points (K, 3) mm to pixels (K, 2)."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False, kw_only=True)
class PerspectiveView(View):
    """A pinhole (point-source) X-ray view, optionally with lens/intensifier distortion.

    ``K`` is the 3x3 camera matrix in pixels; the X-ray source is the camera centre
    ``C = -R.T @ t`` and the detector lies at depth ``K[0,0] * pixel spacing`` in front of it.
    A negative ``K[0,0]`` describes a mirrored readout (see the DICOM reader).

    ``distortion`` holds the OpenCV coefficients ``(k1, k2, p1, p2, k3, k4, k5, k6)`` (4 or 5
    are accepted and padded with zeros; all zeros is stored as ``None``). ``project`` distorts
    normalised coordinates before applying ``K``; ``rays`` undistorts pixels exactly (Newton)
    before back-projection, so the two stay exact inverses (see :mod:`.pinhole`).
    """

    K: np.ndarray
    distortion: np.ndarray | None = None

    kind = "perspective"

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "K", _check_intrinsics(self.K, orthographic=False))
        object.__setattr__(self, "distortion", as_distortion(self.distortion))

    @property
    def centre(self) -> np.ndarray:
        """The X-ray source position (camera centre) in the world frame, mm."""
        return -self.R.T @ self.t

    @property
    def principal_ray(self) -> np.ndarray:
        """Unit direction of the optical axis (camera +z) in the world frame."""
        return self.R[2].copy()

    @property
    def projection_matrix(self) -> np.ndarray:
        """The 3x4 matrix ``K @ [R | t]`` (world mm -> homogeneous pixels, no distortion)."""
        return self.K @ np.column_stack([self.R, self.t])

    def _rays_camera(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = pixels_to_normalized(uv, self.K, self.distortion)
        dc = np.column_stack([xy, np.ones(len(uv))])
        return np.zeros_like(dc), dc

    def project(self, X: object) -> np.ndarray:
        Xc = self._to_camera_in_front(X)
        return project_camera_points(Xc, self.K, self.distortion)


@dataclass(frozen=True, eq=False, kw_only=True)
class OrthographicView(View):
    """A parallel-projection view: every ray has direction camera +z.

    ``K``'s first two rows map camera ``(x, y)`` in mm to pixels (``K[0,0]``, ``K[1,1]`` in
    pixels per mm); its third row is ``[0, 0, 1]``. Ray origins lie on the camera plane ``z = 0``.
    """

    K: np.ndarray

    kind = "orthographic"

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "K", _check_intrinsics(self.K, orthographic=True))

    @property
    def principal_ray(self) -> np.ndarray:
        """Unit direction of the projection (camera +z) in the world frame."""
        return self.R[2].copy()

    def _rays_camera(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A = self.K[:2, :2]
        xy = np.linalg.solve(A, (uv - self.K[:2, 2]).T).T
        oc = np.column_stack([xy, np.zeros(len(uv))])
        dc = np.tile([0.0, 0.0, 1.0], (len(uv), 1))
        return oc, dc

    def project(self, X: object) -> np.ndarray:
        Xc = self.to_camera(X)
        return Xc[:, :2] @ self.K[:2, :2].T + self.K[:2, 2]


@dataclass(frozen=True, eq=False, kw_only=True)
class SlotScanningView(View):
    """A slot-scanning (EOS-like) view: perspective across a detector row, parallel along the scan.

    The source and the detector line move together along camera ``+y``. The source of image row
    ``v`` sits at camera coordinates ``(0, (v - cv) * row_pitch, 0)``; within that row the rays
    fan out in the camera x-z plane like a pinhole with focal length ``fu`` (pixels) and principal
    column ``cu``. A camera point ``(x, y, z)`` is imaged at ``u = fu * x / z + cu`` and
    ``v = y / row_pitch + cv``. Each row therefore has its own ray origin: a generalised camera.

    Parameters
    ----------
    fu : float
        Focal length across the row, pixels (source-detector distance / pixel width).
    cu, cv : float
        Principal column and the row at which the source passes camera ``y = 0``, pixels.
    row_pitch : float
        Scan distance per image row, mm.
    """

    fu: float = 1.0
    cu: float = 0.0
    cv: float = 0.0
    row_pitch: float = 1.0

    kind = "slot_scanning"

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "fu", check_positive("fu", self.fu))
        object.__setattr__(self, "row_pitch", check_positive("row_pitch", self.row_pitch))
        for key in ("cu", "cv"):
            val = float(getattr(self, key))
            if not np.isfinite(val):
                raise ValueError(f"{key}: must be finite, got {val!r}")
            object.__setattr__(self, key, val)

    def _rays_camera(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(uv)
        oc = np.column_stack([np.zeros(n), (uv[:, 1] - self.cv) * self.row_pitch, np.zeros(n)])
        dc = np.column_stack([(uv[:, 0] - self.cu) / self.fu, np.zeros(n), np.ones(n)])
        return oc, dc

    def project(self, X: object) -> np.ndarray:
        Xc = self._to_camera_in_front(X)
        z = Xc[:, 2]
        return np.column_stack(
            [self.fu * Xc[:, 0] / z + self.cu, Xc[:, 1] / self.row_pitch + self.cv]
        )
