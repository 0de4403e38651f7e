"""Write a complete synthetic case folder with a known ground truth (demo, tests, benchmarks).

The scene (all seeded, deterministic):

* model: :func:`biplanar_reg.synthetic.synthetic_bone_model` (a 60 mm bone-like capsule,
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
  exact silhouette outline (random start), resampled at 2 px, plus ``N(0, contour_noise_px)``.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..annotation import (
    Annotations,
    Contour,
    Landmark,
    ViewAnnotations,
    render_radiograph,
    save_annotations,
)
from ..annotation._fileio import atomic_write_bytes, atomic_write_json
from ..annotation.clean import resample_polyline
from ..calibration import save_calibration
from ..io import write_mesh
from ..ssm import ShapeModel
from ..synthetic import look_at_view, random_pose, synthetic_bone_model

__all__ = ["write_synthetic_case", "synthetic_landmarks"]

CASE_TOML = """format = "biplanar-reg/case@1"
id = "{case_id}"
units = "mm"

[model]
ssm = "model/bone_ssm.npz"
landmarks = "model/landmarks.json"

[[views]]
name = "cam1"
calibration = "calib/cam1.txt"
calibration_format = "mayacam2"
image = "xray/cam1.png"

[[views]]
name = "cam2"
calibration = "calib/cam2.json"
image = "xray/cam2.png"

[annotations]
file = "annotations.json"

[registration]
poses = "known"
silhouettes = {silhouettes}

[ground_truth]
mesh = "gt/bone.ply"
"""


def synthetic_landmarks(model: ShapeModel) -> dict[str, int]:
    """Eight well-spread landmark vertices: the tips and the extremes across the shaft at two
    heights (mean shape, object frame)."""
    V = model.mean
    z = V[:, 2]
    out = {"distal_tip": int(np.argmax(z)), "proximal_tip": int(np.argmin(z))}
    for level, zc in (("distal", np.percentile(z, 80)), ("proximal", np.percentile(z, 25))):
        band = np.flatnonzero(np.abs(z - zc) < 0.06 * np.ptp(z))
        for axis, label in ((0, "x"), (1, "y")):
            out[f"{level}_{label}_max"] = int(band[np.argmax(V[band, axis])])
            out[f"{level}_{label}_min"] = int(band[np.argmin(V[band, axis])])
    picked = list(out.items())[:8]
    return dict(picked)


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
) -> Path:
    """Write a synthetic case into ``folder`` (created); returns the folder.

    Parameters
    ----------
    folder : path
        Output case folder.
    seed : int
        Seed of the truth (weights, pose) and of the noise; the model itself uses seed 0.
    n_modes : int
        Modes of the model.
    image_size : (W, H)
        Radiograph size, pixels.
    landmark_noise_px, contour_noise_px : float
        Standard deviation of the pixel noise added to the annotations.
    case_id : str, optional
        ``id`` in case.toml (default: the folder's name).
    silhouettes : bool
        ``[registration] silhouettes`` in case.toml.
    """
    root = Path(folder)
    for sub in ("model", "calib", "xray", "gt"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    model = synthetic_bone_model(n_modes, seed=0)
    landmarks = synthetic_landmarks(model)
    model = ShapeModel(
        model.mean, model.modes, faces=model.faces, variances=model.variances, landmarks=landmarks
    )
    model.save(root / "model" / "bone_ssm.npz")
    atomic_write_json(root / "model" / "landmarks.json", landmarks)

    w = rng.normal(size=n_modes)
    R, t = random_pose(rng, max_offset=5.0)
    truth = model.instance(w) @ R.T + t
    write_mesh(root / "gt" / "bone.ply", truth, model.faces)

    a = np.deg2rad(75.0) / 2
    views = [
        look_at_view(
            900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]),
            sdd=1200.0,
            pixel=0.3 * 512 / min(image_size),  # the bone covers the same image fraction
            image_size=image_size,
            name=name,
        )
        for sx, name in ((-1.0, "cam1"), (1.0, "cam2"))
    ]
    save_calibration(views[0], root / "calib" / "cam1.txt", "mayacam2")
    save_calibration(views[1], root / "calib" / "cam2.json", "json")

    ann = Annotations()
    for view in views:
        rad = render_radiograph(
            truth, model.faces, view, blur_sigma_px=0.7, noise_sigma=0.01, seed=seed
        )
        png = np.round(np.clip(rad.image, 0, 1) * 255).astype(np.uint8)
        ok, buf = cv2.imencode(".png", png)
        if not ok:  # pragma: no cover - OpenCV always encodes a uint8 image
            raise RuntimeError("PNG encoding failed")
        atomic_write_bytes(root / "xray" / f"{view.name}.png", buf.tobytes())
        ids = np.array(list(landmarks.values()))
        uv = view.project(truth[ids]) + rng.normal(scale=landmark_noise_px, size=(len(ids), 2))
        lms = {n: Landmark(p, 1.0) for n, p in zip(landmarks, uv, strict=True)}
        outline = resample_polyline(rad.outlines[0], 2.0, closed=rad.outline_closed[0])
        k = len(outline)
        start = int(rng.integers(k))
        piece = np.roll(outline, -start, axis=0)[: int(0.8 * k)]
        piece = piece + rng.normal(scale=contour_noise_px, size=piece.shape)
        ann.views[view.name] = ViewAnnotations(lms, [Contour(piece, False)])
    save_annotations(ann, root / "annotations.json")
    text = CASE_TOML.format(
        case_id=case_id or root.name, silhouettes="true" if silhouettes else "false"
    )
    atomic_write_bytes(root / "case.toml", text.encode("utf-8"))
    return root
