"""Synthetic sequences: one bone moving along a smooth path, seen in F calibrated frame pairs.

:func:`make_sequence` builds, from a :class:`.realistic.RealisticScene` (e.g.
:func:`.realistic.wrist_scene`), what a biplanar videoradiography annotator would see:

* truth: held-out population member ``n_train + seed % n_held_out`` (out of the model's span),
  the same shape in every frame;
* path: frame ``f`` of ``F`` at ``s = f / (F - 1)``: the scene's nominal pose, rotated about a
  random axis through the bone's centre by ``sweep_deg * (s - 1/2)`` plus a 2 deg wobble
  ``sin(2 pi s)`` about a second random axis, and translated by ``sweep_mm * (s - 1/2)`` along
  a random direction; the second (overlapping) bone follows with a smooth relative motion of
  up to 2 deg / 1.5 mm; the soft tissue moves with the bone;
* views: the scene's calibrations read out in one window around every frame's bones (so the
  calibration is the same in every frame); radiographs rendered as in :mod:`.realistic`
  (bone, second bone, tissue, blur, noise);
* outlines: per frame and view one open livewire-traced stretch of ``outline_fraction`` of the
  bone's outline (as :func:`.realistic.make_realistic_case`);
* landmarks: in the frames ``landmark_frames`` (default every other frame, starting at 0)
  ``n_landmarks_per_view`` model landmarks (the same ones in every view and frame), projected
  plus ``N(0, landmark_noise_px)``; the other frames have none.

Lengths mm, pixels ``(u, v)``, world = the calibrations' frame, model frame = the population's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..annotation import Contour
from ..calibration.views import PerspectiveView
from ..registration import ViewObservations
from ..ssm import ShapeModel
from .realistic import (
    RealisticScene,
    _crop,
    _render,
    _trace,
    _traceable,
    model_floor,
)
from .scenes import outline_stretch

__all__ = ["SequenceCase", "make_sequence", "subsequence", "write_sequence_case"]


@dataclass(frozen=True)
class SequenceCase:
    """One synthetic sequence (see the module docstring).

    Attributes
    ----------
    seed : int
    model : ShapeModel
    frames : list of lists of ViewObservations
        Per frame its views (shared calibrations) with landmarks and traced outlines.
    truth_shape : (N, 3) array
        The true shape in the model frame, mm.
    truth_poses : (F, 4, 4) array
        Every frame's true model -> world transform, mm.
    floor_mm : float
        The model floor of the truth (:func:`.realistic.model_floor`).
    views : list of PerspectiveView
        The (true, shared) calibrations.
    radiographs : list of lists of (H, W) arrays
        Per frame and view, intensities in [0, 1] (bone dark).
    landmark_frames : list of int
    member : int
    """

    seed: int
    model: ShapeModel
    frames: list[list[ViewObservations]]
    truth_shape: np.ndarray
    truth_poses: np.ndarray
    floor_mm: float
    views: list[PerspectiveView]
    radiographs: list[list[np.ndarray]] = field(repr=False)
    landmark_frames: list[int]
    member: int

    def truth_vertices(self, f: int) -> np.ndarray:
        """The true bone in frame ``f`` (world, mm)."""
        T = self.truth_poses[f]
        return self.truth_shape @ T[:3, :3].T + T[:3, 3]


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _path(scene: RealisticScene, shape: np.ndarray, n: int, sweep_deg, sweep_mm, rng):
    """Per frame the bone's pose (R, t), the second bone's relative motion and the tissue."""
    c = shape.mean(axis=0)
    a1, a2, d, b1 = _unit(rng), _unit(rng), _unit(rng), _unit(rng)
    db = rng.uniform(-1.5, 1.5, 3)
    out = []
    for f in range(n):
        s = f / max(n - 1, 1)
        rot = Rotation.from_rotvec(np.deg2rad(sweep_deg * (s - 0.5)) * a1)
        rot = Rotation.from_rotvec(np.deg2rad(2.0 * np.sin(2 * np.pi * s)) * a2) * rot
        R = rot.as_matrix() @ scene.pose.R
        t = scene.pose.apply(c) - R @ c + sweep_mm * (s - 0.5) * d
        rel = Rotation.from_rotvec(np.deg2rad(2.0 * np.sin(np.pi * s)) * b1).as_matrix()
        out.append((R, t, rel, db * np.sin(np.pi * s)))
    return out


def _second(scene: RealisticScene, R, t, rel, shift) -> np.ndarray:
    s_loc = scene.second[0]
    sc = s_loc.mean(axis=0)
    return ((s_loc - sc) @ rel.T + sc + shift) @ R.T + t


def _frame_views(
    scene, views, shape, pose, rng, names, ids, noise_px, has_lm, fraction, spacing, anchor_noise
):
    """One frame: its radiographs and its ViewObservations."""
    R, t, rel, shift = pose
    truth = shape @ R.T + t
    second = _second(scene, R, t, rel, shift)
    tissue = (R @ scene.tissue[0] + t, R[:, 2])
    images, obs = [], []
    for view in views:
        img, outline, _ = _render(scene, view, truth, second, tissue, rng, 1)
        part = _traceable(outline, True, view.project(truth[scene.cut]))
        keep = min(int(round(float(rng.uniform(*fraction)) * len(outline))), len(part))
        if anchor_noise is None:  # the exact outline's stretch, no tracing
            pieces = [outline_stretch(part, False, min(keep, len(part)) / len(part), rng)]
        else:
            pieces = _trace(img, part, keep, spacing, anchor_noise, rng)
        uv = view.project(truth[ids]) + noise_px * rng.normal(size=(len(ids), 2))
        images.append(img)
        obs.append(
            ViewObservations(
                name=view.name,
                view=view,
                landmark_names=list(names) if has_lm else [],
                landmark_ids=ids if has_lm else np.zeros(0, np.int64),
                landmark_uv=uv if has_lm else np.zeros((0, 2)),
                landmark_sigma_px=np.full(len(ids) if has_lm else 0, max(noise_px, 1.0)),
                contours=[Contour(uv=p, closed=False) for p in pieces],
            )
        )
    return images, obs


def make_sequence(
    seed: int,
    *,
    scene: RealisticScene,
    n_frames: int = 10,
    landmark_frames: list[int] | None = None,
    n_landmarks_per_view: int = 3,
    landmark_noise_px: float = 1.5,
    sweep_deg: float = 30.0,
    sweep_mm: float = 8.0,
    outline_fraction: tuple[float, float] = (0.6, 0.8),
    anchor_spacing_px: float = 40.0,
    anchor_noise_px: float | None = 1.5,
) -> SequenceCase:
    """One seeded sequence (module docstring).

    Parameters
    ----------
    seed : int
    scene : RealisticScene
    n_frames : int
        ``F >= 1``.
    landmark_frames : list of int, optional
        Frames with landmarks (default ``0, 2, 4, ...``).
    n_landmarks_per_view : int
    landmark_noise_px : float
        Click noise (px, per coordinate) and the stated sigma (at least 1 px).
    sweep_deg, sweep_mm : float
        Total rotation (deg) and translation (mm) of the bone over the sequence.
    outline_fraction, anchor_spacing_px, anchor_noise_px
        As :func:`.realistic.make_realistic_case`; ``anchor_noise_px=None``: no livewire
        tracing, the outline is an open stretch of the bone's exact projected outline.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames: must be >= 1, got {n_frames}")
    lm_frames = list(range(0, n_frames, 2)) if landmark_frames is None else list(landmark_frames)
    if any(not 0 <= f < n_frames for f in lm_frames):
        raise ValueError(f"landmark_frames: must be in 0..{n_frames - 1}, got {lm_frames}")
    rng = np.random.default_rng([int(seed), 20])
    member = scene.n_train + int(seed) % scene.n_held_out
    shape = scene.population[member]
    poses = _path(scene, shape, n_frames, sweep_deg, sweep_mm, rng)
    every = np.vstack(
        [np.vstack([shape @ R.T + t, _second(scene, R, t, r, s)]) for R, t, r, s in poses]
    )
    views = [_crop(v, every) for v in scene.views]
    names = list(scene.model.landmarks)
    if not 1 <= n_landmarks_per_view <= len(names):
        raise ValueError(f"n_landmarks_per_view: must be in 1..{len(names)}")
    chosen = [names[i] for i in rng.permutation(len(names))[:n_landmarks_per_view]]
    ids = np.array([scene.model.landmarks[k] for k in chosen], dtype=np.int64)
    frames, images = [], []
    for f, pose in enumerate(poses):
        img, obs = _frame_views(
            scene,
            views,
            shape,
            pose,
            rng,
            chosen,
            ids,
            landmark_noise_px,
            f in lm_frames,
            outline_fraction,
            anchor_spacing_px,
            anchor_noise_px,
        )
        frames.append(obs)
        images.append(img)
    T = np.tile(np.eye(4), (n_frames, 1, 1))
    for f, (R, t, _, _) in enumerate(poses):
        T[f, :3, :3], T[f, :3, 3] = R, t
    return SequenceCase(
        seed=int(seed),
        model=scene.model,
        frames=frames,
        truth_shape=shape,
        truth_poses=T,
        floor_mm=model_floor(scene.model, shape)[0],
        views=views,
        radiographs=images,
        landmark_frames=lm_frames,
        member=member,
    )


