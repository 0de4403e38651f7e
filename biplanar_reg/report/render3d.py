"""Off-screen 3D render of a surface coloured by its error, with a colour bar in mm.

PyVista/VTK renders off-screen without a display: with no ``DISPLAY`` the X11 render window
fails ("bad X server connection") and VTK >= 9.4 falls back to EGL; this module asks for the
EGL window directly (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``) so the fallback is not
tried on every render. Measured on the project machine (VTK 9.7.2, no X server, no Xvfb):
EGL off-screen works. Where no off-screen OpenGL exists at all (no EGL/OSMesa libraries), the
render raises and :func:`render_error_mesh` falls back to a matplotlib 3D plot with a logged
warning. ``BIPLANAR_REG_RENDERER=matplotlib`` forces the fallback.
"""

from __future__ import annotations

import logging
import os

import numpy as np

__all__ = ["render_error_mesh"]

log = logging.getLogger(__name__)


def _error_max(error_mm: np.ndarray) -> float:
    """Top of the colour scale, mm: the largest error, at least 1e-6 mm so that an exact fit
    (all errors 0) still has a non-empty colour range."""
    return max(float(np.max(error_mm)), 1e-6)


def render_pyvista(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
    *,
    size: tuple[int, int] = (900, 700),
) -> None:
    """Render with PyVista off-screen (surface, error colour map, colour bar in mm)."""
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    from ..io.meshes import to_polydata

    mesh = to_polydata(np.asarray(vertices, float), np.asarray(faces))
    plotter = pv.Plotter(off_screen=True, window_size=size)
    try:
        plotter.set_background("white")
        if error_mm is not None:
            mesh.point_data["error (mm)"] = np.asarray(error_mm, float)
            plotter.add_mesh(
                mesh,
                scalars="error (mm)",
                cmap="viridis",
                clim=(0.0, _error_max(error_mm)),
                smooth_shading=True,
                scalar_bar_args={"title": "error (mm)", "color": "black", "vertical": True},
            )
        else:
            plotter.add_mesh(mesh, color="ivory", smooth_shading=True)
        plotter.add_text(title, font_size=10, color="black")
        plotter.view_isometric()
        plotter.screenshot(str(path))
    finally:
        plotter.close()


def render_matplotlib(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> None:
    """The fallback: a matplotlib 3D triangle plot coloured by error, with a colour bar in mm."""
    from matplotlib import cm, colors
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from .figures import save_figure

    V = np.asarray(vertices, float)
    F = np.asarray(faces)
    fig = Figure(figsize=(7.0, 6.0))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    poly = Poly3DCollection(V[F], linewidths=0.1, edgecolors=(0, 0, 0, 0.15))
    if error_mm is not None:
        face_err = np.asarray(error_mm, float)[F].mean(axis=1)
        norm = colors.Normalize(0.0, _error_max(error_mm))
        poly.set_facecolor(cm.viridis(norm(face_err)))
        sm = cm.ScalarMappable(norm=norm, cmap="viridis")
        fig.colorbar(sm, ax=ax, shrink=0.7, label="error (mm)")
    else:
        poly.set_facecolor("ivory")
    ax.add_collection3d(poly)
    lo, hi = V.min(axis=0), V.max(axis=0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, ci in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), c, strict=True):
        setter(ci - r, ci + r)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title(title)
    save_figure(fig, path)


def render_error_mesh(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> str:
    """Render the mesh coloured by ``error_mm`` (per vertex) to a PNG; returns the renderer used
    ("pyvista" or "matplotlib")."""
    if os.environ.get("BIPLANAR_REG_RENDERER", "").lower() != "matplotlib":
        try:
            render_pyvista(path, vertices, faces, error_mm, title)
            return "pyvista"
        except Exception as exc:  # noqa: BLE001 - any VTK/OpenGL failure: use the fallback
            log.warning("PyVista off-screen rendering failed (%s); using matplotlib 3D", exc)
    render_matplotlib(path, vertices, faces, error_mm, title)
    return "matplotlib"
