"""Shared helpers of the paper-comparison benchmarks (models, metrics, atomic outputs).

The three volumetric test models stand in for the seed paper's Stanford bunny, Nefertiti and
Spot: each is a template mesh (mm) with a 5-member harmonic-deformation population
(:func:`synthesise_population`, default families) and its 4-mode SSM (:func:`build_ssm`), as the
paper's "5 configurations of freeform deformation".

* ``radius``: the wrist radius of ``sample_cases/wrist_radius`` (CT, 1,002-vertex surface);
* ``box``: a rounded box (superellipsoid 32 x 24 x 18 mm, exponent 0.4), carpal-bone-like;
* ``bent``: a capsule (radius 6 mm, 60 mm long) bent along a 90 degree arc.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from biplanar_reg.io.atomic import atomic_path, atomic_write_text
from biplanar_reg.registration.unknown_poses import similarity_fit
from biplanar_reg.ssm import build_ssm, synthesise_population
from biplanar_reg.ssm.model import ShapeModel

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
RADIUS_CT = REPO / "sample_cases" / "wrist_radius" / "data" / "radius_ct.tif"
RADIUS_VOXEL = (0.39625, 0.39625, 0.625)


# -- templates ------------------------------------------------------------------------------------
def _oriented(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces flipped if needed so the signed volume is positive (outward normals)."""
    tri = verts[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    return verts, (faces[:, ::-1].copy() if vol < 0 else faces)


def box_template() -> tuple[np.ndarray, np.ndarray]:
    """Rounded box: an icosphere (642 vertices) mapped onto a superellipsoid, mm."""
    s = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(s.vertices)
    v = np.sign(v) * np.abs(v) ** 0.4 * np.array([16.0, 12.0, 9.0])
    return _oriented(v, np.asarray(s.faces, dtype=np.int64))


def bent_template() -> tuple[np.ndarray, np.ndarray]:
    """A capsule (radius 6 mm, 60 mm between cap centres) bent along a 90 degree arc, mm."""
    c = trimesh.creation.capsule(height=60.0, radius=6.0, count=[24, 24])
    v = np.asarray(c.vertices)
    v = v - v.mean(axis=0)
    bend = 60.0 / (np.pi / 2)  # arc radius: the axis length spans 90 degrees
    phi = v[:, 2] / bend
    r = bend + v[:, 0]
    out = np.column_stack([r * np.cos(phi) - bend, v[:, 1], r * np.sin(phi)])
    return _oriented(out, np.asarray(c.faces, dtype=np.int64))


def radius_template() -> tuple[np.ndarray, np.ndarray]:
    """The shipped wrist radius CT's surface, decimated to about 1,000 vertices, mm."""
    from biplanar_reg.io import read_volume
    from biplanar_reg.ssm import bone_surface

    surf = bone_surface(read_volume(RADIUS_CT, voxel_size=RADIUS_VOXEL), target_vertices=1000)
    return surf.vertices, surf.faces


TEMPLATES = {"radius": radius_template, "box": box_template, "bent": bent_template}


def volumetric_model(name: str, seed: int = 0) -> ShapeModel:
    """The 4-mode SSM of a 5-member harmonic population of template ``name`` (mm)."""
    verts, faces = TEMPLATES[name]()
    pop = synthesise_population(verts, 5, seed=seed)
    return build_ssm(pop.shapes, faces, n_modes=4)


def volumetric_models(names: list[str] | None = None, seed: int = 0) -> dict[str, ShapeModel]:
    """The test models by name (all three by default)."""
    return {n: volumetric_model(n, seed) for n in (names or list(TEMPLATES))}


def diagonal(model: ShapeModel) -> float:
    """Largest diagonal (bounding box) of the mean shape, mm (the paper quotes this size)."""
    return float(np.linalg.norm(np.ptp(model.mean, axis=0)))


# -- scenes and metrics ---------------------------------------------------------------------------
def paper_pose(rng: np.random.Generator) -> np.ndarray:
    """Rotation with Euler angles (xyz) uniform in [-90, 90] degrees, as in the seed paper."""
    return Rotation.from_euler("xyz", rng.uniform(-90.0, 90.0, 3), degrees=True).as_matrix()


def paper_weights(rng: np.random.Generator, n_modes: int) -> np.ndarray:
    """Shape weights uniform in [0, 1] (standard deviations), as in the seed paper."""
    return rng.uniform(0.0, 1.0, n_modes)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS distance, mm."""
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def rms_rigid(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS after the best rigid alignment of ``a`` onto ``b`` (shape error only), mm."""
    _, R, _ = similarity_fit(a, b)  # the least-squares rotation does not depend on the scale
    return rms((a - a.mean(axis=0)) @ R.T + b.mean(axis=0), b)


def fmt(values: object, digits: int = 2) -> str:
    """``median [q1-q3]`` of finite values (``n/a`` if none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return "n/a"
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return f"{med:.{digits}g} [{q1:.{digits}g}-{q3:.{digits}g}]"


def machine() -> str:
    """One line on where the numbers were measured."""
    return (
        f"{platform.machine()}, {os.cpu_count()} cores shared with other engineers' jobs "
        f"(timings may be affected), Python {platform.python_version()}"
    )


# -- atomic outputs -------------------------------------------------------------------------------
def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (the package's writer, parents created)."""
    atomic_write_text(path, text)


def save_figure(fig: object, path: Path) -> None:
    """Save a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(path, make_parents=True) as tmp:
            fig.savefig(tmp, dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)


def output_paths(stem: str, quick: bool, out_dir: Path | None = None) -> tuple[Path, Path]:
    """``(markdown, png)`` result paths; quick runs get a ``_quick`` suffix so they never
    overwrite the committed full results."""
    d = out_dir or RESULTS
    name = f"{stem}_quick" if quick else stem
    return d / f"{name}.md", d / f"{name}.png"
