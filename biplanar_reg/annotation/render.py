"""Synthetic radiographs of a closed triangle mesh seen by a calibrated view, with ground truth.

Each pixel's ray (``view.rays``) is intersected exactly with the planes of the triangles whose
projection (``view.project`` of the vertices) covers the pixel centre. With outward normals a ray
enters the solid through faces with ``n . d < 0`` and leaves through faces with ``n . d > 0``, so
the path length inside the mesh is ``sum(sign(n . d) * s)`` over the hits at ray distance ``s``.
The radiograph is the transmitted fraction ``exp(-mu * L)`` (bone dark on bright, like the
wrist radiographs), optionally with Poisson or Gaussian noise and a Gaussian detector blur.

Ground truth: ``mask`` (pixel centres covered by the projected mesh) and ``outlines``, the
projected occluding contour: mesh edges between a front- and a back-facing triangle, chained into
polylines, keeping only the edges that lie on the border of the mask (inner folds dropped); the
outline is :func:`biplanar_reg.outline.outline_polylines` with this exact coverage as its mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .._validate import as_array, check_positive
from ..calibration.views import View
from ..outline import outline_polylines

__all__ = ["Radiograph", "render_radiograph"]


@dataclass(frozen=True, eq=False)
class Radiograph:
    """A synthetic radiograph and its ground truth.

    Attributes
    ----------
    image : (H, W) float64
        Transmitted fraction in [0, 1] (1 = no attenuation), after noise and blur.
    path_length : (H, W) float64
        Noise-free path length of each pixel's ray through the mesh, mm.
    mask : (H, W) bool
        Pixels whose centre ray hits the mesh (the exact coverage sampled at pixel centres).
    outlines : list of (K, 2) float64
        Outline polylines in pixels (u, v), longest first; closed loops repeat no point.
    outline_closed : list of bool
        Whether each outline polyline is a closed loop.
    """

    image: np.ndarray
    path_length: np.ndarray
    mask: np.ndarray
    outlines: list[np.ndarray] = field(default_factory=list)
    outline_closed: list[bool] = field(default_factory=list)


def _check_mesh(vertices: object, faces: object) -> tuple[np.ndarray, np.ndarray]:
    V = as_array("vertices", vertices, (None, 3))
    F = as_array("faces", faces, (None, 3), dtype=int)
    if len(F) == 0:
        raise ValueError("faces: the mesh has no triangles")
    if F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"faces: vertex index out of range 0..{len(V) - 1}")
    # orient outward: a closed mesh with inward normals has negative signed volume
    v0, v1, v2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = np.einsum("ij,ij->i", v0, np.cross(v1, v2)).sum() / 6.0
    if vol < 0:
        F = F[:, ::-1].copy()
    return V, F


def _image_size(view: View, image_size: tuple[int, int] | None) -> tuple[int, int]:
    size = image_size if image_size is not None else view.image_size
    if size is None:
        raise ValueError("image_size: the view has no image_size; pass image_size=(W, H)")
    w, h = (int(s) for s in size)
    if w <= 0 or h <= 0:
        raise ValueError(f"image_size: expected positive (W, H), got {size!r}")
    return w, h


def _covering_pairs(
    uv: np.ndarray, F: np.ndarray, w: int, h: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangle index, pixel u, pixel v) for every pixel centre inside a projected triangle.

    A half-open edge rule (top-left convention) makes a pixel centre on an edge shared by two
    triangles count for exactly one of them.
    """
    tri = uv[F]  # (F, 3, 2)
    lo = np.ceil(tri.min(axis=1)).astype(np.int64)
    hi = np.floor(tri.max(axis=1)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w - 1, h - 1])
    nw = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    nh = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nw * nh
    keep = counts > 0
    fid = np.repeat(np.flatnonzero(keep), counts[keep])
    if fid.size == 0:
        e = np.zeros(0, np.int64)
        return e, e, e
    starts = np.cumsum(counts[keep]) - counts[keep]
    local = np.arange(fid.size) - np.repeat(starts, counts[keep])
    pu = lo[fid, 0] + local % nw[fid]
    pv = lo[fid, 1] + local // nw[fid]
    a, b, c = tri[fid, 0], tri[fid, 1], tri[fid, 2]
    p = np.column_stack([pu, pv]).astype(float)
    # orient each projected triangle counter-clockwise in (u, v) so edge functions are >= 0 inside
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    flip = area < 0
    b2 = np.where(flip[:, None], c, b)
    c2 = np.where(flip[:, None], b, c)
    inside = np.abs(area) > 1e-12
    for e0, e1 in ((a, b2), (b2, c2), (c2, a)):
        d = e1 - e0
        f = d[:, 0] * (p[:, 1] - e0[:, 1]) - d[:, 1] * (p[:, 0] - e0[:, 0])
        # top-left rule: points exactly on an edge belong to it only for "top" or "left" edges
        top_left = (d[:, 1] > 0) | ((d[:, 1] == 0) & (d[:, 0] < 0))
        inside &= (f > 0) | ((f == 0) & top_left)
    return fid[inside], pu[inside], pv[inside]


