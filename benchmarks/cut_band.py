"""How far a template's cut reaches: the width of the band left out of the region of interest.

The templates of the sample cases are CT-cropped bones: their surface ends in a flat cap where
the bone left the scanned volume (:func:`biplanar_reg.cases.cuts.detect_cuts`). This script
measures, against the distance from that cap (on the model's mean shape,
:func:`biplanar_reg.cases.cuts.cut_distance`):

1. **geometry**: how the surface turns from the cap into the shaft. Per distance bin the
   median of ``|n . n_cap|`` (vertex normal against the cap's normal: 1 on the cap, 0 on a
   shaft wall parallel to the cut's normal) over the cut templates' mean shapes;
2. **errors of real registrations**: every sample case whose template has a cut is registered
   (``run_case_dir``, no report) and each registered vertex's error to the ground truth is
   binned by its distance from the cut: the RMS of the vertex-to-vertex error (vertex i
   against vertex i of the truth) and of the vertex-to-surface distance, and the bins' share
   of the squared vertex error. The truth is first aligned as ``register`` does for
   ``up_to_pose`` cases; a multi-frame case contributes its frame 0 (``registered.ply``).

3. **detection**: the two tests of :func:`~biplanar_reg.cases.cuts.detect_cuts` on every
   plane its directions lead to, for surfaces with a cut (the sample cases' templates, mean
   shapes and ground truths; the radius and ulna CTs extracted at several resolutions,
   :func:`biplanar_reg.ssm.bone_surface`; each also rotated) and without (spheres, an
   ellipsoid, capsules, the synthetic bone-like model): the prism ratio (cross-section 1 mm
   inside / 4 mm inside) and the flat fraction (triangles on the plane / cross-section 4 mm
   inside) of the found caps, and the largest prism ratio of any plane of a surface without a
   cut.

Run ``python benchmarks/cut_band.py`` (about a minute on two cores); writes
``benchmarks/results/cut_band.md``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from biplanar_reg.cases import load_case
from biplanar_reg.cases.alignment import align_rigid
from biplanar_reg.cases.cuts import cut_distance, cut_region, detect_cuts
from biplanar_reg.cases.metrics import (
    SURFACE_SAMPLES,
    _sample_surface,
    point_to_surface,
    surface_metrics,
)
from biplanar_reg.cases.run import run_case_dir
from biplanar_reg.io import read_mesh
from biplanar_reg.io.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
#: Voxel size of the wrist CTs (column, row, slice), mm (sample_cases/reference.py).
CT_VOXEL_MM = (0.39625, 0.39625, 0.625)
CASES = (
    "wrist_radius",
    "synthetic_radius_known",
    "synthetic_radius_unknown",
    "synthetic_radius_blunder",
    "wrist_radius_frames",
    "wrist_radius_ulna",
)
#: Distance bins (mm) from the cut: [edges[i], edges[i + 1]).
EDGES = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, 20.0, np.inf)
#: Finer bins (mm) of the surface samples.
PROFILE_EDGES = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, 20.0, np.inf)
#: Band widths (mm) of the sweep.
BANDS = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)
#: The reference of each bone's errors: its vertices at least this far (mm) from the cut.
FAR_MM = 20.0


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # area-weighted
    out = np.zeros_like(V)
    for i in range(3):
        np.add.at(out, F[:, i], n)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def _bones(case):
    """``(label, single-bone case, path of its registered.ply in the output folder)``."""
    if case.bones:
        return [(f"{case.id}/{b.bone}", b, Path("bones") / b.bone) for b in case.bones]
    return [(case.id, case, Path("."))]


def _truth(bone, registered: np.ndarray):
    gt = bone.ground_truth if bone.ground_truth is not None else bone.frames[0].ground_truth
    G = gt.vertices
    if gt.up_to_pose:
        G = align_rigid(gt.vertices, gt.faces, registered, bone.model.faces).apply(gt.vertices)
    return G, gt.faces


def measure(cases=CASES) -> tuple[list[dict], list[dict]]:
    """Per bone: the distance of each vertex from the cut, its normal's ``|n . n_cap|``, and
    its vertex and surface errors (mm)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="cut-band-") as tmp:
        for name in cases:
            case = load_case(ROOT / "sample_cases" / name)
            out = Path(tmp) / name
            run_case_dir(case.case_dir, out, report=False)
            for label, bone, sub in _bones(case):
                mean, F = bone.model.mean.reshape(-1, 3), bone.model.faces
                cuts = detect_cuts(mean, F)
                if not cuts.caps:
                    continue
                V, _ = read_mesh(out / sub / "registered.ply")
                G, GF = _truth(bone, V)
                cap = cuts.caps[0].normal
                rows.append(
                    {
                        "bone": label,
                        "distance": cut_distance(mean, F, cuts),
                        "turn": np.abs(_vertex_normals(mean, F) @ cap),
                        "vertex": np.linalg.norm(V - G, axis=1),
                        "surface": point_to_surface(V, G, GF),
                        "sweep": _sweep(V, F, G, GF, mean),
                        "profile": _profile(V, F, G, GF, mean, cuts),
                        "edge": _median_edge(mean, F),
                    }
                )
    return rows


