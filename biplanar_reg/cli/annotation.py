"""``biplanar-reg annotate ...``: contour tracing, landmark snapping, merging and previews."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._parsing import Wanted, add_command, number

if TYPE_CHECKING:
    import numpy as np

__all__ = ["register"]


def recipe_path_for(out: str | os.PathLike[str]) -> Path:
    """The recipe written beside a contour file: ``contour.json`` -> ``contour.recipe.json``."""
    out = Path(out)
    return out.with_name(out.stem + ".recipe.json")


def _relative_to(path: Path, folder: Path) -> str:
    try:
        return os.path.relpath(path.resolve(), folder.resolve())
    except ValueError:  # different drives (Windows): keep the absolute path
        return str(path.resolve())


def _contour_inputs(path: Path) -> dict[str, Any]:
    """Read the anchors file: a list of [u, v] or an object with anchors/box/polygon/zones."""
    from ..io.jsonfile import read_json

    doc = read_json(path)
    if isinstance(doc, list):
        return {"anchors": doc}
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a list of [u, v] anchors or an object")
    allowed = {"anchors", "closed", "box", "polygon", "exclusion_zones"}
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown} (known: {sorted(allowed)})")
    return doc


def _cmd_contour(args: argparse.Namespace) -> int:
    from ..annotation import Annotations, ViewAnnotations, load_image, save_annotations
    from ..annotation.recipe import parse_recipe, run_recipe, save_recipe

    image_path = Path(args.image)
    image = load_image(image_path, args.frame)
    inputs = _contour_inputs(Path(args.anchors)) if args.anchors else {}
    out = Path(args.output)
    rpath = recipe_path_for(out)
    doc: dict[str, Any] = {
        "format": "biplanar-reg/contour-recipe@1",
        "image": _relative_to(image_path, rpath.parent),
        "frame": args.frame,
        "view": args.view or image_path.stem,
        "method": args.method,
        "closed": bool(inputs.get("closed", False) or args.closed),
        "params": {},
        "cleaning": {"spacing_px": args.spacing, "border_px": args.border},
    }
    if "exclusion_zones" in inputs:
        doc["cleaning"]["exclusion_zones"] = inputs["exclusion_zones"]
    if args.method == "livewire":
        if "anchors" not in inputs:
            raise ValueError("--anchors: livewire needs an anchors file (a list of [u, v])")
        doc["anchors"] = inputs["anchors"]
        doc["params"]["sigma_px"] = args.sigma
    else:
        box = args.box if args.box is not None else inputs.get("box")
        if box is not None:
            doc["box"] = list(box)
        if "polygon" in inputs:
            doc["polygon"] = inputs["polygon"]
    source = f"{args.anchors or 'command line'}"
    recipe = parse_recipe(doc, source)
    contours = run_recipe(recipe, image=image)
    if not contours:
        raise ValueError(
            f"{args.image}: the traced contour was cut away entirely (borders/exclusion zones)"
        )
    ann = Annotations({recipe.view: ViewAnnotations(contours=contours)})
    save_recipe(recipe, rpath)
    save_annotations(ann, out)
    n = sum(len(c.uv) for c in contours)
    _report(
        args,
        {"output": str(out), "recipe": str(rpath), "contours": len(contours), "points": n},
        f"{out}: {len(contours)} contour piece(s), {n} points; recipe {rpath}",
    )
    return 0


def _cmd_regenerate(args: argparse.Namespace) -> int:
    from ..annotation import Annotations, ViewAnnotations, load_recipe, run_recipe, save_annotations

    rpath = Path(args.recipe)
    recipe = load_recipe(rpath)
    contours = run_recipe(recipe, base_dir=rpath.parent)
    if not contours:
        raise ValueError(f"{rpath}: the traced contour was cut away entirely")
    ann = Annotations({recipe.view or "view": ViewAnnotations(contours=contours)})
    save_annotations(ann, args.output)
    _report(
        args,
        {"output": str(args.output), "contours": len(contours)},
        f"{args.output}: {len(contours)} contour piece(s) from {rpath}",
    )
    return 0


def _read_points(path: Path) -> dict[str, np.ndarray]:
    """Points file: {"name": [u, v]} or {"name": {"uv": [u, v]}} or an annotation file's view."""
    import numpy as np

    from ..io.jsonfile import read_json

    doc = read_json(path)
    if not isinstance(doc, dict) or not doc:
        raise ValueError(f"{path}: expected an object {{name: [u, v]}}")
    out: dict[str, np.ndarray] = {}
    problems = []
    for name, val in doc.items():
        uv = val.get("uv") if isinstance(val, dict) else val
        try:
            arr = np.asarray(uv, dtype=float)
        except (TypeError, ValueError):
            arr = np.array([np.nan])
        if arr.shape != (2,) or not np.all(np.isfinite(arr)):
            problems.append(f"{name}: expected [u, v] finite numbers, got {uv!r:.60}")
            continue
        out[str(name)] = arr
    if problems:
        raise ValueError(f"{path}: invalid points:\n  " + "\n  ".join(problems))
    return out


