"""The uncertainty map of a registration: the bone coloured by its per-vertex sd over each view.

``uncertainty.png``: one panel per view, the registered bone's triangles projected into the view
(pixels) in painter's order (farthest from the source first, so the surface nearest the source
shows) over the radiograph when there is one, each triangle coloured by the mean ``sd_mm`` of
its corners (``RegistrationResult.vertex_sd_mm``: posterior sd, RMS over the three axes, mm;
:mod:`biplanar_reg.registration.uncertainty`), one colour scale for all panels.

The triangles are filled with OpenCV into an image of the panel's crop (at twice the panel's
resolution, then reduced: anti-aliased edges), blended at 85 % over the radiograph, and the image
is shown on matplotlib axes in pixel units: a matplotlib collection of the 15,000 triangles of a
knee-sized bone took ten times longer to draw.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..io.atomic import atomic_path

if TYPE_CHECKING:
    from ..calibration import View

__all__ = ["uncertainty_figure"]


def _painter_faces(view: View, vertices: np.ndarray, faces: np.ndarray) -> tuple:
    """Projected triangles (T, 3, 2) px, farthest first, and the face index of each."""
    centroid = (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3.0
    origin, direction = view.rays(view.project(centroid))
    depth = np.einsum("ij,ij->i", centroid - origin, direction)
    order = np.argsort(-depth, kind="stable")
    return view.project(vertices)[faces[order]], order


#: Largest side (px) of the radiograph crop drawn under the bone: a figure panel is ~500 px wide,
#: and drawing a full 8000 px radiograph costs matplotlib gigabytes.
MAX_BACKGROUND_PX = 560


def _crop(display: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, tuple]:
    """The part of ``display`` (H, W) inside the pixel box ``lo``..``hi`` (u, v), reduced to at
    most :data:`MAX_BACKGROUND_PX` a side, and its ``imshow`` extent in full-image pixels."""
    import cv2

    h, w = display.shape
    u0, v0 = (max(int(np.floor(x)), 0) for x in lo)
    u1, v1 = min(int(np.ceil(hi[0])) + 1, w), min(int(np.ceil(hi[1])) + 1, h)
    if u1 <= u0 or v1 <= v0:  # the bone projects outside the image
        u0, v0, u1, v1 = 0, 0, w, h
    crop = np.asarray(display[v0:v1, u0:u1], dtype=np.float32)
    f = MAX_BACKGROUND_PX / max(crop.shape)
    if f < 1.0:
        size = (max(int(crop.shape[1] * f), 1), max(int(crop.shape[0] * f), 1))
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
    return crop, (u0 - 0.5, u1 - 0.5, v1 - 0.5, v0 - 0.5)


def _panel_image(
    tri: np.ndarray,
    rgb: np.ndarray,
    display: np.ndarray | None,
    box: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, tuple]:
    """The panel (H, W, 3) in [0, 1]: triangles ``tri`` (T, 3, 2) px filled in order with
    colours ``rgb`` (T, 3), 85 % over the radiograph (or white), inside the pixel box
    ``box = (lo, hi)``; and its ``imshow`` extent in full-image pixels."""
    import cv2

    lo, hi = box
    f = MAX_BACKGROUND_PX / max(float(np.max(hi - lo)), 1e-9)
    w, h = (max(int(np.ceil(x * f)), 1) for x in hi - lo)
    if display is not None:
        crop, extent = _crop(display, lo, hi)
        u0, u1, v1, v0 = extent
        lo, hi = np.array([u0, v0]), np.array([u1, v1])
        f = MAX_BACKGROUND_PX / max(float(np.max(hi - lo)), 1e-9)
        w, h = (max(int(np.ceil(x * f)), 1) for x in hi - lo)
        back = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA)
        back = np.repeat(np.clip(back, 0.0, 1.0)[:, :, None], 3, axis=2)
    else:
        back = np.ones((h, w, 3), np.float32)
    s, shift = 2, 4  # supersampling; cv2 fixed-point sub-pixel precision (1/16 px)
    layer = np.zeros((h * s, w * s, 3), np.uint8)
    cover = np.zeros((h * s, w * s), np.uint8)
    # the box's corners are pixel edges: image point u maps to (u - lo) f s - 0.5 in the
    # layer's pixel-centre coordinates
    pts = np.round(((tri - lo) * f * s - 0.5) * (1 << shift)).astype(np.int32)
    cols = np.round(np.asarray(rgb) * 255).astype(int).tolist()
    for t, col in zip(pts, cols, strict=True):
        cv2.fillConvexPoly(layer, t, col, lineType=cv2.LINE_8, shift=shift)
        cv2.fillConvexPoly(cover, t, 255, lineType=cv2.LINE_8, shift=shift)
    layer = cv2.resize(layer, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    alpha = 0.85 * cv2.resize(cover, (w, h), interpolation=cv2.INTER_AREA)[:, :, None] / 255
    image = np.clip(alpha * layer + (1.0 - alpha) * back, 0.0, 1.0)
    hi = lo + np.array([w, h]) / f  # the image's own extent (whole pixels)
    return image, (lo[0], hi[0], hi[1], lo[1])


def uncertainty_figure(
    path: str | os.PathLike,
    panels: Sequence[tuple[str, View, np.ndarray | None]],
    vertices: np.ndarray,
    faces: np.ndarray,
    sd_mm: np.ndarray,
) -> Path:
    """Write ``path`` (PNG): the bone coloured by ``sd_mm`` over each view.

    Parameters
    ----------
    path : path-like
        Output PNG (written atomically).
    panels : sequence of (name, view, display)
        Per view its name, calibrated view (the pose the registration used) and radiograph
        (``(H, W)`` in [0, 1], or None for a blank canvas).
    vertices : (N, 3) array
        Registered surface, world frame, mm.
    faces : (F, 3) int array
    sd_mm : (N,) array
        Per-vertex sd, mm.
    """
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    V, F = np.asarray(vertices, float), np.asarray(faces, dtype=np.int64)
    sd = np.asarray(sd_mm, float)
    face_sd = (sd[F[:, 0]] + sd[F[:, 1]] + sd[F[:, 2]]) / 3.0
    norm = Normalize(vmin=0.0, vmax=max(float(np.percentile(face_sd, 99)), 1e-6))
    face_rgb = colormaps["viridis"](norm(face_sd))[:, :3]
    fig = Figure(figsize=(5.2 * len(panels), 5.0))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (name, view, display) in zip(axes[0], panels, strict=True):
        tri, order = _painter_faces(view, V, F)
        lo, hi = tri.reshape(-1, 2).min(axis=0), tri.reshape(-1, 2).max(axis=0)
        pad = 0.08 * float(np.max(hi - lo))
        image, extent = _panel_image(tri, face_rgb[order], display, (lo - pad, hi + pad))
        ax.imshow(image, extent=extent, interpolation="bilinear")
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(hi[1] + pad, lo[1] - pad)  # image rows grow downwards
        ax.set_aspect("equal")
        ax.set_title(f"{name}")
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
    fig.colorbar(
        ScalarMappable(norm=norm, cmap="viridis"),
        ax=list(axes[0]),
        shrink=0.8,
        label="sd (mm, RMS over axes)",
    )
    fig.suptitle(
        f"Posterior sd per vertex: median {np.median(sd_mm):.2f} mm, "
        f"95th percentile {np.percentile(sd_mm, 95):.2f} mm"
    )
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fig.savefig(fh, format="png", dpi=90, pil_kwargs={"compress_level": 1})
    return path
