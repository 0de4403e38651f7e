"""``biplanar-reg template ...``, ``population ...`` and ``ssm ...`` (see docs/ssm.md)."""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import CommandError
from ._parsing import Builder, Wanted, add_command, emit, number
from .ssm_kernel import build_augment

if TYPE_CHECKING:
    from ..ssm.model import ShapeModel

__all__ = ["register"]

log = logging.getLogger(__name__)

#: Affine fraction above which a mode is flagged as affine-like (see :mod:`biplanar_reg.ssm.build`).
AFFINE_WARNING = 0.9


# -- parsers ------------------------------------------------------------------------------------


def _build_from_ct(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    from ..io.meshes import MESH_SUFFIXES

    p.add_argument("volume", help="DICOM series folder, multi-page .tif/.tiff, or .npy (K, J, I)")
    p.add_argument("-o", "--output", required=True, help=f"mesh file ({', '.join(MESH_SUFFIXES)})")
    p.add_argument(
        "--voxel-size",
        nargs=3,
        type=number(float, 0, 1000, above=True),
        metavar=("X", "Y", "Z"),
        help="voxel spacing (column, row, slice) in mm; required for TIFF and NPY",
    )
    p.add_argument(
        "--threshold",
        type=number(float),
        help="bone threshold in the volume's units (default: 300 HU for DICOM CT, Otsu otherwise)",
    )
    p.add_argument(
        "--target-vertices",
        type=number(int, 0, 10_000_000),
        default=4000,
        help="decimate to about this many vertices; 0 keeps all (default 4000)",
    )
    p.add_argument(
        "--smooth-iterations",
        type=number(int, 0, 10_000),
        default=20,
        help="windowed-sinc smoothing iterations, 0 = none (default 20)",
    )
    p.add_argument(
        "--no-slice-fill",
        action="store_true",
        help="fill enclosed holes in 3-D only, not also slice by slice",
    )
    p.add_argument(
        "--series",
        help="SeriesNumber or SeriesInstanceUID to read from a folder with several series",
    )
    p.set_defaults(func=_cmd_from_ct)


def _build_synth(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    from ..io.meshes import MESH_SUFFIXES
    from ..ssm.population import FAMILIES

    p.add_argument("template", help="template mesh or point file")
    p.add_argument("-o", "--output", required=True, help="output folder (created if needed)")
    p.add_argument(
        "--size", type=number(int, 1, 100_000), default=9, help="number of shapes (default 9)"
    )
    p.add_argument(
        "--seed", type=number(int, 0, 2**32 - 1), default=0, help="random seed (default 0)"
    )
    p.add_argument(
        "--families",
        default=",".join(FAMILIES),
        help=f"comma-separated deformation families (default {','.join(FAMILIES)})",
    )
    p.add_argument(
        "--strength",
        type=number(float, 0, 100),
        default=1.0,
        help="multiplier of all deformation magnitudes (default 1)",
    )
    p.add_argument(
        "--format",
        default="ply",
        choices=[s[1:] for s in MESH_SUFFIXES],
        help="output file format (default ply)",
    )
    p.set_defaults(func=_cmd_synth)


def _build_build(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("inputs", nargs="+", help="mesh/point files or folders of them")
    p.add_argument("-o", "--output", required=True, help="model file (.npz)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--modes", type=number(int, 1, 100_000), help="number of modes to keep")
    group.add_argument(
        "--variance",
        type=number(float, 0, 1, above=True),
        default=0.98,
        help="explained-variance fraction to keep (default 0.98)",
    )
    p.add_argument(
        "--align",
        choices=["rigid", "similarity", "none"],
        default="rigid",
        help="generalised Procrustes alignment before PCA (default rigid)",
    )
    p.add_argument("--landmarks", help='JSON file {"name": vertex index}')
    p.add_argument(
        "--correspond",
        action="store_true",
        help="meshes of any vertex count/topology/pose: fit the template to each (docs/ssm.md)",
    )
    p.add_argument(
        "--template", help="with --correspond: template mesh (default: the first input mesh)"
    )
    p.add_argument(
        "--mirror",
        metavar="SPEC",
        help="'auto' (with --correspond: keep each subject or its mirror image, whichever fits "
        "the template better), 'AXIS:FILE[,FILE...]' (mirror those inputs across x/y/z first) "
        "or 'AXIS' (mirror the built model)",
    )
    p.add_argument(
        "--groupwise",
        type=number(int, 0, 20),
        default=0,
        help="with --correspond: extra passes with the evolving mean as template (default 0)",
    )
    p.add_argument(
        "--samples",
        type=number(int, 500, 10_000_000),
        default=20000,
        help="with --correspond: surface samples per mesh (default 20000; at least 2x the "
        "template's vertices are used)",
    )
    p.add_argument(
        "--quality",
        action="store_true",
        help="also write <model>_quality.json and .png (compactness, generalisation, specificity)",
    )
    p.set_defaults(func=_cmd_build)


def _build_info(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("model", help="model file (.npz or statismo .h5)")
    p.set_defaults(func=_cmd_info)


def _build_quality(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("inputs", nargs="+", help="mesh/point files or folders of them")
    p.add_argument("-o", "--output", required=True, help="report file (.json); a .png beside it")
    p.add_argument(
        "--align",
        choices=["rigid", "similarity", "none"],
        default="rigid",
        help="generalised Procrustes alignment before PCA, as in ssm build (default rigid)",
    )
    p.add_argument(
        "--samples",
        type=number(int, 1, 100_000),
        default=100,
        help="random model shapes per mode count for specificity (default 100)",
    )
    p.add_argument(
        "--seed", type=number(int, 0, 2**32 - 1), default=0, help="random seed (default 0)"
    )
    p.set_defaults(func=_cmd_quality)


def _build_export(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("model", help="model file (.npz or .h5)")
    p.add_argument("-o", "--output", required=True, help="statismo file (.h5) or model (.npz)")
    p.add_argument(
        "--precision",
        choices=["float32", "float64"],
        default="float32",
        help="floating-point datasets of a .h5 (default float32, what statismo/scalismo read)",
    )
    p.set_defaults(func=_cmd_export)


def _build_densify(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("model", help="surface model file (.npz)")
    p.add_argument("-o", "--output", required=True, help="dense point model file (.npz)")
    p.add_argument(
        "--points",
        type=number(int, 1, 10_000_000),
        default=20000,
        help="number of interior points (default 20000)",
    )
    p.add_argument(
        "--seed", type=number(int, 0, 2**32 - 1), default=0, help="random seed (default 0)"
    )
    p.set_defaults(func=_cmd_densify)


#: The three groups: (name, help, dest of the chosen sub-command, its sub-commands).
_GROUPS: tuple[tuple[str, str, str, tuple[tuple[str, Builder, str], ...]], ...] = (
    (
        "template",
        "bone templates from CT volumes",
        "template_command",
        (("from-ct", _build_from_ct, "CT volume (DICOM folder, TIFF stack, .npy) -> bone mesh"),),
    ),
    (
        "population",
        "synthetic shape populations",
        "population_command",
        (("synth", _build_synth, "harmonic-deformation population of a template mesh"),),
    ),
    (
        "ssm",
        "statistical shape models",
        "ssm_command",
        (
            ("build", _build_build, "PCA shape model from shapes in correspondence"),
            ("info", _build_info, "modes, variances, compactness and affine fractions"),
            ("quality", _build_quality, "compactness, generalisation, specificity of shapes"),
            ("export", _build_export, "write a model as statismo HDF5 (.h5) or .npz"),
            ("densify", _build_densify, "add interior points that deform barycentrically"),
            ("augment", build_augment, "add a smooth Gaussian-process deformation kernel"),
        ),
    ),
)


def _group_builder(dest: str, commands: tuple[tuple[str, Builder, str], ...]) -> Builder:
    """The builder of one group: a required sub-command among ``commands``."""

    def build(parser: argparse.ArgumentParser, wanted: Wanted) -> None:
        sub = parser.add_subparsers(dest=dest, metavar="COMMAND", required=True)
        for name, build_command, help_text in commands:
            add_command(sub, name, build_command, wanted, help=help_text)

    return build


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add the ``template``, ``population`` and ``ssm`` command groups."""
    for name, help_text, dest, commands in _GROUPS:
        add_command(subparsers, name, _group_builder(dest, commands), wanted, help=help_text)


# -- commands -----------------------------------------------------------------------------------


def _npz_path(path: str) -> Path:
    out = Path(path)
    if out.suffix.lower() != ".npz":
        raise ValueError(f"{out}: the model file must end in .npz")
    return out


def _cmd_from_ct(args: argparse.Namespace) -> int:
    from ..io.meshes import write_mesh
    from ..io.volumes import read_volume
    from ..ssm.template import bone_surface

    t0 = time.perf_counter()
    volume = read_volume(args.volume, voxel_size=args.voxel_size, series=args.series)
    try:
        surface = bone_surface(
            volume,
            threshold=args.threshold,
            target_vertices=args.target_vertices or None,
            smooth_iterations=args.smooth_iterations,
            fill_slices=not args.no_slice_fill,
        )
    except RuntimeError as exc:  # a surface check failed: a failure, not bad input
        raise CommandError(str(exc)) from None
    write_mesh(args.output, surface.vertices, surface.faces)
    seconds = time.perf_counter() - t0
    result = {
        "output": str(args.output),
        "vertices": len(surface.vertices),
        "faces": len(surface.faces),
        "threshold": surface.threshold,
        "threshold_units": volume.units,
        "volume_mm3": surface.volume_mm3,
        "segmented_volume_mm3": surface.segmented_mm3,
        "decimated": surface.decimated,
        "closed": True,
        "components": 1,
        "seconds": seconds,
    }
    lines = [
        f"wrote {args.output}: {len(surface.vertices)} vertices, {len(surface.faces)} faces, "
        "closed, 1 component",
        f"threshold {surface.threshold:.6g} {volume.units}; enclosed volume "
        f"{surface.volume_mm3:.1f} mm^3 (segmentation {surface.segmented_mm3:.1f} mm^3); "
        f"{seconds:.2f} s",
    ]
    emit(args, result, lines)
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    import numpy as np

    from ..io.atomic import atomic_write_text
    from ..io.meshes import check_manifold, read_mesh, write_mesh
    from ..ssm.population import synthesise_population

    t0 = time.perf_counter()
    vertices, faces = read_mesh(args.template)
    if faces is not None:
        check_manifold(faces, name=str(args.template))
    if faces is None and args.format == "stl":
        raise ValueError(f"{args.template}: a point template cannot be written as STL")
    if faces is not None and args.format in ("csv", "npy"):
        raise ValueError(f"--format {args.format}: stores points only; the template has faces")
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    pop = synthesise_population(
        vertices, args.size, seed=args.seed, families=families, strength=args.strength
    )
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder (-o takes an output folder)")
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for i, shape in enumerate(pop.shapes):
        name = f"shape_{i:03d}.{args.format}"
        write_mesh(out / name, shape, faces)
        names.append(name)
    rms = np.sqrt(np.mean(np.sum((pop.shapes - vertices) ** 2, axis=2), axis=1))
    manifest = {
        "format": "biplanar-reg/population@1",
        "template": str(args.template),
        "size": args.size,
        "seed": args.seed,
        "families": families,
        "strength": args.strength,
        "cage_divisions": pop.cage.divisions.tolist(),
        "cage_vertices": len(pop.cage.lattice),
        "shapes": [
            {"file": n, "rms_from_template_mm": float(r), "parameters": p}
            for n, r, p in zip(names, rms, pop.parameters, strict=True)
        ],
    }
    atomic_write_text(out / "population.json", json.dumps(manifest, indent=2))
    seconds = time.perf_counter() - t0
    result = {
        "output": str(out),
        "files": names,
        "seconds": seconds,
        "rms_from_template_mm": rms.tolist(),
    }
    lines = [
        f"wrote {len(names)} shapes ({len(vertices)} vertices each) and population.json to {out}",
        f"RMS distance from the template: {rms.min():.2f} .. {rms.max():.2f} mm; {seconds:.2f} s",
    ]
    emit(args, result, lines)
    return 0


def _mode_report(model: ShapeModel) -> tuple[list[dict], list[str]]:
    import numpy as np

    from ..ssm.build import affine_fractions, explained_fractions

    frac = explained_fractions(model)
    aff = affine_fractions(model)
    rows = []
    lines = ["mode  variance_mm2  rms_1sd_mm  explained  cumulative  affine_fraction"]
    cumulative = 0.0
    for i in range(model.n_modes):
        cumulative += frac[i]
        var = float(model.variances[i]) if model.variances is not None else float("nan")
        # Per-vertex RMS displacement of a +1 SD step along the mode: a size people can read.
        rms = float(np.sqrt(np.mean(np.sum(model.modes[i] ** 2, axis=1))))
        rows.append(
            {
                "mode": i,
                "variance_mm2": var,
                "rms_1sd_mm": rms,
                "explained": float(frac[i]),
                "affine_fraction": float(aff[i]),
            }
        )
        flag = "  affine-like" if aff[i] > AFFINE_WARNING else ""
        lines.append(
            f"{i:4d}  {var:12.4g}  {rms:10.3f}  {frac[i]:9.3f}  {cumulative:10.3f}  "
            f"{aff[i]:15.3f}{flag}"
        )
    if np.any(aff > AFFINE_WARNING):
        lines.append(
            f"note: modes with affine fraction > {AFFINE_WARNING} are near scaling/shear maps of "
            "the mean; the convex relaxation may not be tight (rounding + local refinement needed)"
        )
    return rows, lines


def _parse_mirror(spec: str | None, correspond: bool) -> tuple[str | None, str, list[str]]:
    """``--mirror`` -> (mode, axis, files) of :func:`biplanar_reg.ssm.build_model_from_files`."""
    from ..ssm.mirror import AXES

    if spec is None:
        return None, "x", []
    if spec == "auto":
        if not correspond:
            raise ValueError("--mirror auto: needs --correspond")
        return "auto", "x", []
    axis, _, names = spec.partition(":")
    if axis not in AXES:
        raise ValueError(
            f"--mirror {spec}: expected 'auto', 'AXIS' or 'AXIS:FILE[,FILE...]' with AXIS one "
            f"of {', '.join(AXES)}"
        )
    files = [n for n in names.split(",") if n]
    if _ and not files:
        raise ValueError(f"--mirror {spec}: no file names after '{axis}:'")
    if files and not correspond:
        raise ValueError(f"--mirror {spec}: mirroring input files needs --correspond")
    return ("files" if files else "model"), axis, files


def _residual_table(provenance: dict) -> list[str]:
    corr = provenance.get("correspondence")
    if not corr:
        return []
    mirrored = set(provenance.get("mirrored_subjects", []))
    lines = ["subject  residual_mean_mm  residual_max_mm  converged  mirrored  file"]
    rows = zip(
        corr["subjects"],
        corr["residual_mean_mm"],
        corr["residual_max_mm"],
        corr["converged"],
        strict=True,
    )
    for i, (name, mean, mx, ok) in enumerate(rows):
        lines.append(
            f"{i:7d}  {mean:16.3f}  {mx:15.3f}  {'yes' if ok else 'NO':>9}  "
            f"{'yes' if name in mirrored else 'no':>8}  {name}"
        )
    bad = [n for n, ok in zip(corr["subjects"], corr["converged"], strict=True) if not ok]
    if bad:
        lines.append(
            f"warning: {len(bad)} subject(s) did not converge (check them): {', '.join(bad)}"
        )
    return lines


def _cmd_build(args: argparse.Namespace) -> int:
    import sys

    from ..ssm.from_files import build_model_from_files

    out = _npz_path(args.output)
    mode, axis, mirror_files = _parse_mirror(args.mirror, args.correspond)
    if (args.template or args.groupwise) and not args.correspond:
        raise ValueError("--template/--groupwise: need --correspond")
    built = build_model_from_files(
        args.inputs,
        correspond=args.correspond,
        template=args.template,
        mirror=mode,
        mirror_axis=axis,
        mirror_files=mirror_files,
        groupwise=args.groupwise,
        samples=args.samples,
        n_modes=args.modes,
        variance=args.variance,
        align=args.align,
        landmarks=args.landmarks,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
    )
    model, files, provenance = built.model, built.files, built.provenance
    if args.quality and len(files) < 3:  # before anything is written
        raise ValueError(
            f"--quality: the quality measures need at least 3 shapes, got {len(files)}"
        )
    model.save(out)
    quality = None
    if args.quality:
        quality = _quality_report(
            built.shapes, args.align, out.with_name(out.stem + "_quality.json")
        )
    rows, lines = _mode_report(model)
    lines = [*_residual_table(provenance), *lines]
    header = (
        f"wrote {out}: {model.n_vertices} vertices, {model.n_modes} modes from {len(files)} "
        f"shapes ({'mesh' if model.faces is not None else 'points'}, align {args.align})"
    )
    result = {
        "output": str(out),
        "shapes": [str(f) for f in files],
        "n_vertices": model.n_vertices,
        "modes": rows,
    }
    if quality is not None:
        result["quality"] = quality
        lines.extend(_quality_lines(quality))
    emit(args, result, [header, *lines])
    return 0


#: What ``ssm info`` cannot compute from a model file, and where to get it.
_NEEDS_TRAINING = (
    "generalisation and specificity need the training shapes: `ssm quality INPUTS...` or "
    "`ssm build ... --quality` (writes <model>_quality.json)"
)


def _model_quality(model: ShapeModel, path: Path) -> dict:
    """The quality measures computable from a model file (compactness), plus the build's
    report ``<model>_quality.json`` beside it, if there is one."""
    from ..io.jsonfile import read_json
    from ..ssm.gaussian_process import split_modes
    from ..ssm.quality import compactness, recommended_modes

    out: dict = {
        "needs_training_set": ["generalisation_mm", "specificity_mm"],
        "note": _NEEDS_TRAINING,
    }
    spectrum = model.population_variances
    gp = split_modes(model)  # an augmented model's kernel modes are not the training set's
    n_pca = min(
        model.n_modes if gp is None else gp.ssm_modes, 0 if spectrum is None else len(spectrum)
    )
    if spectrum is not None and spectrum.sum() > 0:
        comp = compactness(spectrum)
        out.update(
            total_variance_mm2=float(spectrum.sum()),
            compactness={"k_from": 1, "values": comp.tolist()},
            kept_fraction=float(comp[n_pca - 1]) if n_pca else 0.0,
            recommended_modes_by_compactness=recommended_modes(comp),
        )
    else:
        out["compactness"] = None
        out["note"] += "; compactness needs the variance of all modes, not stored in this file"
    report = path.with_name(path.stem + "_quality.json")
    if report.is_file():
        out["build_report"] = str(report)
        out["build_report_data"] = read_json(report)
    return out


def _cmd_info(args: argparse.Namespace) -> int:
    from ..ssm.model import ShapeModel

    path = Path(args.model)
    model = ShapeModel.load(path)
    rows, lines = _mode_report(model)
    quality = _model_quality(model, path)
    header = f"{args.model}: {model!r}, size (RMS radius) {model.size:.2f} mm"
    if quality["compactness"] is not None:
        lines.append(
            f"kept modes explain {quality['kept_fraction']:.2%} of the training set's total "
            f"variance {quality['total_variance_mm2']:.4g} mm^2; 95 % compactness at "
            f"k = {quality['recommended_modes_by_compactness']}"
        )
    else:
        lines.append("explained: share of the kept variance (the total is not in this file)")
    gp = model.provenance.get("gaussian_process")
    if isinstance(gp, dict):
        lines.append(
            f"modes {gp.get('ssm_modes', 0) + 1}-{model.n_modes}: a {gp.get('kernel')} "
            f"deformation kernel (width {gp.get('width_mm')} mm, amplitude "
            f"{gp.get('amplitude_mm')} mm), not learned from shapes"
        )
    report = quality.get("build_report_data")
    if isinstance(report, dict) and "recommended_modes" in report:
        lines.append(
            f"build's report {quality['build_report']}: recommended modes "
            f"{report['recommended_modes']} (generalisation and specificity there)"
        )
    else:
        lines.append(f"note: {_NEEDS_TRAINING}")
    emit(
        args,
        {
            "model": str(args.model),
            "n_vertices": model.n_vertices,
            "modes": rows,
            "provenance": model.provenance,
            "quality": quality,
        },
        [header, *lines],
    )
    return 0


def _quality_report(
    shapes: object, align: str, json_path: Path, samples: int = 100, seed: int = 0
) -> dict:
    """Compute the three measures, write ``json_path`` and the PNG beside it; the dict."""
    from ..io.atomic import atomic_write_json
    from ..ssm.quality import model_quality, plot_quality

    quality = model_quality(shapes, align=align, n_samples=samples, seed=seed)
    png = json_path.with_suffix(".png")
    plot_quality(quality, png, title=json_path.stem)
    result = {"report": str(json_path), "plot": str(png), **quality.to_dict()}
    atomic_write_json(json_path, result)
    return result


def _quality_lines(q: dict) -> list[str]:
    comp, gen, spec = (
        q[k]["values"] for k in ("compactness", "generalisation_mm", "specificity_mm")
    )
    lines = ["k  compactness  generalisation_mm  specificity_mm"]
    for k in range(len(spec)):
        c = f"{comp[k - 1]:11.4f}" if k >= 1 else " " * 11
        g = f"{gen[k]:17.3f}" if k < len(gen) else " " * 17
        lines.append(f"{k:2d}  {c}  {g}  {spec[k]:14.3f}")
    lines.append(
        f"recommended modes: {q['recommended_modes']} ({q['rule']}); "
        f"wrote {q['report']} and {q['plot']}"
    )
    return lines


def _cmd_quality(args: argparse.Namespace) -> int:
    from ..ssm.inputs import read_shapes

    out = Path(args.output)
    if out.suffix.lower() != ".json":
        raise ValueError(f"{out}: the quality report must end in .json")
    shapes, _, files = read_shapes(args.inputs)
    if len(files) < 3:
        raise ValueError(
            f"{files[-1]}: the quality measures need at least 3 shapes, got {len(files)}"
        )
    quality = _quality_report(shapes, args.align, out, samples=args.samples, seed=args.seed)
    quality["shapes"] = [str(f) for f in files]
    emit(args, quality, _quality_lines(quality))
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from ..ssm.model import ShapeModel
    from ..ssm.statismo import write_statismo

    out = Path(args.output)
    if out.suffix.lower() not in (".h5", ".hdf5", ".npz"):
        raise ValueError(f"{out}: the output must end in .h5, .hdf5 (statismo) or .npz")
    model = ShapeModel.load(args.model)
    if out.suffix.lower() == ".npz":
        model.save(out)
    else:
        try:
            write_statismo(model, out, dtype=args.precision)
        except ValueError as exc:
            raise ValueError(f"{args.model}: {exc}") from None
    emit(
        args,
        {"output": str(out), "n_vertices": model.n_vertices, "n_modes": model.n_modes},
        [f"wrote {out}: {model.n_vertices} vertices, {model.n_modes} modes"],
    )
    return 0


def _cmd_densify(args: argparse.Namespace) -> int:
    from ..ssm.dense import densify
    from ..ssm.model import ShapeModel

    out = _npz_path(args.output)
    model = ShapeModel.load(args.model)
    try:
        dense, _ = densify(model, args.points, seed=args.seed)
    except ValueError as exc:
        raise ValueError(f"{args.model}: {exc}") from None
    dense.save(out)
    emit(
        args,
        {"output": str(out), "n_points": dense.n_vertices},
        [
            f"wrote {out}: {dense.n_vertices} points ({model.n_vertices} surface + "
            f"{dense.n_vertices - model.n_vertices} interior), {dense.n_modes} modes"
        ],
    )
    return 0
