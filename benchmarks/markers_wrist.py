"""Marker-bead detection on the real wrist radiographs, against beads counted by eye.

The small dark tantalum beads of ``/work/shared/data/wrist`` (``sample_cases/wrist_radius/data``
holds the same two frames) were counted by eye on full-resolution crops: 17 in each view (12
in the forearm in four rows of three, 5 along a metacarpal). Their centres (pixels, to about
1 px) are listed below. A detection within 4 px of a bead counts as found; other detections are
false positives, reported apart when they lie on the lead letters of the images ("F" in cam01,
"2" in cam02), which are radio-opaque too.

The larger skin-marker discs (9 in cam01's forearm, 6 in cam02's and 5 over its metacarpals)
are listed too, for ``--kind discs`` (found within 8 px: their centres by eye are rougher).

    python benchmarks/markers_wrist.py [--contrast 0.03 0.035 0.04] [--kind beads|discs]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from biplanar_reg.annotation import load_image
from biplanar_reg.annotation.markers import BEAD_RADII_PX, DISC_RADII_PX, detect_markers

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
#: the larger skin-marker discs (radius ~17 px) counted by eye, centres to ~4 px
DISCS = {
    "cam01": [
        (738, 1220), (913, 1218), (892, 1318), (970, 1363), (820, 1393), (915, 1420),
        (980, 1480), (872, 1520), (952, 1572),
    ],
    "cam02": [
        (603, 1374), (822, 1370), (590, 1492), (790, 1500), (560, 1578), (843, 1588),
        (820, 848), (915, 835), (752, 955), (922, 932), (870, 1018),
    ],
}  # fmt: skip
#: the lead letter of each image: (u0, v0, u1, v1) pixels
LETTERS = {"cam01": (1610, 840, 1670, 895), "cam02": (15, 805, 65, 855)}
#: a detection this near a marker counted by eye found it, px (beads, discs)
FOUND_PX = {"beads": 4.0, "discs": 8.0}


def measure(view: str, contrast: float, kind: str = "beads") -> dict[str, float]:
    """Detect the markers of one kind in one view; counts and seconds."""
    image = load_image(DATA / f"{view}_frame0099.tif")
    radii = BEAD_RADII_PX if kind == "beads" else DISC_RADII_PX
    t0 = time.perf_counter()
    found = detect_markers(image, radii_px=radii, min_contrast=contrast)
    seconds = time.perf_counter() - t0
    truth = np.array((BEADS if kind == "beads" else DISCS)[view], float)
    near = FOUND_PX[kind]
    uv = np.array([m.uv for m in found], float).reshape(-1, 2)
    d = np.linalg.norm(uv[:, None, :] - truth[None, :, :], axis=2)
    hit = d.min(axis=1) <= near if len(uv) else np.zeros(0, bool)
    u0, v0, u1, v1 = LETTERS[view]
    letter = (uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)
    return {
        "beads": len(truth),
        "found": int((d.min(axis=0) <= near).sum()) if len(uv) else 0,
        "detections": len(uv),
        "false_letter": int((~hit & letter).sum()),
        "false_other": int((~hit & ~letter).sum()),
        "seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--contrast", type=float, nargs="+", default=[0.03, 0.035, 0.04])
    parser.add_argument("--kind", choices=["beads", "discs"], default="beads")
    args = parser.parse_args()
    print(f"| view | min_contrast | {args.kind} (eye) | found | detections | false (letter) |"
          " false (other) | seconds |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for contrast in args.contrast:
        for view in BEADS:
            r = measure(view, contrast, args.kind)
            print(
                f"| {view} | {contrast:g} | {r['beads']} | {r['found']} | {r['detections']} | "
                f"{r['false_letter']} | {r['false_other']} | {r['seconds']:.2f} |"
            )


if __name__ == "__main__":
    main()
