"""Write a complete synthetic case folder with a known ground truth.

:func:`write_synthetic_case` writes a case folder in the case format (``docs/cases.md``) with
its ground truth, through the public writers of the calibration, annotation, io and ssm
packages; the bundled ``sample_cases/synthetic_*`` cases, the tests and the benchmarks use it,
and so can anyone testing a pipeline on data with a known answer.

The default scene (all seeded, deterministic):

* model: :func:`biplanar_reg.simulate.synthetic_bone_model` (a 60 mm bone-like capsule,
  482 vertices, ``n_modes`` non-affine modes), saved as ``model/bone_ssm.npz``; eight landmarks
  at extreme vertices (``model/landmarks.json``);
* truth: weights ``N(0, 1)``, a uniformly random rotation and a translation within 5 mm of the
  origin; ``gt/bone.ply`` is the posed instance (model topology);
* views: two perspective views 75 degrees apart (source-object 900 mm, source-detector
  1200 mm; 512 x 512 with 0.3 mm pixels, or the same field of view at other sizes),
  ``calib/cam1.txt`` (MayaCam 2.0) and ``calib/cam2.json``
  (native JSON);
* radiographs ``xray/cam{1,2}.png``: :func:`biplanar_reg.annotation.render_radiograph` of the
  truth (``mu`` 0.05/mm, 0.7 px blur, Gaussian noise 0.01, 8-bit);
* annotations: every landmark in both views, projected from the truth plus pixel noise
  ``N(0, landmark_noise_px)`` (``sigma_px`` = 1); per view one open contour covering 80 % of the
  exact silhouette's longest outline (a contiguous stretch from a random start; an open outline
  is never wrapped across its ends), resampled at 2 px, plus ``N(0, contour_noise_px)``.

Options (all default to the scene above) let other sample cases reuse the same writer: another
``model`` with its own landmarks, a ``truth_shape`` that need not lie in the model's span (e.g.
a harmonic deformation of the template), a fixed ``pose``, other ``views`` (e.g. the real
wrist calibrations cropped to the bone), ``poses = "unknown"`` in case.toml (the ground truth
is then compared up to pose, ``[ground_truth] up_to_pose = true``), and one landmark blunder
(``blunder_px``: one landmark of the first view moved by that many pixels in a seeded random
direction). ``gt/truth.json`` records the truth (pose, shape source, noise, blunder).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from ..annotation import (
    Annotations,
    Contour,
    Landmark,
    Radiograph,
    ViewAnnotations,
    render_radiograph,
    resample_polyline,
    save_annotations,
)
from ..calibration import save_calibration
from ..calibration.views import View
from ..io import write_mesh
from ..io.atomic import atomic_write_bytes, atomic_write_json
from ..pose import Pose
from ..ssm import ShapeModel
from .scenes import look_at_view, outline_stretch, random_pose, synthetic_bone_model

__all__ = ["write_synthetic_case", "synthetic_landmarks"]

CASE_TOML = """format = "biplanar-reg/case@1"
id = "{case_id}"
units = "mm"

[model]
ssm = "model/bone_ssm.npz"
landmarks = "model/landmarks.json"
{views}
[annotations]
file = "annotations.json"

[registration]
poses = "{poses}"
silhouettes = {silhouettes}

