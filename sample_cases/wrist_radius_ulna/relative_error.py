"""The registered relative pose of the ulna in the radius against the truth's (docs/bones.md).

    biplanar-reg register sample_cases/wrist_radius_ulna --out /tmp/wru
    python sample_cases/wrist_radius_ulna/relative_error.py /tmp/wru

The truth's pose of each bone is the rigid part of the best (prior-free) rigid + model fit of
its ground-truth surface (``biplanar_reg.ssm.fit_model``): the truth is out of the models'
span, so this is the pose the model can best express. Prints the rotation (deg) and
translation (mm) between the registered and the true pose of the ulna in the radius's frame,
and per bone the vertex RMS error and its ratio to the model floor.
"""

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from biplanar_reg.cases import load_case
from biplanar_reg.io import read_tra, relative_pose, rigid_pose
from biplanar_reg.ssm import fit_model

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the output folder of register")
    out = ap.parse_args().out
    true, reg = {}, {}
    for bone in load_case(HERE).bones:
        fit = fit_model(bone.model, bone.ground_truth.vertices)
        true[bone.bone] = rigid_pose(fit.rotation, fit.translation)
        reg[bone.bone] = read_tra(out / f"{bone.bone}.tra")[0]
    t_rel = relative_pose(true["radius"], true["ulna"])
    r_rel = relative_pose(reg["radius"], reg["ulna"])
    d = np.linalg.inv(t_rel) @ r_rel
    deg = np.rad2deg(Rotation.from_matrix(d[:3, :3]).magnitude())
    mm = np.linalg.norm(r_rel[:3, 3] - t_rel[:3, 3])
    print(f"ulna in radius: rotation error {deg:.2f} deg, translation error {mm:.2f} mm")
    doc = json.loads((out / "result.json").read_text())
    for name, b in doc["bones"].items():
        m = b["metrics"]
        floor, ratio = m["model_floor_vertex_rms_mm"], m["vertex_rms_to_floor"]
        print(
            f"{name}: vertex RMS {m['vertex_rms_mm']:.3f} mm, floor {floor:.3f} mm (ratio "
            f"{ratio:.2f}), mean shape {m['mean_shape_vertex_rms_mm']:.3f} mm"
        )
    (pair,) = doc["contact"]["pairs"]
    gap = pair["frames"][0]["clearance_mm"]
    print(f"contact: depth {pair['max_depth_mm']:.2f} mm, clearance {gap:.2f} mm")
