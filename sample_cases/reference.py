"""Building blocks of the bundled sample cases (this folder, ``sample_cases/``): the
distal-radius template from the shipped CT, its harmonic-population shape model, cropped wrist
views, and the synthetic reference cases with full ground truth.

Not part of the installed package: it reads the data of this source tree
(``wrist_radius/data/``) and is imported by the generator scripts beside it
(``make_reference_cases.py``, ``wrist_radius/make_case.py``), which run from a clone.

Everything is deterministic (fixed seeds). Lengths are mm; the template lives in the CT's frame
(voxel grid scaled by the voxel size, origin at the centre of voxel (0, 0, 0); +z runs from
the distal articular surface towards the shaft).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from biplanar_reg.calibration import load_calibration
from biplanar_reg.calibration.views import PerspectiveView
from biplanar_reg.io import read_volume
from biplanar_reg.pose import Pose
from biplanar_reg.simulate import synthetic_landmarks, write_synthetic_case
from biplanar_reg.ssm import ShapeModel, bone_surface, build_ssm, synthesise_population

__all__ = [
    "WRIST_DATA",
    "CT_VOXEL_MM",
    "radius_template",
    "radius_model",
    "wrist_views",
    "crop_view",
    "crop_to_points",
    "WRIST_RADIUS_POSE",
    "write_reference_cases",
]

#: The shipped real data (beside this file in the source tree).
WRIST_DATA = Path(__file__).resolve().parent / "wrist_radius" / "data"
#: Voxel size of ``radius_ct.tif`` (column, row, slice), mm.
CT_VOXEL_MM = (0.39625, 0.39625, 0.625)
#: A realistic pose of the radius in the wrist calibrations' world frame (template frame ->
#: world, ``X = R @ x + t``, mm): the rough pose of the real radius in the shipped radiographs
#: (``sample_cases/wrist_radius/annotation/rough_pose.json``).
WRIST_RADIUS_POSE = Pose(
    np.array(
        [
            [-0.970953, 0.239242, -0.003638],
            [-0.011965, -0.033362, 0.999372],
            [0.23897, 0.970387, 0.035255],
        ]
    ),
    np.array([118.522, 117.724, 68.557]),
)


def radius_template(target_vertices: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """The distal radius surface from ``radius_ct.tif`` (project CT-to-mesh, Otsu threshold).

    Returns
    -------
    vertices : (N, 3) array, mm, CT frame
    faces : (F, 3) int array
    """
    vol = read_volume(WRIST_DATA / "radius_ct.tif", voxel_size=CT_VOXEL_MM)
    surf = bone_surface(vol, target_vertices=target_vertices)
    return surf.vertices, surf.faces


def radius_model(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    size: int = 9,
    seed: int = 0,
    landmarks: dict[str, int] | None = None,
) -> ShapeModel:
    """Shape model of a harmonic-deformation population of the template (all families,
    ``size`` shapes, ``seed``), rigid Procrustes, 98 % of the variance; mean in the template's
    frame."""
    pop = synthesise_population(vertices, size, seed=seed)
    return build_ssm(pop.shapes, faces=faces, variance=0.98, landmarks=landmarks)


def wrist_views() -> list[PerspectiveView]:
    """The two real wrist calibrations (MayaCam 2.0), named ``cam01`` and ``cam02``."""
    return [
        load_calibration(WRIST_DATA / f"{n}_calibration_mayacam2.txt", name=n)
        for n in ("cam01", "cam02")
    ]


def crop_view(view: PerspectiveView, u0: int, v0: int, width: int, height: int) -> PerspectiveView:
    """The same detector read out in the window of ``width`` x ``height`` pixels whose top-left
    pixel is ``(u0, v0)`` of the full image: the principal point moves by ``(-u0, -v0)``."""
    K = view.K.copy()
    K[0, 2] -= u0
    K[1, 2] -= v0
    return dataclasses.replace(view, K=K, image_size=(int(width), int(height)))


def crop_to_points(
    view: PerspectiveView, points: np.ndarray, margin_px: int = 40
) -> PerspectiveView:
    """:func:`crop_view` around the projection of ``points`` (mm) plus a margin, sizes rounded
    up to multiples of 8 pixels."""
    uv = view.project(points)
    lo = np.floor(uv.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(uv.max(axis=0)).astype(int) + margin_px
    size = -(-(hi - lo + 1) // 8) * 8
    return crop_view(view, int(lo[0]), int(lo[1]), int(size[0]), int(size[1]))


#: The synthetic reference cases: folder -> (seed, poses, blunder_px).
REFERENCE_CASES = {
    "synthetic_radius_known": (1, "known", 0.0),
    "synthetic_radius_unknown": (2, "unknown", 0.0),
    "synthetic_radius_blunder": (3, "known", 30.0),
}


def write_reference_cases(root: str | os.PathLike, target_vertices: int = 1000) -> list[Path]:
    """Write the synthetic reference cases under ``root`` (see docs/sample_cases.md).

    The model is :func:`radius_model` of a ``target_vertices`` radius template with the
    eight extreme-vertex landmarks of
    :func:`biplanar_reg.simulate.synthetic_landmarks` (distal = low CT z, anatomical names);
    the
    truth of case ``seed`` is one harmonic deformation of the template drawn with population
    seed ``100 + seed`` (not a member of the model's population, so it is not exactly in the
    model's span), placed near :data:`WRIST_RADIUS_POSE` (rotation perturbed by up to 10
    degrees, translation by up to 3 mm), viewed by the wrist calibrations cropped to the bone.
    """
    verts, faces = radius_template(target_vertices)
    model = radius_model(verts, faces)
    model = ShapeModel(
        model.mean,
        model.modes,
        faces=model.faces,
        variances=model.variances,
        landmarks=synthetic_landmarks(model, distal_sign=-1.0, bone="radius"),
    )
    out = []
    for name, (seed, poses, blunder) in REFERENCE_CASES.items():
        rng = np.random.default_rng(1000 + seed)
        truth = synthesise_population(verts, 1, seed=100 + seed).shapes[0]
        truth = truth - verts.mean(axis=0) + model.mean.mean(axis=0)  # same centre as the model
        dR = Rotation.from_rotvec(np.deg2rad(10.0) * rng.uniform(-1, 1, 3) / np.sqrt(3)).as_matrix()
        R = dR @ WRIST_RADIUS_POSE.R
        c = model.mean.mean(axis=0)  # turned about the model's centroid, then shifted
        pose = Pose(R, WRIST_RADIUS_POSE.apply(c) - R @ c + rng.uniform(-3.0, 3.0, 3))
        views = [crop_to_points(v, pose.apply(truth)) for v in wrist_views()]
        out.append(
            write_synthetic_case(
                Path(root) / name,
                seed,
                model=model,
                truth_shape=truth,
                pose=pose,
                views=views,
                poses=poses,
                blunder_px=blunder,
                case_id=name,
            )
        )
    return out