def subsequence(case: SequenceCase, frames: list[int]) -> SequenceCase:
    """The sequence restricted to ``frames`` (in that order)."""
    return dataclasses.replace(
        case,
        frames=[case.frames[f] for f in frames],
        truth_poses=case.truth_poses[frames],
        radiographs=[case.radiographs[f] for f in frames],
        landmark_frames=[i for i, f in enumerate(frames) if f in case.landmark_frames],
    )


_CASE_HEAD = """format = "biplanar-reg/case@1"
id = "{case_id}"
units = "mm"

[model]
ssm = "model/bone_ssm.npz"
landmarks = "model/landmarks.json"
"""

_CASE_VIEW = """
[[views]]
name = "{name}"
calibration = "calib/{name}.json"
calibration_format = "json"
image = "xray/{first}"
"""

_CASE_TAIL = """
[registration]
poses = "known"
silhouettes = true
"""


def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 image
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _frame_annotations(frame: list[ViewObservations]):
    from ..annotation import Annotations, Landmark, ViewAnnotations

    ann = Annotations()
    for v in frame:
        lms = {
            n: Landmark(uv=uv, sigma_px=float(s))
            for n, uv, s in zip(v.landmark_names, v.landmark_uv, v.landmark_sigma_px, strict=True)
        }
        ann.views[v.name] = ViewAnnotations(landmarks=lms, contours=list(v.contours))
    return ann


