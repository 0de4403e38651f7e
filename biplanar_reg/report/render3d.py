"""3D view of a surface coloured by its error, with a colour bar in mm.

The default renderer is software (:func:`render_software`): the mesh seen from the isometric
direction (orthographic, z up, as PyVista's ``view_isometric``), each triangle filled in
painter's order (farthest first, back faces of a closed mesh left out) with the mean of its
corners' colours (viridis of the error, times a Lambert shade under a light at the eye from
area-weighted vertex normals, i.e. smooth shading), drawn at twice the size and reduced
(anti-aliasing), then put on a :mod:`.raster_plot` canvas with the title and colour bar. It needs no
OpenGL and imports neither PyVista nor VTK (their import alone cost more than the whole
report's other figures).

``BIPLANAR_REG_RENDERER=pyvista`` renders with PyVista off-screen instead (with no
``DISPLAY`` the X11 render window fails, "bad X server connection", and VTK >= 9.4 falls back
to EGL; this module asks for the EGL window directly, ``VTK_DEFAULT_OPENGL_WINDOW=
vtkEGLRenderWindow``). Where neither EGL nor OSMesa works, VTK's window kills the process
(SIGSEGV) instead of raising, so :func:`.gl_probe.offscreen_rendering_available` first tries a
render in a child process (once per process); when that fails, or PyVista raises, the
software renderer draws the view and one warning line is logged.
``BIPLANAR_REG_RENDERER=matplotlib`` draws a matplotlib 3D triangle plot.
"""

from __future__ import annotations

import logging
import os

import numpy as np

from .gl_probe import offscreen_env, offscreen_rendering_available

__all__ = ["render_error_mesh"]

#: Supersampling factor of the software renderer (each side), for anti-aliased edges.
_SUPERSAMPLE = 2

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
    """Render with PyVista off-screen (surface, error colour map, colour bar in mm).

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
    _save_matplotlib(fig, path)


def _save_matplotlib(fig, path: str | os.PathLike) -> None:
    """A matplotlib figure drawn with the Agg canvas, written as an RGB PNG (the opt-in
    matplotlib renderer only)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from .raster_plot import Canvas

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    out = Canvas(rgba.shape[1], rgba.shape[0])
    out.paste(rgba[:, :, :3], 0, 0)
    out.save(path)


