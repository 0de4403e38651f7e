"""3D view of a surface coloured by its error, with a colour bar in mm.

PyVista renders it off-screen (isometric view, smooth shading, viridis, 900 x 700 px). With no
``DISPLAY`` the X11 render window fails ("bad X server connection"), so VTK is asked for its EGL
window directly (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``, :func:`.gl_probe.
offscreen_env`). Where neither EGL nor OSMesa works, VTK's window kills the process (SIGSEGV)
instead of raising, so VTK is called only after :func:`.gl_probe.offscreen_rendering_available`
has rendered in a child process (once per process). When it has not, or PyVista raises, the
view is drawn with matplotlib's 3D axes (:func:`render_matplotlib`) and a one-line warning says
why (:func:`render_surface` returns it for ``result.json["warnings"]``).
"""

from __future__ import annotations

import logging
import os

import numpy as np

from .gl_probe import offscreen_env, offscreen_rendering_available

__all__ = ["render_error_mesh", "render_surface"]

#: The rendered figure, pixels.
SIZE_PX = (900, 700)

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
    size: tuple[int, int] = SIZE_PX,
) -> None:
    """Render with PyVista off-screen (surface, error colour map, colour bar in mm; without
    ``error_mm`` one ivory colour), isometric view.

    Raises
    ------
    RuntimeError
        Off-screen rendering does not work here (:func:`.gl_probe.offscreen_rendering_available`
        failed); VTK is not called, since it would crash the process.
    """
    ok, why = offscreen_rendering_available()
    if not ok:
        raise RuntimeError(f"off-screen rendering is not available here ({why})")
    for key, value in offscreen_env().items():  # the probe's environment (the EGL window)
        os.environ.setdefault(key, value)
    import pyvista as pv

    from ..io.atomic import atomic_write_bytes
    from ..io.meshes import to_polydata
    from .plotting import png_bytes

    mesh = to_polydata(np.asarray(vertices, float), np.asarray(faces))
    # no multisampling: with Mesa's software OpenGL it doubles the render's time (measured
    # 0.21 vs 0.125 CPU s for 14,640 triangles at 900 x 700 px) for slightly smoother edges
    theme = pv.themes.DocumentTheme()
    theme.multi_samples = 1
    theme.anti_aliasing = None
    plotter = pv.Plotter(off_screen=True, window_size=size, theme=theme)
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
        rgb = plotter.screenshot(None, return_img=True)
    finally:
        plotter.close()
    atomic_write_bytes(path, png_bytes(np.asarray(rgb)[:, :, :3]), make_parents=False)


def render_matplotlib(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
    *,
    size: tuple[int, int] = SIZE_PX,
) -> None:
    """The fallback: matplotlib 3D axes (``mpl_toolkits.mplot3d``), the triangles coloured by
    the mean error of their corners (viridis, colour bar in mm; without ``error_mm`` ivory),
    shaded under a light, seen from the isometric direction; equal axes in mm."""
    from matplotlib import cm, colors
    from matplotlib.colors import LightSource
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from .plotting import new_figure, save_figure

    V = np.asarray(vertices, float)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    fig = new_figure(*size)
    ax = fig.add_axes((0.0, 0.0, 0.86, 0.94), projection="3d")
    if error_mm is not None:
        norm = colors.Normalize(0.0, _error_max(error_mm))
        face_rgb = cm.viridis(norm(np.asarray(error_mm, float)[F].mean(axis=1)))
        cax = fig.add_axes((0.88, 0.3, 0.025, 0.5))
        fig.colorbar(cm.ScalarMappable(norm, "viridis"), cax=cax, label="error (mm)")
    else:
        face_rgb = colors.to_rgba("ivory")
    light = LightSource(azdeg=45.0, altdeg=35.0)  # from the viewer's side
    ax.add_collection3d(
        Poly3DCollection(V[F], facecolors=face_rgb, shade=True, lightsource=light, linewidths=0)
    )
    lo, hi = V.min(axis=0), V.max(axis=0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set(xlim=(c[0] - r, c[0] + r), ylim=(c[1] - r, c[1] + r), zlim=(c[2] - r, c[2] + r))
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=35.26, azim=45.0)  # along +(1, 1, 1), z up: PyVista's isometric view
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    fig.text(0.005, 0.985, title, fontsize=11, va="top")
    save_figure(fig, path)


def render_surface(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> tuple[str, str | None]:
    """Render the mesh (vertices (N, 3) mm, faces (F, 3)) coloured by ``error_mm`` (per
    vertex, mm; ``None``: one neutral colour) to the PNG ``path``.

    Returns
    -------
    renderer : str
        ``"pyvista"``, or ``"matplotlib"`` when PyVista could not render here.
    warning : str or None
        One line saying why the fallback was used (``None`` with PyVista).
    """
    ok, why = offscreen_rendering_available()  # VTK would crash the process otherwise
    if ok:
        try:
            render_pyvista(path, vertices, faces, error_mm, title)
            return "pyvista", None
        except Exception as exc:  # noqa: BLE001 - any VTK/OpenGL failure: use the fallback
            why = f"PyVista failed: {exc}"
    warning = (
        f"3D view drawn with matplotlib: PyVista off-screen rendering is not available here "
        f"({why}); install the EGL library (Debian: libegl1) or OSMesa (libosmesa6)"
    )
    render_matplotlib(path, vertices, faces, error_mm, title)
    return "matplotlib", " ".join(warning.split())


def render_error_mesh(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> str:
    """:func:`render_surface`, its warning logged; returns the renderer used ("pyvista" or
    "matplotlib")."""
    renderer, warning = render_surface(path, vertices, faces, error_mm, title)
    if warning:
        log.warning("%s", warning)
    return renderer