def write_sequence_case(folder, case: SequenceCase, case_id: str | None = None):
    """Write ``case`` as a multi-frame case folder (``[[frames]]``, docs/cases.md "Frames").

    Files: ``model/bone_ssm.npz`` and ``model/landmarks.json``; ``calib/<view>.json`` (the
    shared calibrations, native JSON); ``xray/f<i>_<view>.png`` (8-bit radiographs);
    ``frames/f<i>.json`` (each frame's annotations); ``gt/truth.json`` (the true shape in the
    model frame and every frame's true model -> world pose, mm); ``gt/f<i>.ply`` (the true bone
    in frame ``i``, world, mm, the model's faces: ``[[frames]] ground_truth``). Returns the
    folder.
    """
    from pathlib import Path

    from ..annotation import save_annotations
    from ..calibration import save_calibration
    from ..io import atomic_write_bytes, atomic_write_json, write_mesh

    root = Path(folder)
    for sub in ("model", "calib", "xray", "frames", "gt"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    case.model.save(root / "model" / "bone_ssm.npz")
    atomic_write_json(root / "model" / "landmarks.json", dict(case.model.landmarks))
    text = _CASE_HEAD.format(case_id=case_id or root.name)
    for v in case.views:
        save_calibration(v, root / "calib" / f"{v.name}.json", "json")
        text += _CASE_VIEW.format(name=v.name, first=f"f0_{v.name}.png")
    for f, (frame, images) in enumerate(zip(case.frames, case.radiographs, strict=True)):
        for v, img in zip(frame, images, strict=True):
            atomic_write_bytes(root / "xray" / f"f{f}_{v.name}.png", _png(img))
        save_annotations(_frame_annotations(frame), root / "frames" / f"f{f}.json")
        write_mesh(root / "gt" / f"f{f}.ply", case.truth_vertices(f), case.model.faces)
        text += f'\n[[frames]]\nname = "f{f}"\nannotations = "frames/f{f}.json"\n'
        text += f'ground_truth = "gt/f{f}.ply"\n'
        text += "images = {" + ", ".join(f'{v.name} = "xray/f{f}_{v.name}.png"' for v in frame)
        text += "}\n"
    text += _CASE_TAIL
    atomic_write_bytes(root / "case.toml", text.encode())
    atomic_write_json(
        root / "gt" / "truth.json",
        {
            "frame": "truth in frame f = shape @ poses[f][:3, :3].T + poses[f][:3, 3] (world, mm)",
            "shape": case.truth_shape.tolist(),
            "poses": case.truth_poses.tolist(),
            "floor_mm": case.floor_mm,
            "landmark_frames": case.landmark_frames,
            "seed": case.seed,
        },
    )
    return root
