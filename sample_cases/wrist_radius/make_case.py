"""Regenerate the real wrist case (distal radius, two real radiographs) deterministically.

    python sample_cases/wrist_radius/make_case.py

Reads only ``data/`` (the shipped Autoscoper sample data, BSD licence, unchanged) and the
committed annotation inputs in ``annotation/`` (livewire recipes, landmark clicks), and writes:

* ``model/radius_template.ply``: the distal radius from ``data/radius_ct.tif`` with the
  project's CT-to-mesh tool (Otsu threshold, 2,000 vertices), CT frame, mm;
* ``model/radius_ssm.npz``: shape model of a 9-shape harmonic-deformation population of the
  template (seed 0, all families, 98 % variance), with the landmarks;
* ``model/landmarks.json``: the anatomical landmark vertex ids, chosen on the template by the
  rules of :func:`landmark_vertices` (documented in docs/sample_cases.md);
* ``annotations.json``: the livewire contours of the four recipes and the landmark clicks
  snapped to the nearest edge (``biplanar_reg.annotation.snap_landmark``, edge mode);
* ``case.toml``: views ``cam01``/``cam02`` with ``data/`` calibrations and images; the ground
  truth is the CT template itself, known up to pose (``[ground_truth] up_to_pose = true``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from biplanar_reg.annotation import (
    Annotations,
    Landmark,
    ViewAnnotations,
    load_image,
    merge_annotations,
    save_annotations,
)
from biplanar_reg.annotation.recipe import load_recipe, run_recipe
from biplanar_reg.annotation.snap import snap_landmark
from biplanar_reg.io import atomic_write_bytes, atomic_write_json, read_json, write_mesh
from biplanar_reg.ssm import ShapeModel

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # sample_cases/reference.py, the sample cases' generator
from reference import radius_model, radius_template  # noqa: E402

VIEWS = ("cam01", "cam02")

CASE_TOML = """format = "biplanar-reg/case@1"
id = "wrist_radius"
units = "mm"

[model]
ssm = "model/radius_ssm.npz"
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
mesh = "model/radius_template.ply"   # the same subject's CT, in the CT's frame
up_to_pose = true
model_from_truth = true   # the model population was synthesised from this CT: errors are optimistic
"""


def landmark_vertices(vertices: np.ndarray) -> dict[str, int]:
    """Anatomical landmarks on the radius template (CT frame: +z proximal, the distal end at
    low z; y mediolateral with the styloid at low y; x dorsovolar with the dorsal side at
    high x, where Lister's tubercle bulges).

    * ``radial_styloid_tip``: the most distal vertex (lowest z);
    * ``ulnar_notch_dorsal`` / ``ulnar_notch_volar``: among the vertices 8-16 mm from the
      distal tip within 2.5 mm of the most ulnar (highest y) one, the most dorsal / volar;
    * ``listers_tubercle``: the most dorsal vertex 8-22 mm from the tip within 6 mm of the
      median mediolateral position.
    """
    x, y, z = (vertices - [0.0, 0.0, vertices[:, 2].min()]).T
    out = {"radial_styloid_tip": int(np.argmin(z))}
    band = np.flatnonzero((z > 8) & (z < 16))
    rim = band[y[band] > y[band].max() - 2.5]
    out["ulnar_notch_dorsal"] = int(rim[np.argmax(x[rim])])
    out["ulnar_notch_volar"] = int(rim[np.argmin(x[rim])])
    band = np.flatnonzero((z > 8) & (z < 22))
    mid = band[np.abs(y[band] - np.median(y[band])) < 6]
    out["listers_tubercle"] = int(mid[np.argmax(x[mid])])
    return out


def snapped_landmarks(clicks_path: Path) -> Annotations:
    """Landmark clicks snapped to the nearest image edge (mode, radius and sigma from the file)."""
    doc = read_json(clicks_path)
    snap = doc["snap"]
    ann = Annotations()
    for view, points in doc["views"].items():
        image = load_image(HERE / "data" / f"{view}_frame0099.tif")
        lms = {}
        for name, uv in points.items():
            s = snap_landmark(image, uv, radius_px=snap["radius_px"], mode=snap["mode"])
            lms[name] = Landmark(s.uv, float(snap["sigma_px"]))
        ann.views[view] = ViewAnnotations(lms, [])
    return ann


def main() -> None:
    verts, faces = radius_template(2000)
    landmarks = landmark_vertices(verts)
    (HERE / "model").mkdir(exist_ok=True)
    write_mesh(HERE / "model" / "radius_template.ply", verts, faces)
    model = radius_model(verts, faces, landmarks=landmarks)
    ShapeModel.save(model, HERE / "model" / "radius_ssm.npz")
    atomic_write_json(HERE / "model" / "landmarks.json", landmarks)

    parts = [snapped_landmarks(HERE / "annotation" / "landmark_clicks.json")]
    for path in sorted((HERE / "annotation").glob("*.recipe.json")):
        recipe = load_recipe(path)
        pieces = run_recipe(recipe, base_dir=path.parent)
        parts.append(Annotations({recipe.view: ViewAnnotations({}, pieces)}))
    for view in VIEWS:  # every view present, even without annotations
        parts.append(Annotations({view: ViewAnnotations({}, [])}))
    save_annotations(merge_annotations(parts), HERE / "annotations.json")
    atomic_write_bytes(HERE / "case.toml", CASE_TOML.encode("utf-8"))
    print(f"wrote {HERE}")


if __name__ == "__main__":
    main()
