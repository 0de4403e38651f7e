"""Shared helpers of the benchmarks (models, scenes, metrics, command lines, atomic outputs).

The three volumetric test models stand in for the seed paper's Stanford bunny, Nefertiti and
Spot: each is a template mesh (mm) with a 5-member harmonic-deformation population
(:func:`synthesise_population`, default families) and its 4-mode SSM (:func:`build_ssm`), as the
paper's "5 configurations of freeform deformation".

* ``radius``: the wrist radius of ``sample_cases/wrist_radius`` (CT, 1,002-vertex surface);
* ``box``: a rounded box (superellipsoid 32 x 24 x 18 mm, exponent 0.4), carpal-bone-like;
* ``bent``: a capsule (radius 6 mm, 60 mm long) bent along a 90 degree arc.

The wrist radius CT, its voxel size and the template/model recipes are those of the sample cases
(``sample_cases/reference.py``), not restated here.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from biplanar_reg.io.atomic import atomic_path, atomic_write_text
from biplanar_reg.pose import Pose
from biplanar_reg.simulate import look_at_view
from biplanar_reg.ssm import build_ssm, synthesise_population
from biplanar_reg.ssm.model import ShapeModel

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
sys.path.insert(0, str(REPO / "sample_cases"))  # reference.py: the sample cases' building blocks
import reference  # noqa: E402


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
    return reference.radius_template(1000)


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


def paper_instance(model: ShapeModel, rng: np.random.Generator) -> np.ndarray:
    """The seed paper's random truth: :func:`paper_pose` (drawn first), then
    :func:`paper_weights`; the instance centred on the mean shape's centroid and rotated,
    (N, 3) world frame, mm."""
    R = paper_pose(rng)
    return (model.instance(paper_weights(rng, model.n_modes)) - model.mean.mean(axis=0)) @ R.T


def random_view(
    rng: np.random.Generator, distance: float, target: np.ndarray | None = None
) -> object:
    """A perspective view (source-detector 1200 mm, 0.3 mm pixels) looking at ``target``
    (default the origin, mm) from a random direction, ``distance`` mm +- 20 % away.

    Draws the direction (3 normals), then the distance factor (one uniform)."""
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    up = (0.0, 0.0, 1.0) if abs(d[2]) < 0.9 else (1.0, 0.0, 0.0)
    source = distance * rng.uniform(0.8, 1.2) * d
    if target is not None:
        source = target + source
    return look_at_view(source, target, sdd=1200.0, pixel=0.3, up=up)


def random_views(n: int, rng: np.random.Generator) -> list:
    """``n`` views of :func:`random_view` looking at the origin from 1000 mm +- 20 %."""
    return [random_view(rng, 1000.0) for _ in range(n)]


def ray_scene(
    model: ShapeModel, counts: list[int], noise_px: float, rng: np.random.Generator
) -> tuple[np.ndarray, list[tuple]]:
    """A :func:`paper_instance` seen by ``len(counts)`` :func:`random_views`.

    View ``i`` observes ``counts[i]`` distinct random vertices with Gaussian pixel noise of
    ``noise_px`` px (both coordinates). Returns the truth (N, 3) and per view
    ``(ids, origins, directions, camera)`` (world frame rays, mm).
    """
    X = paper_instance(model, rng)
    out = []
    for cam, k in zip(random_views(len(counts), rng), counts, strict=True):
        ids = rng.choice(model.n_vertices, k, replace=False)
        o, d = cam.rays(cam.project(X[ids]) + rng.normal(scale=noise_px, size=(k, 2)))
        out.append((ids, o, d, cam))
    return X, out


def stacked(views: list[tuple]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All views' ``(ids, origins, directions)`` of :func:`ray_scene` in one set."""
    return tuple(np.concatenate([v[i] for v in views]) for i in range(3))


def sdp_vertices(model: ShapeModel, res: object) -> np.ndarray:
    """Posed vertices (N, 3) of a ``GsftResult``'s rounded SDP solution (before refinement)."""
    return model.instance(res.sdp_weights) @ res.sdp_rotation.T + res.sdp_translation


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS distance, mm."""
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def rms_rigid(a: np.ndarray, b: np.ndarray) -> float:
    """Vertex RMS after the best rigid alignment of ``a`` onto ``b`` (shape error only), mm."""
    return rms(Pose.fit_rigid(a, b).apply(a), b)


def fmt(values: object, digits: int = 2) -> str:
    """``median [q1-q3]`` of finite values (``n/a`` if none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return "n/a"
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return f"{med:.{digits}g} [{q1:.{digits}g}-{q3:.{digits}g}]"


def model_sizes(models: dict[str, ShapeModel]) -> str:
    """``name diagonal mm`` of each model, comma-separated (the results' model line)."""
    return ", ".join(f"{n} {diagonal(m):.1f} mm" for n, m in models.items())


def machine() -> str:
    """One line on where the numbers were measured."""
    return (
        f"{platform.machine()}, {os.cpu_count()} cores shared with other engineers' jobs "
        f"(timings may be affected), Python {platform.python_version()}"
    )


# -- command lines --------------------------------------------------------------------------------
def paper_arguments(
    doc: str,
    quick_help: str,
    repeats: int,
    repeats_help: str | None = None,
    more: Iterable[tuple[str, dict]] = (),
) -> argparse.Namespace:
    """The paper benchmarks' command line: ``--quick``, ``--repeats``, the options in ``more``
    (``(flag, add_argument keywords)``), then ``--seed`` (default 0) and ``--out-dir``."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=quick_help)
    ap.add_argument("--repeats", type=int, default=repeats, help=repeats_help)
    for flag, kwargs in more:
        ap.add_argument(flag, **kwargs)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out-dir", type=Path, default=None)
    return ap.parse_args()


def command(stem: str, quick: bool, full_options: str) -> str:
    """The command that reproduces a run: ``--quick``, or the full run's ``full_options``."""
    return f"python benchmarks/{stem}.py" + (" --quick" if quick else full_options)


def header(title: str, cmd: str, total: float) -> list[str]:
    """The first lines of a results file: title, command, machine and run time (s)."""
    return [
        f"# {title}",
        "",
        f"Command: `{cmd}`  ",
        f"Machine: {machine()}; total run time {total:.0f} s.",
        "",
    ]


# -- atomic outputs -------------------------------------------------------------------------------
def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (the package's writer, parents created)."""
    atomic_write_text(path, text)


def write_optional(path: Path | None, text: str) -> None:
    """:func:`write_text` when an output path was given (``--out``), else nothing."""
    if path:
        write_text(path, text)


def pyplot() -> object:
    """``matplotlib.pyplot`` on the Agg backend (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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


def write_results(
    stem: str, args: argparse.Namespace, text: str, draw: Callable[[Path], None], total: float
) -> None:
    """Write the markdown ``text`` and ``draw`` the figure into the :func:`output_paths` of
    ``stem`` (``args.quick``, ``args.out_dir``); say where and the run time (s)."""
    md, png = output_paths(stem, args.quick, args.out_dir)
    write_text(md, text)
    draw(png)
    print(f"wrote {md} and {png} ({total:.0f} s)")
