"""Regenerate the bundled synthetic demo case (deterministic, seed 0).

    python sample_cases/synthetic_demo/make_case.py
    python sample_cases/synthetic_demo/make_case.py --out /tmp/demo_case   # elsewhere

Writes case.toml, model/, calib/, xray/, gt/ and annotations.json beside this script (or into
``--out``). The scene and the noise are documented in
``biplanar_reg.simulate.write_synthetic_case`` and docs/cases.md: a 482-vertex, 6-mode
synthetic bone; two perspective views 75 degrees apart; 512 x 512 PNG radiographs; landmarks
with 0.5 px and contours with 0.3 px Gaussian noise.
"""

import argparse
from pathlib import Path

from biplanar_reg.simulate import synthetic_bone_model, synthetic_landmarks, write_synthetic_case
from biplanar_reg.ssm import ShapeModel

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parent, help="default: beside this"
    )
    bone = synthetic_bone_model(6, seed=0)  # write_synthetic_case's default bone, named by anatomy
    marks = synthetic_landmarks(bone, bone="bone")
    model = ShapeModel(bone.mean, bone.modes, faces=bone.faces, variances=bone.variances,
                       landmarks=marks)  # fmt: skip
    folder = write_synthetic_case(
        ap.parse_args().out, seed=0, case_id="synthetic_demo", model=model
    )
    print(f"wrote {folder}")