def _isometric_frame(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (right, up, towards the eye) (3, 3) of the isometric view (eye along
    +(1, 1, 1), z up) and the bounding-box centre (3,), mm."""
    eye = np.ones(3) / np.sqrt(3.0)
    right = np.cross(np.array([0.0, 0.0, 1.0]), eye)
    right /= np.linalg.norm(right)
    up = np.cross(eye, right)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return np.stack([right, up, eye]), (lo + hi) / 2


def _vertex_shade(V: np.ndarray, F: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """Lambert shade in [0.25, 1] of each vertex under a light at the eye: ambient 0.25 plus
    0.75 |n . eye| with ``n`` the area-weighted vertex normal."""
    n_face = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    # only n . eye is needed: sum each face's n . eye and |n|-components over its corners
    corners = F.ravel()
    n = np.column_stack(
        [np.bincount(corners, np.repeat(n_face[:, c], 3), len(V)) for c in range(3)]
    )
    length = np.linalg.norm(n, axis=1)
    lit = np.abs(n @ eye) / np.where(length > 0, length, 1.0)
    return 0.25 + 0.75 * np.where(length > 0, lit, 1.0)


def software_image(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_rgb: np.ndarray,
    size: tuple[int, int],
    *,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> np.ndarray:
    """The isometric software rendering (H, W, 3) in [0, 1] of a mesh with per-vertex colours.

    Parameters
    ----------
    vertices : (N, 3) array, mm
    faces : (F, 3) int array
    vertex_rgb : (N, 3) array in [0, 1]
        Unlit colour of each vertex (the shade is applied here).
    size : (W, H)
        Image size, pixels; the mesh fills 90 % of its smaller side.
    """
    return _software_rgb8(vertices, faces, vertex_rgb, size, background).astype(float) / 255.0


def _software_rgb8(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_rgb: np.ndarray,
    size: tuple[int, int],
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> np.ndarray:
    """:func:`software_image` as (H, W, 3) uint8."""
    import cv2

    from .raster_plot import fill_rgb
    from .shading import _outward_sign

    V = np.asarray(vertices, float)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    axes, centre = _isometric_frame(V)
    xyz = (V - centre) @ axes.T  # (right, up, towards the eye)
    w, h = size[0] * _SUPERSAMPLE, size[1] * _SUPERSAMPLE
    half = max(float(np.abs(xyz[:, :2]).max()), 1e-9)
    scale = 0.45 * min(w, h) / half
    uv = np.column_stack([w / 2 + scale * xyz[:, 0], h / 2 - scale * xyz[:, 1]])
    rgb = np.clip(np.asarray(vertex_rgb, float), 0, 1) * _vertex_shade(V, F, axes[2])[:, None]
    tri2 = uv[F]
    area2 = (tri2[:, 1, 0] - tri2[:, 0, 0]) * (tri2[:, 2, 1] - tri2[:, 0, 1]) - (
        tri2[:, 2, 0] - tri2[:, 0, 0]
    ) * (tri2[:, 1, 1] - tri2[:, 0, 1])
    outward = _outward_sign(F, V[F], len(V))
    keep = np.ones(len(F), bool) if outward is None else outward * area2 <= 0.0
    depth = xyz[F, 2].mean(axis=1)
    order = np.flatnonzero(keep)[np.argsort(depth[keep], kind="stable")]  # farthest first
    shift = 4  # cv2 fixed-point sub-pixel precision (1/16 px)
    pts = np.round(tri2[order] * (1 << shift)).astype(np.int32)
    cols = np.round(rgb[F[order]].mean(axis=1) * 255).astype(int).tolist()
    image = np.empty((h, w, 3), np.uint8)
    fill_rgb(image, np.round(np.asarray(background) * 255).astype(np.uint8).tolist())
    for tri, col in zip(pts, cols, strict=True):
        cv2.fillConvexPoly(image, tri, col, lineType=cv2.LINE_8, shift=shift)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def render_software(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
    *,
    size: tuple[int, int] = (900, 700),
) -> None:
    """Render with :func:`software_image` into a figure of ``size`` pixels: the title top left,
    with ``error_mm`` a viridis colour bar in mm on the right, else one ivory colour. The
    rendering is put on the drawn figure pixel for pixel (no axes, no resampling)."""
    from .raster_plot import Canvas, colour, colour_bar, viridis_rgb

    canvas = Canvas(*size, dpi=100)
    n = len(vertices)
    if error_mm is not None:
        top = _error_max(error_mm)
        vertex_rgb = viridis_rgb(np.asarray(error_mm, float), 0.0, top)
    else:
        vertex_rgb = np.tile(np.array(colour("ivory"), float) / 255.0, (n, 1))
    # the rendering fills the figure's lower left 86 % x 94 % (the title above, the colour
    # bar to the right)
    w, h = round(0.86 * size[0]), round(0.94 * size[1])
    canvas.paste(_software_rgb8(vertices, faces, vertex_rgb, (w, h)), 0, size[1] - h)
    canvas.text(0.005 * size[0], 0.015 * size[1], title, size_pt=11, va="top")
    if error_mm is not None:
        bar = (0.90 * size[0], 0.44 * size[1], 0.925 * size[0], 0.94 * size[1])
        colour_bar(canvas, bar, 0.0, top, title="error (mm)", tick_pt=9)
    canvas.save(path)


def render_error_mesh(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    error_mm: np.ndarray | None,
    title: str,
) -> str:
    """Render the mesh coloured by ``error_mm`` (per vertex) to a PNG; returns the renderer used
    ("software", or with ``BIPLANAR_REG_RENDERER`` set, "pyvista" or "matplotlib")."""
    choice = os.environ.get("BIPLANAR_REG_RENDERER", "").lower()
    if choice == "matplotlib":
        render_matplotlib(path, vertices, faces, error_mm, title)
        return "matplotlib"
    if choice == "pyvista":
        ok, why = offscreen_rendering_available()  # VTK would crash the process otherwise
        if not ok:
            log.warning(
                "PyVista off-screen rendering is not available here (%s); using software", why
            )
        else:
            try:
                render_pyvista(path, vertices, faces, error_mm, title)
                return "pyvista"
            except Exception as exc:  # noqa: BLE001 - any VTK/OpenGL failure: use the fallback
                log.warning("PyVista off-screen rendering failed (%s); using software", exc)
    render_software(path, vertices, faces, error_mm, title)
    return "software"
