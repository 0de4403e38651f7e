"""3D view of a surface coloured by its error, with a colour bar in mm.

PyVista renders it off-screen (isometric view, smooth shading, viridis, 900 x 700 px). With no
``DISPLAY`` the X11 render window fails ("bad X server connection"), so VTK is asked for its EGL
window directly (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``, :func:`.gl_probe.
offscreen_env`). Where neither EGL nor OSMesa works, VTK's window kills the process (SIGSEGV)
instead of raising, so VTK is called only after :func:`.gl_probe.offscreen_rendering_available`
has rendered in a child process (once per process). When it has not, or PyVista raises, the
view is drawn with matplotlib's 3D axes (:func:`render_matplotlib`) and a one-line warning says
why (:func:`render_surface` returns it for ``result.json["warnings"]``).

VTK is called from one thread of its own (:func:`_vtk`), which keeps each plotter for the next
view (:data:`_scenes`; the next mesh is copied into the shown one): a report starts its 3D
view there (:func:`start_surface`) and draws its 2D figures meanwhile, and
:func:`warm_scene` builds the scene while the registration runs.
"""

from __future__ import annotations

import logging
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from .gl_probe import offscreen_env, offscreen_rendering_available

__all__ = [
    "finish_surface",
    "forget_scenes",
    "render_error_mesh",
    "render_surface",
    "start_surface",
    "warm_scene",
]

#: The rendered figure, pixels.
SIZE_PX = (900, 700)

log = logging.getLogger(__name__)


def _error_max(error_mm: np.ndarray) -> float:
    """Top of the colour scale, mm: the largest error, at least 1e-6 mm so that an exact fit
    (all errors 0) still has a non-empty colour range."""
    return max(float(np.max(error_mm)), 1e-6)


@dataclass
class _Scene:
    """An off-screen PyVista plotter with the surface's actor and the title: the mesh it shows
    (drawings copy theirs into it, so the actor and its smooth-shading filter update in place)."""

    plotter: Any
    mesh: Any
    actor: Any
    title: Any


#: The scenes kept per (size, coloured by an error): VTK's first render in a window (its OpenGL
#: context, the shaders) is most of a render's time, and a batch worker renders one view per
#: case. Only the VTK thread (:func:`_vtk`) touches them: an OpenGL context is current in one
#: thread at a time.
_scenes: dict[tuple[tuple[int, int], bool], _Scene] = {}
_VTK_THREAD = "report-vtk"
_executor: ThreadPoolExecutor | None = None
_executor_lock = threading.Lock()


def _vtk() -> ThreadPoolExecutor:
    """The one thread that calls VTK (started on first use). Its renders run beside the
    caller's 2D figures: VTK releases the GIL while it renders."""
    global _executor
    with _executor_lock:
        if _executor is None:
            _executor = ThreadPoolExecutor(1, thread_name_prefix=_VTK_THREAD)
        return _executor


def _in_vtk_thread() -> bool:
    return threading.current_thread().name.startswith(_VTK_THREAD)


def forget_scenes() -> None:
    """Close the kept plotters (the next view makes a new one)."""
    if not _in_vtk_thread():
        _vtk().submit(forget_scenes).result()
        return
    while _scenes:
        _scenes.popitem()[1].plotter.close()


def _new_scene(mesh, error_mm: np.ndarray | None, size: tuple[int, int]) -> _Scene:
    """A plotter showing ``mesh``: coloured by its point array "error (mm)" (viridis, colour
    bar in mm) when ``error_mm`` is given, else ivory; smooth shading, white background."""
    import pyvista as pv

    # no multisampling: with Mesa's software OpenGL it doubles the render's time (measured
    # 0.21 vs 0.125 CPU s for 14,640 triangles at 900 x 700 px) for slightly smoother edges
    theme = pv.themes.DocumentTheme()
    theme.multi_samples = 1
    theme.anti_aliasing = None
    plotter = pv.Plotter(off_screen=True, window_size=size, theme=theme)
    try:
        plotter.set_background("white")
        if error_mm is not None:
            actor = plotter.add_mesh(
                mesh,
                scalars="error (mm)",
                cmap="viridis",
                clim=(0.0, _error_max(error_mm)),
                smooth_shading=True,
                scalar_bar_args={"title": "error (mm)", "color": "black", "vertical": True},
            )
        else:
            actor = plotter.add_mesh(mesh, color="ivory", smooth_shading=True)
        title = plotter.add_text("", font_size=10, color="black")
    except BaseException:
        plotter.close()
        raise
    return _Scene(plotter, mesh, actor, title)


