"""Marker-bead detection on the real wrist radiographs, against beads counted by eye.

The small dark tantalum beads of ``/work/shared/data/wrist`` (``sample_cases/wrist_radius/data``
holds the same two frames) were counted by eye on full-resolution crops: 17 in each view (12
in the forearm in four rows of three, 5 along a metacarpal). Their centres (pixels, to about
1 px) are listed below. A detection within 4 px of a bead counts as found; other detections are
false positives, reported apart when they lie on the lead letters of the images ("F" in cam01,
"2" in cam02), which are radio-opaque too.

    python benchmarks/markers_wrist.py [--contrast 0.03 0.04]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from biplanar_reg.annotation import load_image
from biplanar_reg.annotation.markers import BEAD_RADII_PX, detect_markers

DATA = Path(__file__).resolve().parents[1] / "sample_cases" / "wrist_radius" / "data"
#: beads counted by eye, (u, v) pixels
BEADS = {
    "cam01": [
        (950, 1455), (952, 1481), (948, 1417), (944, 1454), (944, 1479), (939, 1414),
        (805, 1340), (796, 1372), (765, 1374), (779, 1319), (764, 1350), (788, 1397),
        (931, 854), (933, 817), (914, 905), (918, 834), (908, 875),
    ],
    "cam02": [
        (879, 1434), (878, 1401), (880, 1460), (892, 1412), (888, 1437), (895, 1381),
        (602, 1423), (599, 1466), (617, 1470), (593, 1490), (621, 1432), (619, 1497),
        (895, 871), (862, 942), (885, 913), (878, 851), (857, 887),
    ],
}  # fmt: skip
#: the lead letter of each image: (u0, v0, u1, v1) pixels
LETTERS = {"cam01": (1610, 840, 1670, 895), "cam02": (15, 805, 65, 855)}
FOUND_PX = 4.0


def measure(view: str, contrast: float) -> dict[str, float]:
    """Detect the beads of one view; counts and seconds."""
    image = load_image(DATA / f"{view}_frame0099.tif")
    t0 = time.perf_counter()
    found = detect_markers(image, radii_px=BEAD_RADII_PX, min_contrast=contrast)
    seconds = time.perf_counter() - t0
    truth = np.array(BEADS[view], float)
    uv = np.array([m.uv for m in found], float).reshape(-1, 2)
    d = np.linalg.norm(uv[:, None, :] - truth[None, :, :], axis=2)
    hit = d.min(axis=1) <= FOUND_PX if len(uv) else np.zeros(0, bool)
    u0, v0, u1, v1 = LETTERS[view]
    letter = (uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)
    return {
        "beads": len(truth),
        "found": int((d.min(axis=0) <= FOUND_PX).sum()) if len(uv) else 0,
        "detections": len(uv),
        "false_letter": int((~hit & letter).sum()),
        "false_other": int((~hit & ~letter).sum()),
        "seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--contrast", type=float, nargs="+", default=[0.03, 0.04])
    args = parser.parse_args()
    print("| view | min_contrast | beads (eye) | found | detections | false (letter) |"
          " false (other) | seconds |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for contrast in args.contrast:
        for view in BEADS:
            r = measure(view, contrast)
            print(
                f"| {view} | {contrast:g} | {r['beads']} | {r['found']} | {r['detections']} | "
                f"{r['false_letter']} | {r['false_other']} | {r['seconds']:.2f} |"
            )


if __name__ == "__main__":
    main()
