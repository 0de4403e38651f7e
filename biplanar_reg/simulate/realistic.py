"""Realistic registration cases: truth out of the model's span, an overlapping second bone,
livewire-traced open outlines, click noise, blunders and calibration errors.

A :class:`RealisticScene` holds what every case of a benchmark shares: a bone template, a
harmonic population of it (:func:`biplanar_reg.ssm.synthesise_population`), the shape model
built from its first ``n_train`` members only (so the other members, the truths, are out of the
model's span), a second bone beside the first (rendered into the radiographs, where it overlaps
the bone's outline), a soft-tissue cylinder around both, and the calibrated views.
:func:`wrist_scene` builds one from the wrist data of a clone (``sample_cases/wrist_radius/data``:
the distal radius and ulna CT volumes and the two real MayaCam 2.0 calibrations).

:func:`make_realistic_case` makes one seeded case from it, as an annotator would see it:

* truth: held-out member ``n_train + seed % (n_population - n_train)``, posed near the scene's
  nominal pose (rotation perturbed by up to 10 deg, translation by up to 3 mm); the second bone
  moves with it, plus up to 3 deg / 2 mm of its own;
* views: the scene's calibrations read out in a window around both bones (the principal
  point moves, nothing else), radiographs ``exp(-mu L)`` of bone (0.05/mm), second bone and
  soft tissue (0.01/mm), 0.8 px blur, Gaussian noise 0.01;
* outlines: per view one open stretch of ``outline_fraction`` (drawn in the range) of the
  bone's true projected outline (:func:`biplanar_reg.outline.outline_polylines` through the
  renderer), anchors every ``anchor_spacing_px`` along it plus ``N(0, anchor_noise_px)``,
  traced with the project's :func:`biplanar_reg.annotation.livewire` on the radiograph (which
  follows whatever edge is strongest: near the second bone it may follow that one);
* landmarks: ``n_landmarks_per_view`` of the model's landmarks (the same ones in both views),
  the truth's vertices projected plus ``N(0, landmark_noise_px)`` per coordinate, stated sigma
  ``landmark_noise_px``; with ``blunder_px`` one of them (random view, landmark, direction)
  moved that many pixels;
* calibration error ``(deg, mm)``: the second view's (the first view is the gauge) pose is
  given to the registration wrong by a rigid motion of that size about the bone's centre
  (random axis and direction; the pixels were made with the true one).

Every random draw is made whatever the options (they only scale what is applied), so cases of
the same seed differ only by what the options change: a blunder case is the clean case plus the
blunder, 3 landmarks per view are the first 3 of the 5. Renders and traced outlines are cached
per (scene, seed) within a process. The model floor is the best prior-free rigid + model fit of
the truth vertices (:func:`model_floor`). Lengths are mm, pixels ``(u, v)``; world = the
calibrations' frame.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from skimage.measure import find_contours

from ..annotation import Contour, clean_contour, livewire, render_radiograph
from ..annotation.render import path_lengths
from ..calibration import load_calibration
from ..calibration.views import PerspectiveView
from ..io import read_json, read_volume
from ..pose import Pose
from ..registration import ViewObservations
from ..ssm import ShapeModel, bone_surface, build_ssm, synthesise_population
from .case_folder import synthetic_landmarks
from .scenes import outline_stretch

__all__ = [
    "RealisticScene",
    "RealisticCase",
    "wrist_scene",
    "make_realistic_case",
    "model_floor",
    "perturb_view",
]

#: Voxel size (column, row, slice) of the shipped wrist CT volumes, mm (their README).
WRIST_CT_VOXEL_MM = (0.39625, 0.39625, 0.625)
#: Attenuation of bone and soft tissue, 1/mm.
MU_BONE, MU_SOFT = 0.05, 0.01


@dataclass(frozen=True, eq=False)
class RealisticScene:
    """What the cases of a benchmark share (see the module docstring).

    Attributes
    ----------
    name : str
        For tables and cache keys.
    faces : (F, 3) int array
        The bone's triangles (every member shares them).
    population : (S, N, 3) array
        Members, template frame, mm; the model is built from the first ``n_train``.
    n_train : int
    model : ShapeModel
        With landmarks (:func:`~.case_folder.synthetic_landmarks` not on ``cut``).
    second : (vertices (K, 3), faces) tuple
        The second bone, template frame, mm, placed beside the bone.
    tissue : (centre (3,), radius) tuple
        A soft-tissue cylinder along the template's z axis around both bones, mm.
    views : list of PerspectiveView
        The full calibrations (world frame, mm).
    pose : Pose
        Nominal pose of the template in the world (template -> world, ``X = R @ x + t``), mm.
    cut : (N,) bool array
        Vertices of the bone that are no anatomy (the CT crop's cut across the shaft): an
        annotator never traces their outline (there is none in a radiograph).
    """

    name: str
    faces: np.ndarray
    population: np.ndarray
    n_train: int
    model: ShapeModel
    second: tuple[np.ndarray, np.ndarray]
    tissue: tuple[np.ndarray, float]
    views: list[PerspectiveView]
    pose: Pose
    cut: np.ndarray

    @property
    def n_held_out(self) -> int:
        """Number of members not in the model (the truths)."""
        return len(self.population) - self.n_train


@dataclass(frozen=True, eq=False)
class RealisticCase:
    """One realistic case (world frame, mm; pixels ``(u, v)``).

    Attributes
    ----------
    seed : int
    model : ShapeModel
        The model to register (truth out of its span).
    views : list of ViewObservations
        What :func:`biplanar_reg.registration.register_views` takes: the calibrations as given
        (with the calibration error, if any), landmarks, traced open contours.
    truth_vertices : (N, 3) array
        The true bone, world frame, mm.
    floor_mm : float
        Model floor: vertex RMS of the best rigid + model fit of the truth (prior-free), mm.
    true_views : list of PerspectiveView
        The calibrations the radiographs were made with (cropped windows).
    truth_pose : Pose
        Template frame -> world of the truth, mm.
    member : int
        Population member of the truth (>= ``scene.n_train``).
    blunder : dict or None
        ``{"view", "landmark", "offset_px": [du, dv]}`` of the injected blunder.
    calibration_error : dict or None
        ``{"view", "deg", "mm"}`` of the injected calibration error.
    radiographs : list of (H, W) arrays
        The rendered images (transmitted fraction).
    true_outlines : list of (K, 2) arrays
        The bone's full true outline per view (longest polyline), pixels.
    outline_fraction : list of float
        Fraction of the true outline the traced stretch was drawn along, per view.
    overlap_fraction : list of float
        Fraction of the true outline lying over the second bone, per view.
    """

    seed: int
    model: ShapeModel
    views: list[ViewObservations]
    truth_vertices: np.ndarray
    floor_mm: float
    true_views: list[PerspectiveView]
    truth_pose: Pose
    member: int
    blunder: dict | None = None
    calibration_error: dict | None = None
    radiographs: list[np.ndarray] = field(default_factory=list, repr=False)
    true_outlines: list[np.ndarray] = field(default_factory=list, repr=False)
    outline_fraction: list[float] = field(default_factory=list)
    overlap_fraction: list[float] = field(default_factory=list)


# -- the model floor ------------------------------------------------------------------------------
def model_floor(
    model: ShapeModel, truth: np.ndarray, iterations: int = 200, tol: float = 1e-10
) -> tuple[float, np.ndarray]:
    """The best the model can do: vertex RMS (mm) of ``min_{R, t, w} |R x(w) + t - truth|``.

    Prior-free least squares over rotation, translation and all the model's weights, by
    alternating the linear weight fit and the rigid (Kabsch) fit from the mean's rigid fit
    (each step lowers the cost; stopped when it changes by less than ``tol`` relative).

    Returns
    -------
    floor_mm : float
    fit : (N, 3) array
        The best fit, world frame, mm.
    """
    truth = np.asarray(truth, float)
    P = model.modes.reshape(model.n_modes, 3 * model.n_vertices).T  # (3N, M)
    w = np.zeros(model.n_modes)
    prev = np.inf
    for _ in range(iterations):
        shape = model.instance(w)
        local = Pose.fit_rigid(shape, truth).inverse().apply(truth)  # truth in the model frame
        if P.shape[1]:
            w = np.linalg.lstsq(P, (local - model.mean).ravel(), rcond=None)[0]
        cost = float(np.mean(np.sum((model.instance(w) - local) ** 2, axis=1)))
        if prev - cost <= tol * max(cost, 1e-300):
            break
        prev = cost
    shape = model.instance(w)
    fit = Pose.fit_rigid(shape, truth).apply(shape)
    return float(np.sqrt(np.mean(np.sum((fit - truth) ** 2, axis=1)))), fit


# -- scenes ---------------------------------------------------------------------------------------
def _wrist_data(data_dir: str | Path) -> Path:
    """The wrist data folder, checked: the CT volumes and calibrations must be there."""
    data = Path(data_dir)
    need = ["radius_ct.tif", "ulna_ct.tif", "cam01_calibration_mayacam2.txt"]
    missing = [n for n in need if not (data / n).is_file()]
    if missing:
        raise ValueError(f"{data}: not the wrist data folder (no {', '.join(missing)})")
    return data


def _overlap_direction(views: list[PerspectiveView], pose: Pose, centre: np.ndarray) -> np.ndarray:
    """The direction across the long (z) axis of the template frame in which a neighbour of a
    bone at ``centre`` hides behind it most in every view: the unit ``u = (cos a, sin a, 0)``
    whose largest image-plane component over the views is smallest (then the second bone
    overlaps the bone's outline in all views, as the ulna overlaps the radius)."""
    world = pose.apply(centre)
    best, best_u = np.inf, np.array([0.0, 1.0, 0.0])
    for a in np.deg2rad(np.arange(0.0, 180.0, 2.0)):
        u = np.array([np.cos(a), np.sin(a), 0.0])
        o = pose.R @ u
        side = 0.0
        for v in views:
            d = world - v.centre
            d /= np.linalg.norm(d)
            side = max(side, float(np.linalg.norm(o - (o @ d) * d)))
        if side < best:
            best, best_u = side, u
    return best_u


def _beside(bone: np.ndarray, other: np.ndarray, u: np.ndarray, gap_mm: float) -> np.ndarray:
    """``other`` (K, 3) translated to lie beside ``bone`` in the direction ``u`` (across z),
    ``gap_mm`` beyond both bones' extents along ``u``, with its distal (low-z) end 4 mm
    proximal of the bone's: where the ulna sits beside the distal radius in the CT frame."""
    cb, co = bone.mean(axis=0), other.mean(axis=0)
    d = np.max((bone - cb) @ u) + np.max(-(other - co) @ u) + gap_mm
    shift = cb - co + d * u
    shift[2] = bone[:, 2].min() + 4.0 - other[:, 2].min()
    return other + shift


def _tissue(points: np.ndarray, margin_mm: float = 12.0) -> tuple[np.ndarray, float]:
    """A cylinder of soft tissue along z enclosing ``points`` (mm) with ``margin_mm`` to spare:
    a point on its axis and its radius (mm)."""
    c = points.mean(axis=0)
    r = float(np.max(np.linalg.norm(points[:, :2] - c[:2], axis=1))) + margin_mm
    return c, r


def _cylinder_lengths(
    view: PerspectiveView, centre: np.ndarray, axis: np.ndarray, radius: float
) -> np.ndarray:
    """Path length (H, W) of every pixel's ray through an infinite cylinder, mm (exact)."""
    w, h = view.image_size
    vv, uu = np.mgrid[0:h, 0:w]
    o, d = view.rays(np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    rel = o - centre
    op = rel - np.outer(rel @ axis, axis)
    dp = d - np.outer(d @ axis, axis)
    a = np.sum(dp * dp, axis=1)
    b = 2 * np.sum(op * dp, axis=1)
    c = np.sum(op * op, axis=1) - radius**2
    disc = np.maximum(b * b - 4 * a * c, 0.0)
    return (np.sqrt(disc) / np.maximum(a, 1e-12)).reshape(h, w)


def model_off_the_cut(
    template: np.ndarray,
    shapes: np.ndarray,
    faces: np.ndarray,
    n_modes: int,
    bone: str = "radius",
) -> tuple[ShapeModel, np.ndarray]:
    """The SSM of ``shapes`` (``n_modes`` modes) with synthetic landmarks off the CT crop's cut,
    and the cut mask (``template``'s vertices within 4 mm of its top along z, mm): no landmark
    on the cut, whose centre ("proximal_end") is nowhere in a radiograph. The landmarks have
    the anatomical names of ``bone`` (``"radius"`` or ``"ulna"``,
    :func:`~.case_folder.synthetic_landmarks`)."""
    model = build_ssm(shapes, faces=faces, n_modes=n_modes)
    cut = template[:, 2] > template[:, 2].max() - 4.0
    marks = synthetic_landmarks(model, distal_sign=-1.0, bone=bone)
    model = ShapeModel(
        model.mean,
        model.modes,
        faces=model.faces,
        variances=model.variances,
        landmarks={k: i for k, i in marks.items() if not cut[i]},
        truncation_modes=model.truncation_modes,
    )
    return model, cut


@functools.lru_cache(maxsize=4)
def wrist_scene(
    data_dir: str,
    *,
    n_vertices: int = 1000,
    n_population: int = 18,
    n_train: int = 8,
    n_modes: int = 6,
    seed: int = 0,
    resolution: int = 40,
) -> RealisticScene:
    """The default scene: the distal radius and the ulna of the shipped wrist CT and the two
    real calibrations (cached).

    Parameters
    ----------
    data_dir : str
        The folder of ``radius_ct.tif``, ``ulna_ct.tif`` and the two MayaCam 2.0 calibrations
        ``cam0{1,2}_calibration_mayacam2.txt``, with the rough pose of the radius in
        ``../annotation/rough_pose.json``: ``sample_cases/wrist_radius/data`` of a clone (the
        installed package ships no data).
    n_vertices : int
        Target vertex count of the radius surface (the ulna gets 600).
    n_population, n_train, n_modes : int
        Population size (seed ``seed``), members the model is built from, modes kept.
    resolution : int
        Laplace grid of the population's harmonic coordinates (intervals along the longest
        axis; a coarser grid is faster and as smooth).
    """
    data = _wrist_data(data_dir)
    rad = bone_surface(
        read_volume(data / "radius_ct.tif", voxel_size=WRIST_CT_VOXEL_MM),
        target_vertices=n_vertices,
    )
    uln = bone_surface(
        read_volume(data / "ulna_ct.tif", voxel_size=WRIST_CT_VOXEL_MM), target_vertices=600
    )
    pop = synthesise_population(rad.vertices, n_population, seed=seed, resolution=resolution)
    model, cut = model_off_the_cut(rad.vertices, pop.shapes[:n_train], rad.faces, n_modes)
    rough = read_json(data.parent / "annotation" / "rough_pose.json")
    pose = Pose(rough["R"], rough["t"])
    views = [
        load_calibration(data / f"{n}_calibration_mayacam2.txt", name=n) for n in ("cam01", "cam02")
    ]
    u = _overlap_direction(views, pose, rad.vertices.mean(axis=0))
    ulna = _beside(rad.vertices, uln.vertices, u, gap_mm=1.5)
    return RealisticScene(
        name=f"wrist-radius-{n_vertices}",
        faces=np.asarray(rad.faces),
        population=pop.shapes,
        n_train=n_train,
        model=model,
        second=(ulna, np.asarray(uln.faces)),
        tissue=_tissue(np.vstack([rad.vertices, ulna])),
        views=views,
        pose=pose,
        cut=cut,
    )


# -- geometry -------------------------------------------------------------------------------------
def _small_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return Rotation.from_rotvec(np.deg2rad(max_deg) * rng.uniform(0, 1) * axis).as_matrix()


def _crop(view: PerspectiveView, points: np.ndarray, margin_px: int = 40) -> PerspectiveView:
    """The view read out in a window (sizes multiples of 8) around the projected points."""
    uv = view.project(points)
    lo = np.floor(uv.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(uv.max(axis=0)).astype(int) + margin_px
    size = -(-(hi - lo + 1) // 8) * 8
    K = view.K.copy()
    K[0, 2] -= lo[0]
    K[1, 2] -= lo[1]
    return dataclasses.replace(view, K=K, image_size=(int(size[0]), int(size[1])))


def perturb_view(
    view: PerspectiveView, centre: np.ndarray, rotation: np.ndarray, shift: np.ndarray
) -> PerspectiveView:
    """``view`` with its pose wrong by a rigid motion about ``centre`` (mm): the returned view
    sees the world point ``X`` where ``view`` sees ``rotation @ (X - centre) + centre + shift``.

    So the relative pose of the views is off by ``rotation`` (its angle) and ``shift`` (mm) at
    the object, whatever the source distance."""
    R = view.R @ rotation
    t = view.R @ (centre - rotation @ centre + shift) + view.t
    return dataclasses.replace(view, R=R, t=t)


# -- rendering and tracing (cached per scene and seed) --------------------------------------------
@dataclass(frozen=True, eq=False)
class _SeedScene:
    """Everything of a seed that no option changes."""

    member: int
    pose: Pose
    truth: np.ndarray
    views: list[PerspectiveView]
    images: list[np.ndarray]
    outlines: list[np.ndarray]
    outline_fraction: list[float]
    overlap: list[float]
    contours: list[list[np.ndarray]]


def _mask_outline(mask: np.ndarray) -> np.ndarray:
    """The outer border (K, 2) of a coverage mask, pixels ``(u, v)``, a closed loop (first point
    not repeated) about one point per pixel: the longest iso-line at level 0.5 between covered
    and uncovered pixel centres (within half a pixel of the exact projected outline)."""
    pad = np.pad(mask.astype(float), 1)
    loops = find_contours(pad, 0.5)
    rc = max(loops, key=len)[:-1] - 1.0
    return np.ascontiguousarray(rc[:, ::-1])


def _render(
    scene: RealisticScene,
    view: PerspectiveView,
    bone: np.ndarray,
    second: np.ndarray,
    tissue: tuple[np.ndarray, np.ndarray],
    rng: np.random.Generator,
    supersample: int,
):
    """Radiograph of bone + second bone + soft tissue; the bone's outline (the border of its
    pixel-exact coverage) and the second bone's coverage mask."""
    rad = render_radiograph(bone, scene.faces, view, mu_per_mm=MU_BONE, supersample=supersample)
    l2, m2 = path_lengths(second, scene.second[1], view, supersample=1)
    l3 = _cylinder_lengths(view, tissue[0], tissue[1], scene.tissue[1])
    img = rad.image * np.exp(-MU_BONE * l2 - MU_SOFT * l3)
    img = ndimage.gaussian_filter(img, 0.8, mode="nearest")
    img = np.clip(img + rng.normal(0.0, 0.01, img.shape), 0.0, 1.0)
    return img, _mask_outline(rad.mask), m2


def _traceable(outline: np.ndarray, closed: bool, cut_uv: np.ndarray) -> np.ndarray:
    """The longest run of outline points (K, 2) farther than 3 px from every projected cut
    vertex, in order along the outline (a closed loop may wrap)."""
    if len(cut_uv) == 0:
        return outline
    ok = cKDTree(cut_uv).query(outline)[0] > 3.0
    if ok.all():
        return outline
    if closed:  # start right after a cut point, so no run wraps around the array's end
        roll = int(np.flatnonzero(~ok)[-1]) + 1
        outline, ok = np.roll(outline, -roll, axis=0), np.roll(ok, -roll)
    edges = np.diff(np.concatenate([[0], ok.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    k = int(np.argmax(ends - starts))
    return outline[starts[k] : ends[k]]


def _trace(
    image: np.ndarray,
    outline: np.ndarray,
    keep: int,
    spacing_px: float,
    noise_px: float,
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """A livewire trace from noisy anchors along ``keep`` points of the open polyline
    ``outline`` (K, 2) from a random start, cleaned: a list of open pieces (usually one)."""
    stretch = outline_stretch(outline, False, min(keep, len(outline)) / len(outline), rng)
    seg = np.linalg.norm(np.diff(stretch, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(round(s[-1] / spacing_px)), 2)
    idx = np.searchsorted(s, np.linspace(0.0, s[-1], n + 1))
    anchors = stretch[np.minimum(idx, len(stretch) - 1)]
    anchors = anchors + rng.normal(0.0, noise_px, anchors.shape)
    h, w = image.shape
    anchors = np.clip(anchors, 0, [w - 1, h - 1])
    raw = livewire(image, anchors, closed=False, bone="dark")
    # then as a contour recipe does (annotation.recipe.run_recipe): resampled at 1 px, cut at
    # the image border and at self-intersections
    pieces, _ = clean_contour(raw, False, spacing_px=1.0, image_size=(w, h))
    return pieces


@functools.lru_cache(maxsize=32)
def _seed_scene(
    scene: RealisticScene,
    seed: int,
    fraction: tuple[float, float],
    spacing_px: float,
    anchor_noise_px: float,
    supersample: int,
) -> _SeedScene:
    rng = np.random.default_rng([int(seed), 16])
    member = scene.n_train + int(seed) % scene.n_held_out
    shape = scene.population[member]
    c = shape.mean(axis=0)
    # turned about the shape's centroid, then shifted
    R = _small_rotation(rng, 10.0) @ scene.pose.R
    pose = Pose(R, scene.pose.apply(c) - R @ c + rng.uniform(-3.0, 3.0, 3))
    truth = pose.apply(shape)
    # the second bone moves with the bone, plus a little of its own (about its own centre)
    s_loc = scene.second[0]
    sc = s_loc.mean(axis=0)
    second = pose.apply((s_loc - sc) @ _small_rotation(rng, 3.0).T + sc + rng.uniform(-2, 2, 3))
    tissue = (pose.apply(scene.tissue[0]), R[:, 2])  # a point on the axis and its direction
    views = [_crop(v, np.vstack([truth, second])) for v in scene.views]
    out: dict[str, list] = {k: [] for k in ("images", "outlines", "frac", "overlap", "contours")}
    for view in views:
        img, outline, mask2 = _render(scene, view, truth, second, tissue, rng, supersample)
        part = _traceable(outline, True, view.project(truth[scene.cut]))
        keep = min(int(round(float(rng.uniform(*fraction)) * len(outline))), len(part))
        uvi = np.clip(np.round(outline).astype(int), 0, [mask2.shape[1] - 1, mask2.shape[0] - 1])
        out["images"].append(img)
        out["outlines"].append(outline)
        out["frac"].append(keep / len(outline))
        out["overlap"].append(float(np.mean(mask2[uvi[:, 1], uvi[:, 0]])))
        out["contours"].append(_trace(img, part, keep, spacing_px, anchor_noise_px, rng))
    return _SeedScene(
        member,
        pose,
        truth,
        views,
        out["images"],
        out["outlines"],
        out["frac"],
        out["overlap"],
        out["contours"],
    )


# -- cases ----------------------------------------------------------------------------------------
def _landmarks(
    scene: RealisticScene,
    geo: _SeedScene,
    rng: np.random.Generator,
    n: int,
    noise_px: float,
    blunder_px: float,
):
    """Per view (ids, names, uv) of the first ``n`` of a random order of the model's
    landmarks, and the blunder record (or None)."""
    names = list(scene.model.landmarks)
    if not 1 <= n <= len(names):
        raise ValueError(f"n_landmarks_per_view: must be in 1..{len(names)}, got {n}")
    order = rng.permutation(len(names))[:n]
    chosen = [names[i] for i in order]
    ids = np.array([scene.model.landmarks[k] for k in chosen], dtype=np.int64)
    noise = [rng.normal(0.0, 1.0, (len(names), 2))[:n] for _ in geo.views]
    b_view, b_lm = int(rng.integers(len(geo.views))), int(rng.integers(n))
    angle = rng.uniform(0.0, 2 * np.pi)
    per_view = []
    for view, e in zip(geo.views, noise, strict=True):
        per_view.append(view.project(geo.truth[ids]) + noise_px * e)
    blunder = None
    if blunder_px > 0:
        offset = blunder_px * np.array([np.cos(angle), np.sin(angle)])
        per_view[b_view][b_lm] += offset
        blunder = {
            "view": geo.views[b_view].name,
            "landmark": chosen[b_lm],
            "offset_px": offset.tolist(),
        }
    return ids, chosen, per_view, blunder


def make_realistic_case(
    seed: int,
    *,
    n_landmarks_per_view: int = 3,
    blunder_px: float = 0.0,
    landmark_noise_px: float = 1.5,
    calibration_error: tuple[float, float] = (0.0, 0.0),
    outline_fraction: tuple[float, float] = (0.6, 0.8),
    anchor_spacing_px: float = 40.0,
    anchor_noise_px: float = 1.5,
    supersample: int = 1,
    scene: RealisticScene | None = None,
) -> RealisticCase:
    """One realistic case (see the module docstring for what is drawn and how).

    Parameters
    ----------
    seed : int
        Seed of everything drawn (truth member and pose, render noise, anchors, landmarks).
    n_landmarks_per_view : int
        Landmarks per view (the same model landmarks in every view).
    blunder_px : float
        Size of the one landmark blunder, pixels (0: none).
    landmark_noise_px : float
        Click noise, pixels (standard deviation per coordinate); also the stated sigma.
    calibration_error : (deg, mm)
        Rotation (degrees) and translation (mm) of the error in the second view's pose.
    outline_fraction : (low, high)
        Range of the fraction of each view's outline traced (open, drawn uniformly).
    anchor_spacing_px, anchor_noise_px : float
        Livewire anchor spacing along the outline and their click noise, pixels.
    supersample : int
        Rays per pixel side of the bone's rendering (odd; 3 smooths the pixel staircase of
        its outline at ~10x the rendering time, 1 relies on the 0.8 px blur).
    scene : RealisticScene
        The scene (e.g. :func:`wrist_scene`); required.
    """
    if scene is None:
        raise ValueError("scene: pass a RealisticScene, e.g. wrist_scene(data_dir)")
    if blunder_px < 0 or landmark_noise_px < 0:
        raise ValueError("blunder_px and landmark_noise_px must be >= 0")
    frac = (float(outline_fraction[0]), float(outline_fraction[1]))
    geo = _seed_scene(
        scene, int(seed), frac, float(anchor_spacing_px), float(anchor_noise_px), int(supersample)
    )
    rng = np.random.default_rng([int(seed), 17])
    ids, names, uv, blunder = _landmarks(
        scene, geo, rng, int(n_landmarks_per_view), landmark_noise_px, blunder_px
    )
    deg, mm = (float(x) for x in calibration_error)
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    given = list(geo.views)
    calib = None
    if deg > 0 or mm > 0:
        rot = Rotation.from_rotvec(np.deg2rad(deg) * axis / np.linalg.norm(axis)).as_matrix()
        shift = mm * direction / np.linalg.norm(direction)
        given[1] = perturb_view(given[1], geo.truth.mean(axis=0), rot, shift)
        calib = {"view": given[1].name, "deg": deg, "mm": mm}
    sigma = landmark_noise_px if landmark_noise_px > 0 else 1.0
    views = [
        ViewObservations(
            name=v.name,
            view=v,
            landmark_names=list(names),
            landmark_ids=ids,
            landmark_uv=p,
            landmark_sigma_px=np.full(len(ids), sigma),
            contours=[Contour(uv=p, closed=False) for p in c],
        )
        for v, p, c in zip(given, uv, geo.contours, strict=True)
    ]
    floor, _ = model_floor(scene.model, geo.truth)
    return RealisticCase(
        seed=int(seed),
        model=scene.model,
        views=views,
        truth_vertices=geo.truth,
        floor_mm=floor,
        true_views=list(geo.views),
        truth_pose=geo.pose,
        member=geo.member,
        blunder=blunder,
        calibration_error=calib,
        radiographs=list(geo.images),
        true_outlines=list(geo.outlines),
        outline_fraction=list(geo.outline_fraction),
        overlap_fraction=list(geo.overlap),
    )
