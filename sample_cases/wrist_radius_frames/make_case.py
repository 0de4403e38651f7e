"""Regenerate the multi-frame sample case (a synthetic distal radius moving over 3 frames).

    python sample_cases/wrist_radius_frames/make_case.py [--out DIR]

The scene is the realistic wrist scene of ``biplanar_reg.simulate.realistic.wrist_scene``
(radius truth out of the 8-member, 6-mode SSM's span, the ulna overlapping it, the two real
MayaCam 2.0 calibrations cropped to the bones), moved along a smooth path
(``biplanar_reg.simulate.sequence.make_sequence``, seed 0, 3 frames, 30 deg / 8 mm): rendered
radiographs, livewire-traced open outlines in every frame, 3 landmarks per view in frames f0
and f2 and none in f1. Written by ``write_sequence_case``; ``gt/truth.json`` holds the truth.
"""

import argparse
from pathlib import Path

from biplanar_reg.simulate.realistic import wrist_scene
from biplanar_reg.simulate.sequence import make_sequence, write_sequence_case

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE, help="default: beside this script")
    out = ap.parse_args().out
    scene = wrist_scene(str(HERE.parent / "wrist_radius" / "data"), n_vertices=500)
    case = make_sequence(0, scene=scene, n_frames=3, landmark_frames=[0, 2])
    print(f"wrote {write_sequence_case(out, case, case_id='wrist_radius_frames')}")
