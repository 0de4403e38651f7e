"""Regenerate the two-bone sample case: a synthetic distal radius and ulna, each with its own
shape model and annotations, seen together (overlapping) in one biplanar pair.

    python sample_cases/wrist_radius_ulna/make_case.py [--out DIR] [--seed 0]

The scene is the realistic wrist scene of ``biplanar_reg.simulate.realistic.wrist_scene``
(radius template from the shipped CT, 300 vertices; its 18-member harmonic population, the
6-mode model built from the first 8 members, the truth a held-out member: out of the model's
span). The ulna gets the same treatment here: its CT surface (300 vertices, placed beside the
radius as in the scene, 1.5 mm apart) is the template of an 18-member harmonic population,
its 6-mode model is built from the first 8 members and its truth is held-out member
8 + seed % 10. The radius is
posed near the real radius's pose (rotation perturbed by up to 10 deg, translation by up to 3 mm);
the ulna moves with it plus up to 1 deg / 0.5 mm of its own (so the true bones do not touch).

Both bones, and a soft-tissue cylinder, are rendered into each radiograph (the two real MayaCam
2.0 calibrations read out in a window around both bones, 0.8 px blur, noise 0.01), where they
overlap. Each bone's outline is traced with the project's livewire (open stretches of 60-80 %
of its outline, anchors every 40 px with 1.5 px click noise; the tracer follows the strongest
edge, which near the other bone may be that bone's); 3 landmarks per view and bone, projected
plus N(0, 1.5 px). Ground truth: both true surfaces in the world frame (model vertex order).
"""

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from biplanar_reg.annotation import (
    Annotations,
    Contour,
    Landmark,
    ViewAnnotations,
    save_annotations,
)
from biplanar_reg.calibration import save_calibration
from biplanar_reg.io import atomic_write_bytes, atomic_write_json, read_volume, write_mesh
from biplanar_reg.simulate.realistic import (
    WRIST_CT_VOXEL_MM,
    _crop,
    _mask_outline,
    _render,
    _trace,
    _traceable,
    model_floor,
    model_off_the_cut,
    wrist_scene,
)
from biplanar_reg.ssm import bone_surface, synthesise_population

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "wrist_radius" / "data"
N_POP, N_TRAIN, N_MODES, N_LANDMARKS, NOISE_PX = 18, 8, 6, 3, 1.5
#: Vertex counts of the two surfaces (small: the case is registered in the test suite).
N_RADIUS, N_ULNA = 300, 300

CASE_TOML = """format = "biplanar-reg/case@1"
id = "wrist_radius_ulna"
units = "mm"

# two bones seen together: each [[bones]] table has its own model, annotations and ground
# truth (the keys of [model], [annotations] and [ground_truth]; docs/bones.md); the views
# and [registration] are shared
[[bones]]
name = "radius"
model = {ssm = "model/radius_ssm.npz", landmarks = "model/radius_landmarks.json"}
annotations = "radius_annotations.json"
ground_truth = {mesh = "gt/radius.ply"}

[[bones]]
name = "ulna"
model = {ssm = "model/ulna_ssm.npz", landmarks = "model/ulna_landmarks.json"}
annotations = "ulna_annotations.json"
ground_truth = {mesh = "gt/ulna.ply"}

[[views]]
name = "cam01"
calibration = "calib/cam01.json"
calibration_format = "json"
image = "xray/cam01.png"

[[views]]
name = "cam02"
calibration = "calib/cam02.json"
calibration_format = "json"
image = "xray/cam02.png"

[registration]
poses = "known"
silhouettes = true
"""


def _ulna_template(scene):
    """The ulna's CT surface with N_ULNA vertices, placed where the scene put its own ulna
    (template frame: the scene's ulna is the 600-vertex surface of the same CT, translated)."""
    vol = read_volume(DATA / "ulna_ct.tif", voxel_size=WRIST_CT_VOXEL_MM)
    full = bone_surface(vol, target_vertices=600)
    shift = scene.second[0][0] - full.vertices[0]
    assert np.allclose(scene.second[0] - full.vertices, shift)  # a pure translation
    small = bone_surface(vol, target_vertices=N_ULNA)
    return small.vertices + shift, np.asarray(small.faces)


