"""Regenerate the synthetic reference cases with full ground truth (deterministic).

    python sample_cases/make_reference_cases.py

Writes ``synthetic_radius_known/``, ``synthetic_radius_unknown/`` and
``synthetic_radius_blunder/`` beside this script: the radius template from the shipped CT
(1,000 vertices), its harmonic-population shape model, a harmonic deformation of the template
as the truth, posed near the real radius and seen by the real wrist calibrations cropped to the
bone, rendered radiographs, and annotations from the truth with documented noise (see
docs/sample_cases.md and ``reference.write_reference_cases`` beside this script).

    python sample_cases/make_reference_cases.py --out /tmp/ref   # into another folder
"""

import argparse
from pathlib import Path

from reference import write_reference_cases  # sample_cases/reference.py (the script's folder)

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parent, help="default: beside this"
    )
    for folder in write_reference_cases(ap.parse_args().out):
        print(f"wrote {folder}")