[ground_truth]
mesh = "gt/bone.ply"
{up_to_pose}"""

VIEW_TOML = """
[[views]]
name = "{name}"
calibration = "calib/{calibration}"
{fmt}image = "xray/{name}.png"
"""


def _calibration_file(index: int, name: str) -> tuple[str, str]:
    """File name and format of a view's calibration: the first view MayaCam 2.0 (the format of
    the real wrist data), the others native JSON, so that both readers are exercised."""
    return (f"{name}.txt", "mayacam2") if index == 0 else (f"{name}.json", "json")


#: Anatomical names of :func:`synthetic_landmarks`' vertices on a forearm bone in the frame of
#: the shipped wrist CT (distal = low z, +x dorsal, +y ulnar; docs/sample_cases.md defines each
#: and says in which views it is an outline point). The distal tip is named per bone.
FOREARM_NAMES = {
    "proximal_tip": "proximal_end",
    "distal_x_max": "distal_dorsal_margin",
    "distal_x_min": "distal_volar_margin",
    "distal_y_max": "distal_ulnar_margin",
    "distal_y_min": "distal_radial_margin",
    "proximal_x_max": "shaft_dorsal_margin",
    "proximal_x_min": "shaft_volar_margin",
    "proximal_y_max": "shaft_ulnar_margin",
    "proximal_y_min": "shaft_radial_margin",
}
#: The name of the distal tip per ``bone`` of :func:`synthetic_landmarks`.
DISTAL_TIPS = {"radius": "radial_styloid_tip", "ulna": "ulnar_styloid_tip", "bone": "distal_tip"}


def synthetic_landmarks(
    model: ShapeModel, distal_sign: float = 1.0, *, bone: str | None = None
) -> dict[str, int]:
    """Eight well-spread landmark vertices: the tips and the extremes across the shaft at two
    heights (mean shape, object frame). The long axis is z; ``distal_sign = -1`` when the
    distal end is at low z (e.g. the radius CT).

    ``bone`` None names them by the axes (``distal_tip``, ``distal_x_max``, ...); ``"radius"``,
    ``"ulna"`` or ``"bone"`` (a synthetic bone) by anatomy (:data:`FOREARM_NAMES`, +x dorsal,
    +y ulnar; the distal tip :data:`DISTAL_TIPS`), the same vertices in the same order."""
    if bone is not None and bone not in DISTAL_TIPS:
        raise ValueError(f"bone: expected one of {sorted(DISTAL_TIPS)} or None, got {bone!r}")
    V = model.mean
    z = distal_sign * V[:, 2]
    out = {"distal_tip": int(np.argmax(z)), "proximal_tip": int(np.argmin(z))}
    for level, zc in (("distal", np.percentile(z, 80)), ("proximal", np.percentile(z, 25))):
        band = np.flatnonzero(np.abs(z - zc) < 0.06 * np.ptp(z))
        for axis, label in ((0, "x"), (1, "y")):
            out[f"{level}_{label}_max"] = int(band[np.argmax(V[band, axis])])
            out[f"{level}_{label}_min"] = int(band[np.argmin(V[band, axis])])
    picked = list(out.items())[:8]
    if bone is None:
        return dict(picked)
    names = {**FOREARM_NAMES, "distal_tip": DISTAL_TIPS[bone]}
    return {names[k]: i for k, i in picked}


def write_synthetic_case(
    folder: str | os.PathLike,
    seed: int = 0,
    *,
    n_modes: int = 6,
    image_size: tuple[int, int] = (512, 512),
    landmark_noise_px: float = 0.5,
    contour_noise_px: float = 0.3,
    case_id: str | None = None,
    silhouettes: bool = True,
    model: ShapeModel | None = None,
    truth_shape: np.ndarray | None = None,
    pose: Pose | None = None,
    views: Sequence[View] | None = None,
    poses: str = "known",
    blunder_px: float = 0.0,
) -> Path:
    """Write a synthetic case into ``folder`` (created); returns the folder.

    Parameters
    ----------
    folder : path
        Output case folder.
    seed : int
        Seed of the truth (weights, pose) and of the noise; the model itself uses seed 0.
    n_modes : int
        Modes of the default model (ignored when ``model`` is given).
    image_size : (W, H)
        Radiograph size of the default views, pixels (ignored when ``views`` are given).
    landmark_noise_px, contour_noise_px : float
        Standard deviation of the pixel noise added to the annotations.
    case_id : str, optional
        ``id`` in case.toml (default: the folder's name).
    silhouettes : bool
        ``[registration] silhouettes`` in case.toml.
    model : ShapeModel, optional
        The case's model (mm); its ``landmarks`` are used when it has them, else
        :func:`synthetic_landmarks`. Default: the synthetic capsule bone.
    truth_shape : (N, 3) array, optional
        The true shape in the model's frame, mm, with the model's vertex order (it need not lie
        in the model's span). Default: ``model.instance(w)``, ``w ~ N(0, 1)``.
    pose : Pose, optional
        World pose of the truth (model frame -> world, ``X = R @ x + t``, mm). Default: a
        uniformly random rotation and a translation within 5 mm of the origin.
    views : sequence of View, optional
        The views (names, image sizes and calibrations). Default: two perspective views
        75 degrees apart around the origin.
    poses : {"known", "unknown"}
        ``[registration] poses``; with "unknown" the ground truth is compared up to pose.
    blunder_px : float
        When > 0, one landmark of the first view (seeded choice) is moved by this many pixels.
    """
    if poses not in ("known", "unknown"):
        raise ValueError(f"poses: expected 'known' or 'unknown', got {poses!r}")
    if not np.isfinite(blunder_px) or blunder_px < 0:
        raise ValueError(f"blunder_px: must be >= 0, got {blunder_px!r}")
    root = Path(folder)
    for sub in ("model", "calib", "xray", "gt"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    model = _case_model(model, n_modes)
    landmarks = dict(model.landmarks)
    model.save(root / "model" / "bone_ssm.npz")
    atomic_write_json(root / "model" / "landmarks.json", landmarks)

    # the draws keep their order whatever the options, so the default case never changes
    w = rng.normal(size=model.n_modes)
    drawn = random_pose(rng, max_offset=5.0)
    pose = drawn if pose is None else pose
    shape = model.instance(w) if truth_shape is None else np.asarray(truth_shape, float)
    if shape.shape != model.mean.shape:
        raise ValueError(f"truth_shape: expected shape {model.mean.shape}, got {shape.shape}")
    truth = pose.apply(shape)
    write_mesh(root / "gt" / "bone.ply", truth, model.faces)

    views = _default_views(image_size) if views is None else list(views)
    view_toml = _write_calibrations(root, views)
    blunder = _draw_blunder(seed, views[0].name, list(landmarks), blunder_px)
    ann = Annotations()
    for view in views:
        rad = _write_radiograph(root, truth, model.faces, view, seed)
        ann.views[view.name] = _view_annotations(
            view, truth, landmarks, rad, rng, landmark_noise_px, contour_noise_px, blunder
        )
    save_annotations(ann, root / "annotations.json")
    atomic_write_json(
        root / "gt" / "truth.json",
        {
            "frame": "world frame of the calibrations, mm; truth = shape @ R.T + t",
            "R": pose.R.tolist(),
            "t": pose.t.tolist(),
            "shape": "model instance" if truth_shape is None else "given truth_shape",
            "weights": w.tolist() if truth_shape is None else None,
            "landmark_noise_px": landmark_noise_px,
            "contour_noise_px": contour_noise_px,
            "contour": "one open piece of 80 % of the exact outline per view, 2 px spacing",
            "blunder": None
            if blunder is None
            else {**blunder, "offset_px": np.asarray(blunder["offset_px"]).tolist()},
        },
    )
    text = CASE_TOML.format(
        case_id=case_id or root.name,
        views=view_toml,
        poses=poses,
        silhouettes="true" if silhouettes else "false",
        up_to_pose="up_to_pose = true\n" if poses == "unknown" else "",
    )
    atomic_write_bytes(root / "case.toml", text.encode("utf-8"))
    return root


def _case_model(model: ShapeModel | None, n_modes: int) -> ShapeModel:
    """The case's model with its landmarks: the capsule bone (seed 0) by default; a given
    model keeps its own landmarks, else gets :func:`synthetic_landmarks`."""
    if model is None:
        model = synthetic_bone_model(n_modes, seed=0)
        landmarks = synthetic_landmarks(model)
    else:
        landmarks = dict(model.landmarks) if model.landmarks else synthetic_landmarks(model)
    return ShapeModel(
        model.mean,
        model.modes,
        faces=model.faces,
        variances=model.variances,
        landmarks=landmarks,
        truncation_modes=model.truncation_modes,
    )


def _default_views(image_size: tuple[int, int]) -> list[View]:
    """Two perspective views 75 degrees apart around the origin (source-object 900 mm,
    source-detector 1200 mm), ``image_size`` pixels covering the field of view of 512 px at
    0.3 mm (so the bone covers the same image fraction at every size)."""
    a = np.deg2rad(75.0) / 2
    return [
        look_at_view(
            900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]),
            sdd=1200.0,
            pixel=0.3 * 512 / min(image_size),
            image_size=image_size,
            name=name,
        )
        for sx, name in ((-1.0, "cam1"), (1.0, "cam2"))
    ]


def _write_calibrations(root: Path, views: Sequence[View]) -> str:
    """Write each view's calibration under ``calib/``; returns the ``[[views]]`` tables of
    case.toml."""
    view_toml = []
    for i, view in enumerate(views):
        fname, fmt = _calibration_file(i, view.name)
        save_calibration(view, root / "calib" / fname, fmt)
        view_toml.append(
            VIEW_TOML.format(
                name=view.name,
                calibration=fname,
                fmt='calibration_format = "mayacam2"\n' if fmt == "mayacam2" else "",
            )
        )
    return "".join(view_toml)


def _draw_blunder(
    seed: int, view_name: str, landmark_names: list[str], blunder_px: float
) -> dict | None:
    """The blunder (view, landmark, ``offset_px`` (2,) pixels) or None when ``blunder_px`` is
    0. Drawn from its own stream ``default_rng([seed, 1])``: the case's other draws stay put."""
    if blunder_px <= 0:
        return None
    brng = np.random.default_rng([seed, 1])
    k = int(brng.integers(len(landmark_names)))
    ang = float(brng.uniform(0.0, 2.0 * np.pi))
    offset = blunder_px * np.array([np.cos(ang), np.sin(ang)])
    return {"view": view_name, "landmark": landmark_names[k], "offset_px": offset}


def _write_radiograph(
    root: Path, truth: np.ndarray, faces: np.ndarray, view: View, seed: int
) -> Radiograph:
    """Render the truth (world frame, mm) in ``view`` (0.7 px blur, noise 0.01, image noise
    seeded with ``seed``) and write it as ``xray/<view>.png`` (8-bit)."""
    rad = render_radiograph(truth, faces, view, blur_sigma_px=0.7, noise_sigma=0.01, seed=seed)
    png = np.round(np.clip(rad.image, 0, 1) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", png)
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 image
        raise RuntimeError("PNG encoding failed")
    atomic_write_bytes(root / "xray" / f"{view.name}.png", buf.tobytes())
    return rad


def _view_annotations(
    view: View,
    truth: np.ndarray,
    landmarks: dict[str, int],
    rad: Radiograph,
    rng: np.random.Generator,
    landmark_noise_px: float,
    contour_noise_px: float,
    blunder: dict | None,
) -> ViewAnnotations:
    """One view's annotations: every landmark projected from the truth (mm) plus
    ``N(0, landmark_noise_px)`` (sigma 1 px), the blunder if it is in this view, and one open
    piece of 80 % of the exact outline (2 px spacing) plus ``N(0, contour_noise_px)``.

    Draws from ``rng``, in this order: the landmark noise, the piece's start, the contour
    noise."""
    ids = np.array(list(landmarks.values()))
    uv = view.project(truth[ids]) + rng.normal(scale=landmark_noise_px, size=(len(ids), 2))
    if blunder is not None and view.name == blunder["view"]:
        uv[list(landmarks).index(blunder["landmark"])] += blunder["offset_px"]
    lms = {n: Landmark(p, 1.0) for n, p in zip(landmarks, uv, strict=True)}
    outline = resample_polyline(rad.outlines[0], 2.0, closed=rad.outline_closed[0])
    piece = outline_stretch(outline, rad.outline_closed[0], 0.8, rng)
    piece = piece + rng.normal(scale=contour_noise_px, size=piece.shape)
    return ViewAnnotations(lms, [Contour(piece, False)])