def _cmd_snap(args: argparse.Namespace) -> int:
    from ..annotation import (
        Annotations,
        Landmark,
        ViewAnnotations,
        load_image,
        save_annotations,
        snap_landmark,
    )

    image = load_image(args.image, args.frame)
    points = _read_points(Path(args.points))
    results = {
        name: snap_landmark(image, uv, radius_px=args.radius, mode=args.mode)
        for name, uv in points.items()
    }
    view = args.view or Path(args.image).stem
    landmarks = {n: Landmark(r.uv, args.sigma) for n, r in results.items()}
    ann = Annotations({view: ViewAnnotations(landmarks=landmarks)})
    save_annotations(ann, args.output)
    report = {
        n: {"clicked": r.clicked.tolist(), "uv": r.uv.tolist(), "shift_px": r.shift_px}
        for n, r in results.items()
    }
    lines = [
        f"{n}: ({r.clicked[0]:.1f}, {r.clicked[1]:.1f}) -> ({r.uv[0]:.2f}, {r.uv[1]:.2f}), "
        f"shift {r.shift_px:.2f} px"
        for n, r in results.items()
    ]
    _report(args, {"output": str(args.output), "points": report}, "\n".join(lines))
    return 0


def _cmd_merge(args: argparse.Namespace) -> int:
    from ..annotation import load_annotations, merge_annotations, save_annotations

    parts = [load_annotations(p) for p in args.inputs]  # all validated before anything is written
    merged = merge_annotations(parts, overwrite=args.overwrite)
    save_annotations(merged, args.output)
    _report(
        args,
        {"output": str(args.output), "views": sorted(merged.views)},
        f"{args.output}: merged {len(parts)} file(s), views {sorted(merged.views)}",
    )
    return 0


def _cmd_preview(args: argparse.Namespace) -> int:
    # the case format belongs to cases (the one case.toml reader); drawing to annotation
    from ..annotation.preview import preview_annotations
    from ..cases.case import CASE_FILE, read_case_views

    views, annotations_file = read_case_views(args.case_dir)
    if all(image is None for _, image in views):
        raise ValueError(f"{Path(args.case_dir) / CASE_FILE}: no view has an 'image' to preview")
    out = preview_annotations(views, annotations_file, args.output, max_height=args.max_height)
    _report(args, {"output": str(out)}, f"wrote {out}")
    return 0


def _report(args: argparse.Namespace, data: dict[str, Any], text: str) -> None:
    if getattr(args, "json", False):
        print(json.dumps(data))
    else:
        print(text)