def path_lengths(
    vertices: object,
    faces: object,
    view: View,
    image_size: tuple[int, int] | None = None,
    supersample: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Path length (mm) of the rays through a closed mesh per pixel, and the coverage mask.

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices in the world frame, mm.
    faces : (F, 3) int array
        Triangles of a closed (watertight) mesh; orientation is fixed automatically.
    view : View
        A calibrated view (perspective, orthographic, slot-scanning, ...).
    image_size : (W, H), optional
        Defaults to ``view.image_size``.
    supersample : int
        Odd number ``s``: each pixel averages ``s x s`` rays on a regular sub-grid (the detector
        integrates over the pixel), which removes the half-pixel staircase of point sampling.

    Returns
    -------
    length : (H, W) float64
        Mean path length inside the mesh over the pixel, mm.
    mask : (H, W) bool
        Pixels whose centre ray hits the mesh.
    """
    V, F = _check_mesh(vertices, faces)
    w, h = _image_size(view, image_size)
    ss = int(supersample)
    if ss < 1 or ss % 2 == 0:
        raise ValueError(f"supersample: expected an odd integer >= 1, got {supersample!r}")
    # sub-sample grid: sub-pixel (i, j) of pixel (u, v) sits at u + (i - (s - 1) / 2) / s
    uv = (view.project(V) + 0.5) * ss - 0.5
    ws, hs = w * ss, h * ss
    fid, pu, pv = _covering_pairs(uv, F, ws, hs)
    length = np.zeros((hs, ws))
    if fid.size:
        n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        # rays of the covered sub-samples only (ray origins differ per pixel for some views)
        flat = pv * ws + pu
        uniq, inv = np.unique(flat, return_inverse=True)
        sub = np.column_stack([uniq % ws, uniq // ws]).astype(float)
        o, d = view.rays((sub + 0.5) / ss - 0.5)
        o, d = o[inv], d[inv]
        nf = n[fid]
        nd = np.einsum("ij,ij->i", nf, d)
        ok = np.abs(nd) > 1e-12 * np.linalg.norm(nf, axis=1)
        s = np.einsum("ij,ij->i", nf, V[F[fid, 0]] - o)[ok] / nd[ok]
        np.add.at(length.reshape(-1), flat[ok], np.sign(nd[ok]) * s)
        # round-off of +s_exit - s_entry is ~1e-12 * distance: clamp tiny negatives
        np.maximum(length, 0.0, out=length)
    covered = np.zeros((hs, ws), bool)
    covered[pv, pu] = True
    c = (ss - 1) // 2
    mask = covered[c::ss, c::ss].copy()
    if ss > 1:
        length = length.reshape(h, ss, w, ss).mean(axis=(1, 3))
    return length, mask


def render_radiograph(
    vertices: object,
    faces: object,
    view: View,
    *,
    image_size: tuple[int, int] | None = None,
    mu_per_mm: float = 0.05,
    photons: float | None = None,
    noise_sigma: float = 0.0,
    blur_sigma_px: float = 0.0,
    supersample: int = 3,
    seed: int | None = 0,
) -> Radiograph:
    """Render a synthetic radiograph of a closed mesh with its outline ground truth.

    Parameters
    ----------
    vertices : (N, 3) array
        Mesh vertices in the world frame, mm.
    faces : (F, 3) int array
        Triangles of a closed mesh.
    view : View
        The calibrated view (``view.project`` places the vertices, ``view.rays`` gives the rays).
    image_size : (W, H), optional
        Defaults to ``view.image_size``.
    mu_per_mm : float
        Linear attenuation coefficient, 1/mm (0.05 ~ cortical-ish contrast for a 10-30 mm bone).
    photons : float, optional
        Unattenuated photon count per pixel; when given, Poisson noise is applied.
    noise_sigma : float
        Standard deviation of additive Gaussian noise on the transmitted fraction.
    blur_sigma_px : float
        Gaussian detector blur, pixels (applied before noise).
    supersample : int
        Odd number of rays per pixel side (see :func:`path_lengths`); 1 = point sampling.
    seed : int or None
        Seed of the noise generator (deterministic by default).

    Returns
    -------
    Radiograph
    """
    mu = check_positive("mu_per_mm", mu_per_mm)
    if noise_sigma < 0 or not np.isfinite(noise_sigma):
        raise ValueError(f"noise_sigma: must be >= 0, got {noise_sigma!r}")
    if blur_sigma_px < 0 or not np.isfinite(blur_sigma_px):
        raise ValueError(f"blur_sigma_px: must be >= 0, got {blur_sigma_px!r}")
    V, F = _check_mesh(vertices, faces)
    length, mask = path_lengths(V, F, view, image_size, supersample)
    img = np.exp(-mu * length)
    if blur_sigma_px > 0:
        img = ndimage.gaussian_filter(img, blur_sigma_px, mode="nearest")
    rng = np.random.default_rng(seed)
    if photons is not None:
        n0 = check_positive("photons", photons)
        img = rng.poisson(img * n0) / n0
    if noise_sigma > 0:
        img = img + rng.normal(0.0, noise_sigma, img.shape)
    img = np.clip(img, 0.0, 1.0)
    # ground truth: the occluding contour on the border of this exact coverage
    outlines, closed = outline_polylines(V, view, F, mask=mask)
    return Radiograph(img, length, mask, outlines, closed)
