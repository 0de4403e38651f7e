"""Regenerate the bundled synthetic demo case (deterministic, seed 0).

    python sample_cases/synthetic_demo/make_case.py

Writes case.toml, model/, calib/, xray/, gt/ and annotations.json beside this script. The scene
and the noise are documented in ``biplanar_reg.cases.synthetic_case`` and docs/cases.md: a
482-vertex, 6-mode synthetic bone; two perspective views 75 degrees apart; 512 x 512 PNG
radiographs; landmarks with 0.5 px and contours with 0.3 px Gaussian noise.
"""

from pathlib import Path

from biplanar_reg.cases.synthetic_case import write_synthetic_case

if __name__ == "__main__":
    folder = write_synthetic_case(Path(__file__).resolve().parent, seed=0, case_id="synthetic_demo")
    print(f"wrote {folder}")