def _draw(scene: _Scene, mesh, error_mm: np.ndarray | None, title: str) -> np.ndarray:
    """Show ``mesh`` (with its "error (mm)" array when ``error_mm`` is given) titled ``title``
    in ``scene``, isometric view; the screenshot (H, W, 3 or 4) uint8."""
    if mesh is not scene.mesh:
        scene.mesh.copy_from(mesh)  # in place: the actor's pipeline follows
    if error_mm is not None:
        scene.actor.mapper.scalar_range = (0.0, _error_max(error_mm))  # and the colour bar
    scene.title.set_text("upper_left", title)
    scene.plotter.view_isometric()  # the camera fitted to this mesh
    return scene.plotter.screenshot(None, return_img=True)


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
    ``error_mm`` one ivory colour), isometric view, in the VTK thread (:func:`_vtk`; the caller
    waits), where the plotter is kept for the next view of the same size and kind
    (:data:`_scenes`).

    Raises
    ------
    RuntimeError
        Off-screen rendering does not work here (:func:`.gl_probe.offscreen_rendering_available`
        failed); VTK is not called, since it would crash the process.
    """
    if not _in_vtk_thread():
        args = (path, vertices, faces, error_mm, title)
        return _vtk().submit(render_pyvista, *args, size=size).result()
    ok, why = offscreen_rendering_available()
    if not ok:
        raise RuntimeError(f"off-screen rendering is not available here ({why})")
    for key, value in offscreen_env().items():  # the probe's environment (the EGL window)
        os.environ.setdefault(key, value)
    from ..io.atomic import atomic_write_bytes
    from ..io.meshes import to_polydata
    from .plotting import png_bytes

    mesh = to_polydata(np.asarray(vertices, float), np.asarray(faces))
    if error_mm is not None:
        mesh.point_data["error (mm)"] = np.asarray(error_mm, float)
    key = (tuple(size), error_mm is not None)
    scene = _scenes.pop(key, None) or _new_scene(mesh, error_mm, size)
    try:
        rgb = _draw(scene, mesh, error_mm, title)
    except BaseException:
        scene.plotter.close()  # a failed scene is not drawn on again
        raise
    _scenes[key] = scene
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


def _pyvista_job(path, vertices, faces, error_mm, title) -> str | None:
    """In the VTK thread: PyVista's view to ``path`` (None), or why it could not be drawn."""
    ok, why = offscreen_rendering_available()  # VTK would crash the process otherwise
    if not ok:
        return why
    try:
        render_pyvista(path, vertices, faces, error_mm, title)
    except Exception as exc:  # noqa: BLE001 - any VTK/OpenGL failure: use the fallback
        return f"PyVista failed: {exc}"
    return None


def start_surface(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> Future:
    """Start PyVista's view of :func:`render_surface` in the VTK thread (after the off-screen
    check) and return at once; :func:`finish_surface` collects it."""
    return _vtk().submit(_pyvista_job, path, vertices, faces, error_mm, title)


def finish_surface(
    started: Future,
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> tuple[str, str | None]:
    """Wait for the view :func:`start_surface` started (same arguments); where PyVista could
    not draw it, draw it with matplotlib. ``(renderer, warning)`` as :func:`render_surface`."""
    why = started.result()
    if why is None:
        return "pyvista", None
    warning = (
        f"3D view drawn with matplotlib: PyVista off-screen rendering is not available here "
        f"({why}); install the EGL library (Debian: libegl1) or OSMesa (libosmesa6)"
    )
    render_matplotlib(path, vertices, faces, error_mm, title)
    return "matplotlib", " ".join(warning.split())


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
    args = (path, vertices, faces, error_mm, title)
    return finish_surface(start_surface(*args), *args)


def _warm_job(with_error: bool, size: tuple[int, int]) -> None:
    """In the VTK thread: the scene of ``(size, with_error)`` built and rendered once."""
    if (tuple(size), with_error) in _scenes or not offscreen_rendering_available()[0]:
        return
    for key, value in offscreen_env().items():
        os.environ.setdefault(key, value)
    import pyvista as pv

    mesh = pv.Sphere()
    error = np.abs(mesh.points[:, 2]) if with_error else None
    if error is not None:
        mesh.point_data["error (mm)"] = error
    scene = _new_scene(mesh, error, size)
    try:
        _draw(scene, mesh, error, "")
    except BaseException:
        scene.plotter.close()
        raise
    _scenes[(tuple(size), with_error)] = scene


def warm_scene(with_error: bool, size: tuple[int, int] = SIZE_PX) -> Future:
    """Build the 3D view's scene (PyVista imported, the window opened, its shaders compiled by
    one render) in the VTK thread, where off-screen rendering works; returns at once."""
    return _vtk().submit(_warm_job, with_error, size)


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
