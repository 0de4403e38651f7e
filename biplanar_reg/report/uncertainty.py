"""The uncertainty map of a registration: the bone coloured by its per-vertex sd over each view.

``uncertainty.png``: one panel per view, the registered bone's triangles projected into the view
(pixels) in painter's order (farthest from the source first, so the surface nearest the source
shows) over the radiograph when there is one, each triangle coloured by the mean ``sd_mm`` of
its corners (``RegistrationResult.vertex_sd_mm``: posterior sd, RMS over the three axes, mm;
:mod:`biplanar_reg.registration.uncertainty`), one colour scale for all panels.
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
    tri = vertices[faces]
    centroid = tri.mean(axis=1)
    origin, direction = view.rays(view.project(centroid))
    depth = np.einsum("ij,ij->i", centroid - origin, direction)
    order = np.argsort(-depth, kind="stable")
    return view.project(vertices)[faces[order]], order


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
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import Normalize

    V, F = np.asarray(vertices, float), np.asarray(faces, dtype=np.int64)
    face_sd = np.asarray(sd_mm, float)[F].mean(axis=1)
    norm = Normalize(vmin=0.0, vmax=max(float(np.percentile(face_sd, 99)), 1e-6))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 5.0), squeeze=False)
    for ax, (name, view, display) in zip(axes[0], panels, strict=True):
        tri, order = _painter_faces(view, V, F)
        if display is not None:
            ax.imshow(display, cmap="gray", vmin=0.0, vmax=1.0)
        coll = PolyCollection(tri, array=face_sd[order], cmap="viridis", norm=norm)
        coll.set_edgecolor("face")
        coll.set_alpha(0.85)
        ax.add_collection(coll)
        lo, hi = tri.reshape(-1, 2).min(axis=0), tri.reshape(-1, 2).max(axis=0)
        pad = 0.08 * float(np.max(hi - lo))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(hi[1] + pad, lo[1] - pad)  # image rows grow downwards
        ax.set_aspect("equal")
        ax.set_title(f"{name}")
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
    fig.colorbar(
        plt.cm.ScalarMappable(norm=norm, cmap="viridis"),
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
        fig.savefig(fh, format="png", dpi=90)
    plt.close(fig)
    return path