def _median_edge(V: np.ndarray, F: np.ndarray) -> float:
    """The median edge length (mm) of a surface (each triangle's three edges)."""
    return float(np.median(np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2)))


def _sweep(V, F, G, GF, mean) -> dict[float, dict]:
    """``surface_metrics`` with the default region of each band width (mm), and without."""
    out = {None: surface_metrics(V, F, G, GF)[0]}
    for band in BANDS:
        out[band] = surface_metrics(V, F, G, GF, region=cut_region(mean, F, band_mm=band))[0]
    return out


def _profile(V, F, G, GF, mean, cuts) -> tuple[np.ndarray, np.ndarray]:
    """Points sampled on the registered surface (as ``surface_metrics`` does): their distance
    from the cut (the same point of the mean shape, by its barycentric coordinates) and their
    distance to the truth, mm."""
    pts, face, bary = _sample_surface(V, F, SURFACE_SAMPLES, 0)
    on_mean = np.einsum("ki,kij->kj", bary, mean[F[face]])
    caps = np.vstack([F[c.faces] for c in cuts.caps])
    return point_to_surface(on_mean, mean, caps), point_to_surface(pts, G, GF)


def _zoo() -> tuple[dict, dict]:
    """Surfaces ``{name: (vertices, faces)}`` with a cut and without."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from biplanar_reg.io import read_volume
    from biplanar_reg.simulate import synthetic_bone_model
    from biplanar_reg.ssm import ShapeModel, bone_surface

    cut = {}
    for p in sorted((ROOT / "sample_cases").glob("*/model/*.npz")):
        m = ShapeModel.load(p)
        cut[f"{p.parts[-3]} {p.stem} mean"] = (m.mean.reshape(-1, 3), m.faces)
    for p in sorted((ROOT / "sample_cases").glob("*/gt/*.ply")):
        if p.parts[-3] != "synthetic_demo":
            cut[f"{p.parts[-3]} {p.name}"] = read_mesh(p)
    cut["radius_template.ply"] = read_mesh(
        ROOT / "sample_cases/wrist_radius/model/radius_template.ply"
    )
    for bone in ("radius", "ulna"):
        vol = read_volume(
            ROOT / f"sample_cases/wrist_radius/data/{bone}_ct.tif", voxel_size=CT_VOXEL_MM
        )
        for n in (300, 1000, 4000, None):
            s = bone_surface(vol, target_vertices=n)
            cut[f"{bone} CT, target_vertices={n}"] = (s.vertices, s.faces)
    R = Rotation.from_rotvec([0.5, -0.9, 0.4]).as_matrix()
    cut.update({f"{k}, rotated": (np.asarray(v) @ R.T, f) for k, (v, f) in list(cut.items())})
    ico = trimesh.creation.icosphere(3, radius=10.0)
    cap = trimesh.creation.capsule(height=40.0, radius=8.0, count=[32, 32])
    bone = synthetic_bone_model(8, seed=0)
    none = {
        "sphere r 10": (ico.vertices, ico.faces),
        "ellipsoid 10 x 15 x 40": (ico.vertices * [1.0, 1.5, 4.0], ico.faces),
        "capsule r 8": (cap.vertices, cap.faces),
        "synthetic bone-like model, mean": (bone.mean.reshape(-1, 3), bone.faces),
    }
    for k in range(3):
        w = np.zeros(bone.n_modes)
        w[k] = 2.5
        none[f"synthetic bone-like model, +2.5 sd mode {k}"] = (bone.instance(w), bone.faces)
    return cut, none


def _planes(V, F) -> list[tuple[float, float, np.ndarray]]:
    """(prism ratio, flat fraction, triangles) of every plane the directions of
    ``detect_cuts`` lead to."""
    from biplanar_reg.cases import cuts as c

    geo = c._Faces(np.asarray(V, float), np.asarray(F, np.int64))
    out, seen = [], set()
    for n in c._directions(geo):
        plane = c._plane(geo, n)
        if plane is None or plane[1].tobytes() in seen:
            continue
        seen.add(plane[1].tobytes())
        n, on = plane
        top = float(np.max(geo.V @ n))
        deep = c._section_area(geo, n, top - c.SECTION_DEPTH_MM)
        if deep > 0:
            near = c._section_area(geo, n, top - c.NEAR_DEPTH_MM)
            out.append((near / deep, float(geo.area[on].sum()) / deep, on))
    return out


def _detection_rows() -> list[str]:
    cut, none = _zoo()
    lines = [
        "| surface | caps found | prism ratio of the caps | flat fraction of the caps | "
        "largest prism ratio of any plane apart from the caps |",
        "|---|---|---|---|---|",
    ]
    for name, (V, F) in {**cut, **none}.items():
        cuts = detect_cuts(V, F)
        prism = [c.near_section_mm2 / c.section_mm2 for c in cuts.caps]
        flat = [c.area_mm2 / c.section_mm2 for c in cuts.caps]
        taken = np.concatenate([c.faces for c in cuts.caps] + [np.zeros(0, np.int64)])
        other = [p for p, _, on in _planes(V, F) if not np.isin(on, taken).any()]
        lines.append(
            f"| {name} | {len(cuts.caps)} | {', '.join(f'{p:.2f}' for p in prism) or '-'} | "
            f"{', '.join(f'{x:.2f}' for x in flat) or '-'} | "
            f"{max(other) if other else float('nan'):.2f} |"
        )
    return lines


def _bin_rows(rows: list[dict]) -> list[str]:
    """Per distance bin: vertices, the normals' turn, and each bone's error RMS in the bin as a
    ratio to its RMS beyond :data:`FAR_MM` (the bones' error scales differ), median and range
    over the bones."""
    lines = [
        "| distance from the cut (mm) | vertices | median abs(n . n_cap) | vertex-to-surface "
        f"RMS / beyond {FAR_MM:g} mm: median (min-max) over the bones | vertex error RMS / "
        f"beyond {FAR_MM:g} mm: median (min-max) |",
        "|---|---|---|---|---|",
    ]
    d = np.concatenate([r["distance"] for r in rows])
    turn = np.concatenate([r["turn"] for r in rows])
    for lo, hi in zip(EDGES[:-1], EDGES[1:], strict=True):
        k = (d >= lo) & (d < hi)
        if not k.any():
            continue
        cells = []
        for key in ("surface", "vertex"):
            ratio = []
            for r in rows:
                b = (r["distance"] >= lo) & (r["distance"] < hi)
                far = r["distance"] >= FAR_MM
                if b.any():
                    ratio.append(_rms(r[key][b]) / _rms(r[key][far]))
            cells.append(f"{np.median(ratio):.2f} ({min(ratio):.2f}-{max(ratio):.2f})")
        lines.append(
            f"| {lo:g}-{hi:g} | {int(k.sum())} | {np.median(turn[k]):.2f} | {cells[0]} | "
            f"{cells[1]} |"
        )
    return lines


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _profile_rows(rows: list[dict]) -> list[str]:
    """Per distance bin of the surface samples: each bone's RMS distance to the truth in the
    bin as a ratio to its RMS beyond :data:`FAR_MM`, median and range over the bones."""
    lines = [
        f"| distance from the cut (mm) | samples | RMS distance to the truth / beyond {FAR_MM:g} "
        "mm: median (min-max) over the bones |",
        "|---|---|---|",
    ]
    for lo, hi in zip(PROFILE_EDGES[:-1], PROFILE_EDGES[1:], strict=True):
        ratio, n = [], 0
        for r in rows:
            d, e = r["profile"]
            b = (d >= lo) & (d < hi)
            n += int(b.sum())
            if b.sum() >= 10:
                ratio.append(_rms(e[b]) / _rms(e[d >= FAR_MM]))
        if ratio:
            lines.append(
                f"| {lo:g}-{hi:g} | {n} | {np.median(ratio):.2f} "
                f"({min(ratio):.2f}-{max(ratio):.2f}) |"
            )
    return lines


def _sweep_rows(rows: list[dict]) -> list[str]:
    """Per bone: ``roi_surface_rms_mm`` / ``roi_surface_p95_mm`` / ``roi_signed_mean_mm`` of
    each band width, and the whole surface's."""
    head = " | ".join(f"band {b:g} mm" for b in BANDS)
    lines = [f"| bone | whole surface | {head} |", "|---" * (len(BANDS) + 2) + "|"]
    for r in rows:
        cells = []
        for band in (None, *BANDS):
            m = r["sweep"][band]
            p = "" if band is None else "roi_"
            cells.append(
                f"{m[p + 'surface_rms_mm']:.3f} / {m[p + 'surface_p95_mm']:.3f} / "
                f"{m[p + 'signed_mean_mm' if band is not None else 'surface_signed_mean_mm']:+.3f}"
            )
        lines.append(f"| {r['bone']} | " + " | ".join(cells) + " |")
    return lines


def _per_bone(rows: list[dict]) -> list[str]:
    lines = [
        "| bone | median edge of the mean shape (mm) | vertex RMS: within 5 mm of the cut / "
        "beyond (mm) | vertex-to-surface RMS: within / beyond (mm) | within 5 mm: share of "
        "vertices / of the squared vertex error |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        k = r["distance"] < 5.0
        v, s = r["vertex"], r["surface"]
        lines.append(
            f"| {r['bone']} | {r['edge']:.2f} | {np.sqrt(np.mean(v[k] ** 2)):.3f} / "
            f"{np.sqrt(np.mean(v[~k] ** 2)):.3f} | {np.sqrt(np.mean(s[k] ** 2)):.3f} / "
            f"{np.sqrt(np.mean(s[~k] ** 2)):.3f} | {k.mean():.1%} / "
            f"{np.sum(v[k] ** 2) / np.sum(v**2):.1%} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "cut_band.md"))
    args = parser.parse_args()
    rows = measure()
    text = "\n".join(
        [
            "# How far a template's cut reaches (benchmarks/cut_band.py)",
            "",
            "`python benchmarks/cut_band.py`: every sample case whose template has a cut, "
            "registered (`run_case_dir`, no report); per vertex its distance from the cut "
            "(on the model's mean shape), how its normal turns from the cap's, and its error "
            f"to the ground truth. Bones: {', '.join(r['bone'] for r in rows)}.",
            "",
            "Per vertex (the normals' turn shows where the cap's rim ends; the vertex error "
            "is vertex i against vertex i, which the shaft's lack of features inflates far from "
            "the cut as well):",
            "",
            *_bin_rows(rows),
            "",
            f"Per point sampled on the registered surface ({SURFACE_SAMPLES} per bone, as the "
            "metrics sample it):",
            "",
            *_profile_rows(rows),
            "",
            "The region-of-interest statistics against the band's width "
            "(`surface_metrics(..., region=cut_region(mean shape, faces, band_mm=band))`): "
            "`roi_surface_rms_mm` / `roi_surface_p95_mm` / `roi_signed_mean_mm` (mm); the "
            "whole surface's `surface_rms_mm` / `surface_p95_mm` / `surface_signed_mean_mm`:",
            "",
            *_sweep_rows(rows),
            "",
            *_per_bone(rows),
            "",
            "Detection (`detect_cuts`: a cap passes when its prism ratio is at least "
            "`MIN_PRISM` = 0.9 and its flat fraction at least `MIN_CAP_FRACTION` = 0.4):",
            "",
            *_detection_rows(),
            "",
        ]
    )
    atomic_write_text(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
