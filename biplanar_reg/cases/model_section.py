"""``[model]`` of a case file: a shape model file, or a template with its synthesised population."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..io import read_mesh
from ..io.jsonfile import read_json
from ..ssm import ShapeModel
from ._case_file import (
    _MB_BASE,
    _MB_PER_FACE,
    _SECONDS_PER_FACE,
    MAX_TEMPLATE_FACES,
    MAX_TEMPLATE_VERTICES,
    MODEL_DEFAULTS,
    PLAUSIBLE_EXTENT_MM,
    _Ctx,
    _units_name,
)

__all__ = []


def _read_landmarks(ctx: _Ctx, path: Path, n_vertices: int) -> dict[str, int]:
    where = "[model] landmarks"
    with ctx.reraise(where):
        data = read_json(path)
    if not isinstance(data, dict) or not data:
        raise ctx.error(where, f"{path.name}: expected a non-empty JSON object {{name: index}}")
    out: dict[str, int] = {}
    for name, idx in data.items():
        if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < n_vertices:
            raise ctx.error(
                where,
                f"{path.name}: landmark {name!r}: expected a vertex index in 0..{n_vertices - 1}"
                f", got {idx!r}",
            )
        out[name] = idx
    return out


def _scaled_model(model: ShapeModel, s: float, landmarks: dict[str, int]) -> ShapeModel:
    provenance = dict(model.provenance)
    gp = provenance.get("gaussian_process")
    if isinstance(gp, dict):  # the kernel's lengths are in the model's units too
        scaled = {
            k: gp[k] * s
            for k in ("width_mm", "amplitude_mm")
            if isinstance(gp.get(k), (int, float))
        }
        provenance["gaussian_process"] = {**gp, **scaled}
    return ShapeModel(
        model.mean * s,
        model.modes * s,
        faces=model.faces,
        variances=None if model.variances is None else model.variances * s * s,
        landmarks=landmarks,
        truncation_modes=None if model.truncation_modes is None else model.truncation_modes * s,
        provenance=provenance,
    )


def _load_model(ctx: _Ctx, doc: dict, scale: float) -> tuple[ShapeModel, dict, dict[str, int]]:
    table = ctx.table(doc, "model", required=True)
    ctx.unknown_keys(table, "model", "[model]")
    has_ssm, has_tpl = "ssm" in table, "template" in table
    if has_ssm == has_tpl:
        raise ctx.error("[model]", "give exactly one of 'ssm' and 'template'")
    if has_ssm:
        path = ctx.path(table, "ssm", "[model]")
        with ctx.reraise("[model] ssm"):
            model = ShapeModel.load(path)
        n_faces = 0 if model.faces is None else len(model.faces)
        _check_model_size(ctx, "[model] ssm", path, model.n_vertices, n_faces)
        source: dict[str, Any] = {"ssm": str(path)}
    else:
        model, source = _template_model(ctx, table, scale)
    # the template route built its population from the already scaled template
    scale_model = scale if has_ssm else 1.0
    if model.faces is None:
        ctx.warn("[model]: the model has no faces; silhouettes and surface metrics are limited")
    lm_path = ctx.path(table, "landmarks", "[model]", required=False)
    if lm_path is not None:
        landmarks = _read_landmarks(ctx, lm_path, model.n_vertices)
        source["landmarks"] = str(lm_path)
    elif model.landmarks:
        landmarks = dict(model.landmarks)
    else:
        raise ctx.error("[model] landmarks", "missing (and the model file holds no landmarks)")
    model = _scaled_model(model, scale_model, landmarks)
    ext = float(np.linalg.norm(np.ptp(model.mean, axis=0)))
    lo, hi = PLAUSIBLE_EXTENT_MM
    if not lo <= ext <= hi:
        raise ctx.error(
            "units",
            f"the model is {ext:.4g} mm across after reading it in {_units_name(scale)}; a bone "
            f"should be {lo:g}-{hi:g} mm: the 'units' setting contradicts the files",
        )
    return model, source, landmarks


def _template_model(ctx: _Ctx, table: dict, scale: float) -> tuple[ShapeModel, dict[str, Any]]:
    """``[model] template``: the model built from a population synthesised from the template
    (scaled to mm), and the settings used (the ``source`` record)."""
    path = ctx.path(table, "template", "[model]")
    with ctx.reraise("[model] template"):
        verts, faces = read_mesh(path)
    if faces is None:
        raise ctx.error("[model] template", f"{path.name}: a template needs faces (a mesh)")
    _check_model_size(ctx, "[model] template", path, len(verts), len(faces))
    _check_template_faces(ctx, path, faces)
    faces = _template_surface(ctx, path, verts, faces)
    # imported here: model building (~10 ms to import) is only for the template route
    from ..ssm import build_ssm, synthesise_population
    from ..ssm.population import FAMILIES

    settings = dict(MODEL_DEFAULTS, population_families=list(FAMILIES))
    for key in ("population_size", "population_seed"):
        settings[key] = ctx.bounded(table, key, "[model]", int, settings[key])
    for key in ("population_strength", "ssm_variance"):
        settings[key] = ctx.bounded(table, key, "[model]", float, settings[key])
    fams = table.get("population_families", settings["population_families"])
    if not isinstance(fams, list) or not all(isinstance(f, str) for f in fams):
        raise ctx.error("[model] population_families", f"expected a list of names: {fams!r}")
    settings["population_families"] = fams
    try:
        pop = synthesise_population(
            verts * scale,
            settings["population_size"],
            seed=settings["population_seed"],
            families=fams,
            strength=settings["population_strength"],
        )
        model = build_ssm(pop.shapes, faces=faces, variance=settings["ssm_variance"])
    except ValueError as exc:
        raise ctx.error("[model]", f"building the model from the template: {exc}") from None
    return model, {"template": str(path), **settings}


def _check_template_faces(ctx: _Ctx, path: Path, faces: np.ndarray | None) -> None:
    """Refuse a template with a face that repeats a vertex (a degenerate face).

    Such a face has no normal and no area; in an STL it is also the sign that corners of
    different vertices share one position (STL vertices are merged by position), so the
    vertex count, and every landmark index after the merged vertex, differ from the mesh
    the landmarks were written for.
    """
    if faces is None:
        return
    f = np.asarray(faces)
    bad = np.flatnonzero((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]))
    if bad.size:
        i = int(bad[0])
        merged = " (STL corners at one position are merged into one vertex)"
        raise ctx.error(
            "[model] template",
            f"{path.name}: face {i} is degenerate (vertices {f[i].tolist()}; {bad.size} such "
            f"face(s)){merged if path.suffix.lower() == '.stl' else ''}: a template needs "
            "triangles of three different vertices",
        )


def _check_model_size(ctx: _Ctx, key: str, path: Path, n_vertices: int, n_faces: int) -> None:
    """Refuse a model mesh above :data:`MAX_TEMPLATE_FACES` / :data:`MAX_TEMPLATE_VERTICES`,
    saying what it would cost (the measured cost per face) and what to do."""
    if n_faces <= MAX_TEMPLATE_FACES and n_vertices <= MAX_TEMPLATE_VERTICES:
        return
    faces = max(n_faces, 2 * n_vertices)  # a closed surface has about 2 faces per vertex
    gb = (_MB_BASE + _MB_PER_FACE * faces) / 1024.0
    seconds = _SECONDS_PER_FACE * faces
    took = f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"
    raise ctx.error(
        key,
        f"{path.name}: {n_faces:,} faces ({n_vertices:,} vertices); at most "
        f"{MAX_TEMPLATE_FACES:,} faces ({MAX_TEMPLATE_VERTICES:,} vertices) are registered: "
        f"this one would need about {gb:.1f} GB of memory and {took}, and a finer mesh "
        "registers no more accurately (docs/cases.md): decimate it to a few thousand vertices "
        "('biplanar-reg template from-ct --target-vertices 4000' from the CT, or quadric "
        "decimation in 3D Slicer or MeshLab) and pick its landmark vertices again (decimation "
        "renumbers them)",
    )


def _and_list(values: list[int]) -> str:
    """``"1, 2 and 3"`` (at most 4 values, then ``", ..."``)."""
    text = [f"{v:,}" for v in values[:4]]
    if len(values) > 4:
        return ", ".join(text) + ", ..."
    return text[0] if len(text) == 1 else ", ".join(text[:-1]) + " and " + text[-1]


def _template_surface(ctx: _Ctx, path: Path, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The template's faces, checked and repaired where that is safe (docs/cases.md).

    Measured on the synthetic case (``template`` = its truth mesh with each defect, seeds 0-2):
    duplicated and inward or inconsistently wound faces left the registration unchanged (the
    same vertex RMS to 0.01 mm) but go into ``registered.ply`` and its exports, so they are
    repaired (faces only: vertices and landmark indices stay) with a warning; several pieces
    are carried into ``registered.ply`` and dominate its surface metrics (surface RMS 0.2-27
    mm against 0.12-0.18 mm; 1.8-27 mm with the second piece outside the bone), an error; an
    open surface registers as given (a hole of 5 % of the faces: vertex RMS unchanged; half
    the bone missing: 0.2-0.3 -> 0.3-0.6 mm), a warning.
    """
    from ..ssm.surface import (
        boundary_edge_count,
        component_sizes,
        duplicate_faces,
        nonmanifold_edge_count,
    )

    key, name = "[model] template", path.name
    faces = np.asarray(faces, dtype=np.int64)
    dup = duplicate_faces(faces)
    if dup.size:
        faces = np.delete(faces, dup, axis=0)
        ctx.warn(f"{key}: {name}: {dup.size:,} duplicated faces removed (each triangle kept once)")
    sizes = component_sizes(len(verts), faces)
    if len(sizes) > 1:
        raise ctx.error(
            key,
            f"{name}: {len(sizes)} separate pieces ({_and_list(sizes)} vertices); a template is "
            "one bone's surface: remove the other pieces (another bone, fragments; e.g. "
            "MeshLab's 'Remove Isolated pieces') and check the landmark vertex indices",
        )
    shared = nonmanifold_edge_count(faces)
    if shared:
        ctx.warn(
            f"{key}: {name}: {shared:,} edges are shared by more than two faces; the faces' "
            "winding was not checked"
        )
    else:
        faces = _outward(ctx, key, name, verts, faces)
    rim = boundary_edge_count(faces)
    if rim:
        ctx.warn(
            f"{key}: {name}: the surface is open ({rim:,} boundary edges): it is registered as "
            "given, and what is missing counts as error in the surface metrics: close the "
            "holes if the bone is whole"
        )
    return faces


def _outward(ctx: _Ctx, key: str, name: str, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` wound consistently and outward (a warning says how many were re-wound)."""
    from ..ssm.surface import inward_pieces, orient_consistently

    flip = orient_consistently(faces)
    if flip is None:
        ctx.warn(f"{key}: {name}: the surface has no consistent winding (a Moebius strip?)")
        return faces
    wound = np.where(flip[:, None], faces[:, ::-1], faces)
    flip ^= inward_pieces(verts, wound)
    changed = int(flip.sum())
    if changed == len(faces):
        ctx.warn(f"{key}: {name}: the faces point inward; flipped to point outward")
    elif changed:
        ctx.warn(
            f"{key}: {name}: {changed:,} of {len(faces):,} faces re-wound to point outward like "
            "their neighbours"
        )
    return np.where(flip[:, None], faces[:, ::-1], faces)
