"""Models and case folders of the real wrist benchmark (radius and ulna on two real radiographs).

    python benchmarks/real_wrist/build.py [--out DIR]

Reads the shipped wrist data (``sample_cases/wrist_radius/data``: two real radiographs, their
MayaCam 2.0 calibrations, the same subject's CT radius and ulna) and the annotations made
through the workbench (``annotations/<bone>_<annotator>.json``, see ``annotate.py``), and writes
into ``models/`` (committed; rerunning reproduces them):

* ``<bone>_template.ply``: the bone from its CT volume (``biplanar_reg.ssm.bone_surface``, Otsu
  threshold; radius 2,000 vertices, ulna 1,500), CT frame, mm: the ground truth, up to pose;
* ``<bone>_deformed.ply``: the same mesh moved by one smooth harmonic cage deformation
  (``synthesise_population`` with seed 101, its strength scaled so that the vertex RMS from
  the CT mesh after rigid alignment is 2.5 mm): a template that is not the patient;
* ``<bone>_ct_ssm.npz`` / ``<bone>_deformed_ssm.npz``: the shape model of a 9-member harmonic
  population of either template (seed 0, all families, 98 % of the variance), with the
  landmarks of ``LANDMARKS`` (``<bone>_landmarks.json``).

With ``--out DIR`` it also writes one case folder per bone, template and annotator
(``DIR/<bone>_<template>_<annotator>/``) whose ground truth is the CT mesh up to pose.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

from biplanar_reg.io import atomic_write_json, read_json, read_volume, write_mesh
from biplanar_reg.pose import Pose
from biplanar_reg.ssm import ShapeModel, bone_surface, build_ssm, synthesise_population

HERE = Path(__file__).resolve().parent
DATA = HERE.parents[1] / "sample_cases" / "wrist_radius" / "data"
MODELS = HERE / "models"
ANNOTATIONS = HERE / "annotations"
CT_VOXEL_MM = (0.39625, 0.39625, 0.625)
BONES = {"radius": 2000, "ulna": 1500}
TEMPLATES = ("ct", "deformed")
DEFORMED_RMS_MM = 2.5
DEFORM_SEED = 101


def _kabsch_rms(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS (mm) of ``a`` after its best rigid alignment onto ``b``."""
    d = Pose.fit_rigid(a, b).apply(a) - b
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def radius_landmarks(v: np.ndarray) -> dict[str, int]:
    """Radius (CT frame: +z proximal, distal tip at low z; the ulnar side at high y).

    * ``radial_styloid_tip``: the tip of the radial styloid, the bone's most distal point
      (lowest z): the distal tip of the outline in every view;
    * ``ulnar_corner``: the distal corner of the ulnar border (the sigmoid notch's distal rim):
      the most distal vertex within 2.5 mm of the most ulnar one; an outline corner in a
      postero-anterior view, hidden by the ulna's head in an oblique one.
    """
    x, y, z = v.T
    ulnar = np.flatnonzero(y > y.max() - 2.5)
    return {
        "radial_styloid_tip": int(np.argmin(z)),
        "ulnar_corner": int(ulnar[np.argmin(z[ulnar])]),
    }


def ulna_landmarks(v: np.ndarray) -> dict[str, int]:
    """Ulna (CT frame: +z proximal, the styloid's tip at low z).

    * ``ulnar_styloid_tip``: the tip of the ulnar styloid, the bone's most distal point;
    * ``head_radial_corner``: the corner where the head's distal surface meets its radial
      border (the seat of the distal radio-ulnar joint): among the vertices within 6 mm of the
      head's distal surface, the one farthest from the styloid's tip across the long axis.
    """
    z = v[:, 2]
    tip = int(np.argmin(z))
    head = np.flatnonzero(z < z.min() + 8.0)
    lateral = np.linalg.norm(v[head, :2] - v[tip, :2], axis=1)
    return {"ulnar_styloid_tip": tip, "head_radial_corner": int(head[np.argmax(lateral)])}


LANDMARKS = {"radius": radius_landmarks, "ulna": ulna_landmarks}