def _ulna_model(scene, seed):
    """The ulna's population (template = the scene's ulna, template frame), its model from the
    first N_TRAIN members with landmarks off the crop's cut, and the cut mask."""
    verts, faces = _ulna_template(scene)
    pop = synthesise_population(verts, N_POP, seed=seed + 1, resolution=40)
    model, cut = model_off_the_cut(verts, pop.shapes[:N_TRAIN], faces, N_MODES, "ulna")
    return model, pop.shapes, cut, faces


def _landmarks(model, truth, view, rng):
    names = list(model.landmarks)[:N_LANDMARKS]
    ids = [model.landmarks[n] for n in names]
    uv = view.project(truth[ids]) + rng.normal(0.0, NOISE_PX, (len(ids), 2))
    return {n: Landmark(uv=p, sigma_px=NOISE_PX) for n, p in zip(names, uv, strict=True)}


def _png(image):
    import cv2

    ok, buf = cv2.imencode(".png", np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    assert ok
    return buf.tobytes()


def make(out: Path, seed: int = 0) -> Path:
    scene = wrist_scene(str(DATA), n_vertices=N_RADIUS)
    ulna_model, ulna_pop, ulna_cut, ulna_faces = _ulna_model(scene, seed)
    rng = np.random.default_rng([seed, 30])
    member = N_TRAIN + seed % (N_POP - N_TRAIN)
    radius_shape, ulna_shape = scene.population[member], ulna_pop[member]
    c = radius_shape.mean(axis=0)
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(np.deg2rad(10) * rng.uniform() * axis / np.linalg.norm(axis))
    R = R.as_matrix() @ scene.pose.R
    t = scene.pose.apply(c) - R @ c + rng.uniform(-3.0, 3.0, 3)
    radius = radius_shape @ R.T + t
    uc = ulna_shape.mean(axis=0)
    own = Rotation.from_rotvec(np.deg2rad(1.0) * rng.uniform(-1, 1, 3) / np.sqrt(3)).as_matrix()
    ulna = ((ulna_shape - uc) @ own.T + uc + rng.uniform(-0.5, 0.5, 3)) @ R.T + t
    scene2 = dataclasses.replace(scene, second=(ulna_shape, ulna_faces))
    tissue = (R @ scene.tissue[0] + t, R[:, 2])
    views = [_crop(v, np.vstack([radius, ulna])) for v in scene.views]
    ann = {"radius": Annotations(), "ulna": Annotations()}
    for sub in ("model", "calib", "xray", "gt"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for view in views:
        img, r_outline, ulna_mask = _render(scene2, view, radius, ulna, tissue, rng, 1)
        u_outline = _mask_outline(ulna_mask)
        for name, outline, bone, cut, model in (
            ("radius", r_outline, radius, scene.cut, scene.model),
            ("ulna", u_outline, ulna, ulna_cut, ulna_model),
        ):
            part = _traceable(outline, True, view.project(bone[cut]))
            keep = min(int(round(float(rng.uniform(0.6, 0.8)) * len(outline))), len(part))
            pieces = _trace(img, part, keep, 40.0, 1.5, rng)
            ann[name].views[view.name] = ViewAnnotations(
                landmarks=_landmarks(model, bone, view, rng),
                contours=[Contour(uv=p, closed=False) for p in pieces],
            )
        save_calibration(view, out / "calib" / f"{view.name}.json", "json")
        atomic_write_bytes(out / "xray" / f"{view.name}.png", _png(img))
    floors = {}
    for name, model, truth in (
        ("radius", scene.model, radius),
        ("ulna", ulna_model, ulna),
    ):
        model.save(out / "model" / f"{name}_ssm.npz")
        atomic_write_json(out / "model" / f"{name}_landmarks.json", dict(model.landmarks))
        save_annotations(ann[name], out / f"{name}_annotations.json")
        write_mesh(out / "gt" / f"{name}.ply", truth, model.faces)
        floors[name] = model_floor(model, truth)[0]
    atomic_write_bytes(out / "case.toml", CASE_TOML.encode())
    atomic_write_json(
        out / "gt" / "truth.json",
        {"seed": seed, "member": member, "model_floor_vertex_rms_mm": floors},
    )
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE, help="default: beside this script")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"wrote {make(args.out, args.seed)}")
