"""Regenerate the synthetic reference cases with full ground truth (deterministic).

    python sample_cases/make_reference_cases.py

Writes ``synthetic_radius_known/``, ``synthetic_radius_unknown/`` and
``synthetic_radius_blunder/`` beside this script: the radius template from the shipped CT
(1,000 vertices), its harmonic-population shape model, a harmonic deformation of the template
as the truth, posed near the real radius and seen by the real wrist calibrations cropped to the
bone, rendered radiographs, and annotations from the truth with documented noise (see
docs/sample_cases.md and ``biplanar_reg.cases.reference.write_reference_cases``).
"""

from pathlib import Path

from biplanar_reg.cases.reference import write_reference_cases

if __name__ == "__main__":
    for folder in write_reference_cases(Path(__file__).resolve().parent):
        print(f"wrote {folder}")