def deformed(vertices: np.ndarray) -> np.ndarray:
    """``vertices`` moved by one smooth cage deformation of vertex RMS ``DEFORMED_RMS_MM``."""
    lo, hi = 0.0, 4.0
    for _ in range(40):  # bisection on the strength (the RMS grows with it)
        s = 0.5 * (lo + hi)
        shape = synthesise_population(vertices, 1, seed=DEFORM_SEED, strength=s).shapes[0]
        if _kabsch_rms(shape, vertices) < DEFORMED_RMS_MM:
            lo = s
        else:
            hi = s
    return synthesise_population(vertices, 1, seed=DEFORM_SEED, strength=lo).shapes[0]


def build_models() -> None:
    MODELS.mkdir(exist_ok=True)
    for bone, n in BONES.items():
        surf = bone_surface(
            read_volume(DATA / f"{bone}_ct.tif", voxel_size=CT_VOXEL_MM), target_vertices=n
        )
        v, f = surf.vertices, np.asarray(surf.faces)
        marks = LANDMARKS[bone](v)
        write_mesh(MODELS / f"{bone}_template.ply", v, f)
        atomic_write_json(MODELS / f"{bone}_landmarks.json", marks)
        d = deformed(v)
        write_mesh(MODELS / f"{bone}_deformed.ply", d, f)
        for name, base in (("ct", v), ("deformed", d)):
            pop = synthesise_population(base, 9, seed=0)
            model = build_ssm(pop.shapes, faces=f, variance=0.98, landmarks=marks)
            ShapeModel.save(model, MODELS / f"{bone}_{name}_ssm.npz")
        print(
            f"{bone}: {len(v)} vertices, landmarks {marks}, deformed RMS {_kabsch_rms(d, v):.3f} mm"
        )


CASE_TOML = """format = "biplanar-reg/case@1"
id = "{id}"
units = "mm"

[model]
ssm = "model/ssm.npz"
landmarks = "model/landmarks.json"

[[views]]
name = "cam01"
calibration = "data/cam01_calibration_mayacam2.txt"
calibration_format = "mayacam2"
image = "data/cam01_frame0099.tif"

[[views]]
name = "cam02"
calibration = "data/cam02_calibration_mayacam2.txt"
calibration_format = "mayacam2"
image = "data/cam02_frame0099.tif"

[annotations]
file = "annotations.json"

[registration]
poses = "known"
silhouettes = true

[ground_truth]
mesh = "model/truth.ply"   # the subject's CT mesh, in the CT's frame
up_to_pose = true
model_from_truth = {from_truth}
"""


def write_case(folder: Path, bone: str, template: str, annotations: Path | None) -> Path:
    """A case folder of ``bone`` with the ``template`` model ("ct" or "deformed") and the
    annotation file ``annotations`` (None: an empty one, to annotate in the workbench)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "data").mkdir(exist_ok=True)
    (folder / "model").mkdir(exist_ok=True)
    for name in ("cam01_frame0099.tif", "cam02_frame0099.tif", "cam01_calibration_mayacam2.txt",
                 "cam02_calibration_mayacam2.txt", "LICENSE.txt", "README.md"):  # fmt: skip
        shutil.copy2(DATA / name, folder / "data" / name)
    shutil.copy2(MODELS / f"{bone}_{template}_ssm.npz", folder / "model" / "ssm.npz")
    shutil.copy2(MODELS / f"{bone}_landmarks.json", folder / "model" / "landmarks.json")
    shutil.copy2(MODELS / f"{bone}_template.ply", folder / "model" / "truth.ply")
    if annotations is None:
        atomic_write_json(
            folder / "annotations.json", {"format": "biplanar-reg/annotations@1", "views": {}}
        )
    else:
        atomic_write_json(folder / "annotations.json", read_json(annotations))
    toml = CASE_TOML.format(id=folder.name, from_truth="true" if template == "ct" else "false")
    (folder / "case.toml").write_text(toml)
    return folder


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="also write the case folders here")
    ap.add_argument("--models", action="store_true", help="rebuild models/ from the CT volumes")
    args = ap.parse_args()
    if args.models or not (MODELS / "radius_ct_ssm.npz").exists():
        build_models()
    if args.out:
        for ann in sorted(ANNOTATIONS.glob("*.json")):
            bone, annotator = ann.stem.split("_", 1)
            for template in TEMPLATES:
                print(write_case(args.out / f"{bone}_{template}_{annotator}", bone, template, ann))


if __name__ == "__main__":
    main()