def _build_contour(c: argparse.ArgumentParser, wanted: Wanted) -> None:
    c.add_argument("image", help="radiograph (DICOM, TIFF, PNG, JPEG)")
    c.add_argument(
        "--anchors",
        help="JSON: list of [u, v] anchors, or an object with anchors, "
        "closed, box, polygon, exclusion_zones",
    )
    c.add_argument("--method", choices=("livewire", "grabcut"), default="livewire")
    c.add_argument(
        "--box",
        type=number(float),
        nargs=4,
        metavar=("U0", "V0", "U1", "V1"),
        help="grabcut: box around the bone, pixels",
    )
    c.add_argument("--closed", action="store_true", help="livewire: close the outline")
    c.add_argument("--view", help="view name in the output (default: the image's file stem)")
    c.add_argument(
        "--frame", type=number(int, 0, 100_000), default=0, help="frame of a multi-frame image"
    )
    c.add_argument(
        "--sigma",
        type=number(float, 0, 100, above=True),
        default=1.5,
        help="livewire edge scale, px (1.5)",
    )
    c.add_argument(
        "--spacing",
        type=number(float, 0, 1000, above=True),
        default=1.0,
        help="output point spacing, px (1.0)",
    )
    c.add_argument(
        "--border",
        type=number(float, 0, 10_000),
        default=1.0,
        help="cut this close to the border, px",
    )
    c.add_argument(
        "-o",
        "--output",
        required=True,
        help="output annotations JSON; the recipe is written beside it as <stem>.recipe.json",
    )
    c.set_defaults(func=_cmd_contour)


def _build_regenerate(r: argparse.ArgumentParser, wanted: Wanted) -> None:
    r.add_argument("recipe", help="a <stem>.recipe.json written by 'annotate contour'")
    r.add_argument("-o", "--output", required=True, help="output annotations JSON")
    r.set_defaults(func=_cmd_regenerate)


def _build_snap(s: argparse.ArgumentParser, wanted: Wanted) -> None:
    from ..annotation.snap import SNAP_MODES

    s.add_argument("image")
    s.add_argument("--points", required=True, help='JSON {"name": [u, v], ...}')
    s.add_argument(
        "--radius",
        type=number(float, 0, 1000, above=True),
        default=5.0,
        help="search radius, px (5)",
    )
    s.add_argument("--mode", choices=SNAP_MODES, default="corner")
    s.add_argument(
        "--sigma",
        type=number(float, 0, above=True),
        default=1.0,
        metavar="PX",
        help="uncertainty written for the snapped landmarks (their sigma_px), px (1)",
    )
    s.add_argument("--view", help="view name in the output (default: the image's file stem)")
    s.add_argument("--frame", type=number(int, 0, 100_000), default=0)
    s.add_argument("-o", "--output", required=True, help="output annotations JSON")
    s.set_defaults(func=_cmd_snap)


def _build_merge(m: argparse.ArgumentParser, wanted: Wanted) -> None:
    m.add_argument("inputs", nargs="+")
    m.add_argument(
        "--overwrite",
        action="store_true",
        help="a landmark in several files: the later file wins (default: error)",
    )
    m.add_argument("-o", "--output", required=True)
    m.set_defaults(func=_cmd_merge)


def _build_preview(v: argparse.ArgumentParser, wanted: Wanted) -> None:
    v.add_argument("case_dir")
    v.add_argument("-o", "--output", required=True, help="output PNG")
    v.add_argument(
        "--max-height", type=number(int, 16, 20_000), default=900, help="panel height, px (900)"
    )
    v.set_defaults(func=_cmd_preview)


def _build_group(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    sub = p.add_subparsers(dest="annotate_command", metavar="ACTION")
    sub.required = True
    for name, build, help_text in (
        ("contour", _build_contour, "trace a contour (livewire) or segment one (grabcut)"),
        ("regenerate", _build_regenerate, "re-run a contour recipe"),
        ("snap", _build_snap, "refine clicked landmarks to nearby corners/edges"),
        ("merge", _build_merge, "merge annotation files (contours appended)"),
        ("preview", _build_preview, "draw a case's annotations over its images (PNG)"),
    ):
        add_command(sub, name, build, wanted, help=help_text)


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add the ``annotate`` command group (see :mod:`._parsing` for ``wanted``)."""
    add_command(
        subparsers,
        "annotate",
        _build_group,
        wanted,
        help="annotation tools: contours, snapping, merge, preview",
        description="Semi-automatic annotation of radiographs (pixels: u = column, v = row, "
        "0-based, origin at the centre of the top-left pixel).",
    )
