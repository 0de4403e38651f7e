"""Synthetic scenes with a known ground truth: a bone-like shape model, X-ray views, poses,
the rays and outlines a registration sees.

Everything is seeded and deterministic: the same arguments (and the same state of a given
``numpy.random.Generator``) give the same numbers. Lengths are mm, pixels ``(u, v)`` are
(column, row) of the view's image; the world frame is the views' (``X_cam = R @ X + t``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ..annotation import Contour
from ..calibration.views import PerspectiveView, View
from ..outline import outline_polylines
from ..pose import Pose
from ..registration import ViewObservations
from ..registration.rays import RayObservations
from ..ssm import ShapeModel

__all__ = [
    "synthetic_bone_model",
    "look_at_view",
    "biplanar_views",
    "random_pose",
    "noisy_pixels",
    "observe",
    "outline_stretch",
    "vertex_landmarks",
    "boosting_case",
]


def _capsule_mesh(
    length: float, radius: float, n_u: int, n_v: int
) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-oriented capsule-like surface along z, centred at the origin.

    Returns the vertices ``(n_u * n_v + 2, 3)`` (mm; the two poles last) and the faces
    ``(F, 3)``."""
    v = np.linspace(0.0, np.pi, n_v + 2)[1:-1]  # polar angle, poles added separately
    u = np.linspace(0.0, 2 * np.pi, n_u, endpoint=False)
    V, U = np.meshgrid(v, u, indexing="ij")
    # a bone-like profile: a shaft that flares at one end (distal metaphysis)
    z = -np.cos(V) * length / 2
    flare = 1.0 + 0.6 * np.exp(-(((z - length / 2) / (0.18 * length)) ** 2))
    r = radius * np.sin(V) ** 0.6 * flare
    x = r * np.cos(U) * 1.15
    y = r * np.sin(U) * 0.85
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    south = np.array([[0.0, 0.0, -length / 2]])
    north = np.array([[0.0, 0.0, length / 2 * 1.0]])
    verts = np.vstack([pts, south, north])
    s_id, n_id = len(pts), len(pts) + 1
    faces = []
    for i in range(n_v - 1):
        for j in range(n_u):
            a = i * n_u + j
            b = i * n_u + (j + 1) % n_u
            c = (i + 1) * n_u + j
            d = (i + 1) * n_u + (j + 1) % n_u
            faces += [(a, c, b), (b, c, d)]
    for j in range(n_u):
        faces.append((s_id, j, (j + 1) % n_u))
        top = (n_v - 1) * n_u
        faces.append((n_id, top + (j + 1) % n_u, top + j))
    faces = np.array(faces, dtype=np.int64)
    # orient outwards: the signed volume must be positive
    tri = verts[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    if vol < 0:
        faces = faces[:, ::-1]
    return verts, faces


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals (N, 3): the area-weighted sum of the adjacent face normals."""
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.linalg.norm(vn, axis=1, keepdims=True)


def synthetic_bone_model(
    n_modes: int = 8,
    *,
    length: float = 60.0,
    radius: float = 9.0,
    resolution: tuple[int, int] = (24, 20),
    mode_rms: float = 1.5,
    bump_width: float = 12.0,
    seed: int = 0,
) -> ShapeModel:
    """A bone-like surface model with smooth, non-affine deformation modes.

    Each mode displaces the surface along its normals by a sum of Gaussian bumps at random
    surface points, scaled to ``mode_rms`` mm RMS per unit weight (weights are then in
    "standard deviations" as for a PCA model).

    Parameters
    ----------
    n_modes : int
        Number of modes M.
    length, radius : float
        Size of the shape, mm.
    resolution : (n_around, n_along)
        Mesh resolution (vertices around the shaft and along it).
    mode_rms : float
        RMS displacement of each mode per unit weight, mm.
    bump_width : float
        Width (standard deviation) of the bumps, mm.
    seed : int
        Random seed.
    """
    rng = np.random.default_rng(seed)
    verts, faces = _capsule_mesh(length, radius, *resolution)
    normals = _vertex_normals(verts, faces)
    modes = np.zeros((n_modes, len(verts), 3))
    for i in range(n_modes):
        centres = verts[rng.choice(len(verts), size=4, replace=False)]
        amp = rng.normal(size=4)
        d2 = ((verts[:, None, :] - centres[None]) ** 2).sum(-1)
        field = (amp * np.exp(-d2 / (2 * bump_width**2))).sum(1)
        disp = field[:, None] * normals
        modes[i] = disp * mode_rms / np.sqrt(np.mean(np.sum(disp**2, axis=1)))
    names = {"distal_tip": int(np.argmax(verts[:, 2])), "proximal_tip": int(np.argmin(verts[:, 2]))}
    return ShapeModel(verts, modes, faces=faces, variances=np.ones(n_modes), landmarks=names)


def look_at_view(
    source: np.ndarray,
    target: np.ndarray | None = None,
    *,
    sdd: float = 1200.0,
    pixel: float = 0.3,
    image_size: tuple[int, int] = (1024, 1024),
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
    name: str = "",
) -> PerspectiveView:
    """A perspective X-ray view with its source at ``source`` looking at ``target``.

    Parameters
    ----------
    source : (3,) array
        X-ray source (camera centre), world frame, mm.
    target : (3,) array, optional
        Point on the principal ray, world frame, mm (default: the origin).
    sdd : float
        Source-detector distance, mm.
    pixel : float
        Detector pixel spacing, mm; the focal length is ``sdd / pixel`` pixels.
    image_size : (W, H)
        Image size, pixels; the principal point is the image centre ``((W-1)/2, (H-1)/2)``.
    up : (3,) array
        World direction of the image's +v axis (rows), projected perpendicular to the
        principal ray ``z``: the camera x axis is ``up x z``, its y axis ``z x x``. When
        ``up`` is parallel to the principal ray, world x takes its place.
    name : str
        The view's name.

    Returns
    -------
    PerspectiveView
        No distortion; extrinsics ``X_cam = R @ X + t``.
    """
    target = np.zeros(3) if target is None else np.asarray(target, float)
    z = target - np.asarray(source, float)
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    t = -R @ np.asarray(source, float)
    f = sdd / pixel
    W, H = image_size
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
    return PerspectiveView(R=R, t=t, K=K, image_size=image_size, name=name)


def biplanar_views(
    angle_deg: float = 75.0, *, sod: float = 900.0, sdd: float = 1200.0, pixel: float = 0.3
) -> list[View]:
    """Two perspective views of the origin, ``angle_deg`` apart about the world y axis.

    Sources at ``sod`` mm from the origin (source-object distance) on either side of the -z
    axis; ``sdd`` (mm) and ``pixel`` (mm) as for :func:`look_at_view` (1024 x 1024 pixels).

    Returns
    -------
    list of PerspectiveView
        Named ``cam1`` (source at -x) and ``cam2`` (+x).
    """
    a = np.deg2rad(angle_deg) / 2
    s1 = sod * np.array([-np.sin(a), 0.0, -np.cos(a)])
    s2 = sod * np.array([np.sin(a), 0.0, -np.cos(a)])
    return [
        look_at_view(s1, sdd=sdd, pixel=pixel, name="cam1"),
        look_at_view(s2, sdd=sdd, pixel=pixel, name="cam2"),
    ]


def random_pose(rng: np.random.Generator, max_offset: float = 10.0) -> Pose:
    """A uniformly random rotation and a translation within ``max_offset`` mm of the origin.

    Draws the rotation, then the translation (uniform in each coordinate), from ``rng``.

    Returns
    -------
    Pose
        Object frame -> world; ``t`` in mm.
    """
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-max_offset, max_offset, size=3)
    return Pose(R, t)


def noisy_pixels(
    views: Sequence[View],
    vertices: np.ndarray,
    ids_per_view: Sequence[np.ndarray],
    *,
    noise_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> list[np.ndarray]:
    """The pixels of the given vertices in each view, plus Gaussian pixel noise.

    Parameters
    ----------
    views : sequence of View
        The views (world frame, mm).
    vertices : (N, 3) array
        Posed model vertices, world frame, mm.
    ids_per_view : sequence of (K_i,) int arrays
        The vertices seen in each view (one array per view; may be empty).
    noise_px : float
        Standard deviation of the noise added to each pixel coordinate, pixels (0: exact).
    rng : numpy.random.Generator, optional
        Source of the noise (default ``default_rng(0)``); one ``normal`` draw of shape
        ``(K_i, 2)`` per non-empty view, in view order, only when ``noise_px > 0``.

    Returns
    -------
    list of (K_i, 2) arrays
        Pixels ``(u, v)`` of each view, in the order of ``ids_per_view[i]``.
    """
    rng = rng or np.random.default_rng(0)
    out = []
    for view, ids in zip(views, ids_per_view, strict=True):
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size == 0:  # no draw: an empty view leaves the noise of the others unchanged
            out.append(np.zeros((0, 2)))
            continue
        uv = view.project(vertices[ids])
        if noise_px > 0:
            uv = uv + rng.normal(scale=noise_px, size=uv.shape)
        out.append(uv)
    return out


def observe(
    views: Sequence[View],
    vertices: np.ndarray,
    ids_per_view: Sequence[np.ndarray],
    *,
    noise_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> RayObservations:
    """Rays through the (noisy) pixels of the given vertices in each view.

    The pixels are those of :func:`noisy_pixels` (same arguments, same draws); each is
    back-projected to its view's ray (``View.rays``). Call :func:`noisy_pixels` itself when the
    pixels are needed too: ``observe`` is that followed by the back-projection.

    Parameters
    ----------
    views, vertices, ids_per_view, noise_px, rng
        As for :func:`noisy_pixels`.

    Returns
    -------
    RayObservations
        The rays in the world frame (origins mm, unit directions), view by view in order,
        ``view_index`` the index of each ray's view in ``views``, ``sigmas`` unknown (None).
    """
    pixels = noisy_pixels(views, vertices, ids_per_view, noise_px=noise_px, rng=rng)
    parts = []
    for i, (view, ids, uv) in enumerate(zip(views, ids_per_view, pixels, strict=True)):
        if len(uv) == 0:
            continue
        o, d = view.rays(uv)
        parts.append(RayObservations(np.asarray(ids, np.int64), o, d, None, np.full(len(uv), i)))
    return RayObservations.concatenate(parts)


def outline_stretch(
    outline: np.ndarray, closed: bool, fraction: float, rng: np.random.Generator
) -> np.ndarray:
    """A contiguous stretch of ``fraction`` of an outline polyline (K, 2) from a random start.

    A closed loop may wrap around its start; an open polyline never does (wrapping would join
    its two ends with a chord across the shape).
    """
    keep = int(fraction * len(outline))
    if closed:
        return np.roll(outline, -int(rng.integers(len(outline))), axis=0)[:keep]
    start = int(rng.integers(len(outline) - keep + 1))
    return outline[start : start + keep]


def vertex_landmarks(
    name: str,
    view: View,
    ids: np.ndarray,
    uv: np.ndarray,
    contours: Sequence[Contour] = (),
    sigma_px: float = 1.0,
) -> ViewObservations:
    """A view's observations whose landmarks are model vertices, for ``register_views``.

    Parameters
    ----------
    name : str
        The view's name.
    view : View
        Its calibration (world frame, mm).
    ids : (K,) int array
        The observed model vertices; landmark ``j`` is named ``v<ids[j]>``.
    uv : (K, 2) array
        Their pixels ``(u, v)`` (projected, with any noise already added).
    contours : sequence of Contour
        Annotated outline pieces, pixels (default none).
    sigma_px : float
        Every landmark's standard deviation, pixels.
    """
    return ViewObservations(
        name=name,
        view=view,
        landmark_names=[f"v{i}" for i in ids],
        landmark_ids=ids,
        landmark_uv=uv,
        landmark_sigma_px=np.full(len(ids), float(sigma_px)),
        contours=list(contours),
    )


def boosting_case(
    model: ShapeModel,
    seed: int,
    *,
    fraction: float = 0.7,
    noise_px: float = 0.0,
    landmarks_per_view: int | tuple[int, int] = 3,
    outline_noise_px: float | None = None,
    random_stretch: bool = False,
) -> tuple[list[ViewObservations], tuple[np.ndarray, ...]]:
    """A seeded two-view silhouette-boosting problem with its truth.

    A random instance (weights ~ N(0, 1)) in a random pose (:func:`random_pose`), the two views
    of :func:`biplanar_views` (75 deg apart), ``landmarks_per_view`` landmarks at random
    vertices per view (one count, or one per view) and ``fraction`` of each view's outline (the
    longest chain of the mesh silhouette; open unless ``fraction >= 1``): its first part, or
    with ``random_stretch`` a stretch from a random start (:func:`outline_stretch`). Gaussian
    noise: ``noise_px`` on the landmarks, ``outline_noise_px`` (default ``noise_px``) on the
    outline points.

    Returns
    -------
    views : list of ViewObservations
        Named ``cam1``, ``cam2``; landmarks named ``v<vertex id>`` with 1 px sigmas
        (:func:`vertex_landmarks`).
    truth : (w, R, t, X)
        Weights, object-to-world rotation and translation (mm) and the posed vertices (N, 3).
    """
    rng = np.random.default_rng(seed)
    w = rng.normal(size=model.n_modes)
    pose = random_pose(rng)
    R, t = pose.rt
    X = pose.apply(model.instance(w))
    counts = np.broadcast_to(np.asarray(landmarks_per_view, dtype=int), (2,))
    sigma_outline = noise_px if outline_noise_px is None else outline_noise_px
    views = []
    for name, view, n in zip(("cam1", "cam2"), biplanar_views(75.0), counts, strict=True):
        ids = rng.choice(model.n_vertices, n, replace=False)
        uv = view.project(X[ids]) + noise_px * rng.normal(size=(n, 2))
        polys, closed = outline_polylines(X, view, model.faces)
        outline = polys[0]
        if random_stretch:
            outline = outline_stretch(outline, closed[0], fraction, rng)
        outline = outline + sigma_outline * rng.normal(size=outline.shape)
        if not random_stretch:
            outline = outline[: int(fraction * len(outline))]
        contours = [Contour(uv=outline, closed=fraction >= 1.0)]
        views.append(vertex_landmarks(name, view, ids, uv, contours))
    return views, (w, R, t, X)
