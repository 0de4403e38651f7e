"""``biplanar-reg calibration ...``: convert, show, from-phantom."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._parsing import Wanted, add_command, number

if TYPE_CHECKING:
    import numpy as np

    from ..calibration.views import View

__all__ = ["register"]


def _add_read_options(p: argparse.ArgumentParser) -> None:
    from ..calibration.io import FORMATS

    p.add_argument(
        "--from",
        dest="from_format",
        choices=FORMATS,
        help="input format (default: detected from the content)",
    )
    p.add_argument(
        "--dlt-column",
        type=number(int, 1, 10_000),
        default=None,
        help="camera column (1-based) of a merged XROMM DLT csv",
    )
    p.add_argument(
        "--image-size",
        type=number(int, 1, 100_000),
        nargs=2,
        metavar=("W", "H"),
        default=None,
        help="image size in pixels (required for DLT input)",
    )


def _load(args: argparse.Namespace, path: str) -> View:
    from ..calibration.io import load_calibration

    return load_calibration(
        path,
        args.from_format,
        dlt_column=args.dlt_column,
        image_size=args.image_size,
        name=Path(path).stem,
    )


def _format_from_suffix(path: str) -> str:
    return "json" if Path(path).suffix.lower() == ".json" else "mayacam2"


def _cmd_convert(args: argparse.Namespace) -> int:
    from ..calibration.io import save_calibration

    view = _load(args, args.input)
    save_calibration(view, args.output, args.to)
    print(f"wrote {args.output} ({args.to})")
    return 0


def _fmt_matrix(m: object) -> str:
    import numpy as np

    return "\n".join("    " + "  ".join(f"{x:14.6f}" for x in row) for row in np.asarray(m))


def _cmd_show(args: argparse.Namespace) -> int:
    from ..calibration.geometry import describe_view, principal_rays_distance, view_angle_deg

    views = [_load(args, f) for f in args.files]
    info: dict[str, object] = {"views": [describe_view(v) for v in views]}
    if len(views) == 2:
        dist, mid = principal_rays_distance(*views)
        info["pair"] = {
            "angle_deg": view_angle_deg(*views),
            "principal_rays_distance_mm": dist,
            "principal_rays_midpoint_mm": mid.tolist(),
        }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    for path, d in zip(args.files, info["views"], strict=True):
        print(f"{path}: {d['kind']} view, image size {d['image_size']}")
        if "K" in d:
            print("  K (pixels):\n" + _fmt_matrix(d["K"]))
        if d.get("distortion"):
            print(
                "  distortion (k1 k2 p1 p2 k3 k4 k5 k6): "
                + " ".join(f"{x:.6g}" for x in d["distortion"])
            )
        if "fu" in d:
            print(
                f"  fu={d['fu']:.6f} px  cu={d['cu']:.3f}  cv={d['cv']:.3f}  "
                f"row pitch={d['row_pitch_mm']:.6f} mm"
            )
        print("  R (world -> camera):\n" + _fmt_matrix(d["R"]))
        print("  t (mm): " + "  ".join(f"{x:.6f}" for x in d["t"]))
        if "source" in d:
            print(
                "  source position (mm): "
                + "  ".join(f"{x:.3f}" for x in d["source"])
                + f"   ({d['source_distance_mm']:.1f} mm from the world origin)"
            )
        print("  principal ray (unit, world): " + "  ".join(f"{x:.6f}" for x in d["principal_ray"]))
    if "pair" in info:
        p = info["pair"]
        print(
            f"angle between the principal rays: {p['angle_deg']:.3f} deg; closest approach "
            f"{p['principal_rays_distance_mm']:.2f} mm near ("
            + ", ".join(f"{x:.1f}" for x in p["principal_rays_midpoint_mm"])
            + ") mm"
        )
    return 0


def _read_image(path: str) -> np.ndarray:
    import numpy as np

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such image")
    if p.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        try:
            img = tifffile.imread(p)
        except Exception as exc:  # tifffile raises several types for bad files
            raise ValueError(f"{p}: cannot read TIFF ({exc})") from None
    else:
        import cv2

        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{p}: cannot read the image")
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[-1] not in (3, 4):
        img = img[0]  # multi-page: first page
    return img


def _cmd_from_phantom(args: argparse.Namespace) -> int:
    from ..calibration.io import save_calibration
    from ..calibration.phantom import calibrate_phantom, read_beads_csv, read_seeds_json
    from ..io.atomic import atomic_write_text

    image = _read_image(args.image)
    labels, xyz = read_beads_csv(args.beads)
    seed_idx, seed_uv = read_seeds_json(args.seed, labels)
    res = calibrate_phantom(
        image,
        xyz,
        seed_idx,
        seed_uv,
        labels=labels,
        dark=not args.bright,
        max_radius_px=args.max_radius,
        n_distortion=args.distortion,
        name=args.name or Path(args.image).stem,
    )
    fmt = args.to or _format_from_suffix(args.output)
    save_calibration(res.view, args.output, fmt)
    report = res.report()
    if args.report:
        atomic_write_text(args.report, json.dumps(report, indent=2) + "\n")
    if args.json:
        print(json.dumps({"output": args.output, "format": fmt, **report}, indent=2))
    else:
        print(
            f"{res.n_detected} beads detected, {len(res.bead_index)} matched; reprojection "
            f"RMS {res.rms_px:.4f} px (max {res.residuals_px.max():.4f} px)"
        )
        for b in report["beads"]:
            print(
                f"  bead {b['label']}: ({b['uv'][0]:.2f}, {b['uv'][1]:.2f}) px, residual "
                f"{b['residual_px']:.4f} px"
            )
        print(f"wrote {args.output} ({fmt})")
    return 0


def _build_convert(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    from ..calibration.io import WRITABLE_FORMATS

    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--to", required=True, choices=WRITABLE_FORMATS, help="output format")
    _add_read_options(p)
    p.set_defaults(func=_cmd_convert)


def _build_show(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help="one or two calibration files")
    _add_read_options(p)
    p.set_defaults(func=_cmd_show)


def _build_from_phantom(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    from ..calibration.io import WRITABLE_FORMATS

    p.add_argument("image", help="the phantom radiograph (TIFF, PNG, ...)")
    p.add_argument("beads", help="CSV of bead coordinates in mm: x,y,z or label,x,y,z")
    p.add_argument(
        "--seed",
        required=True,
        help='JSON {"bead label": [u, v], ...} with >= 4 seed correspondences',
    )
    p.add_argument("-o", "--output", required=True, help="calibration file to write")
    p.add_argument(
        "--to",
        choices=WRITABLE_FORMATS,
        default=None,
        help="output format (default: json for .json, else mayacam2)",
    )
    p.add_argument("--bright", action="store_true", help="beads are brighter than background")
    p.add_argument(
        "--max-radius",
        type=number(float, 0, 10_000, above=True),
        default=15.0,
        help="largest bead radius, px",
    )
    p.add_argument(
        "--distortion",
        type=int,
        default=0,
        choices=(0, 2, 4, 5, 8),
        help="number of OpenCV distortion coefficients to estimate (default 0)",
    )
    p.add_argument("--report", default=None, help="write the per-bead residuals (JSON) here")
    p.add_argument("--name", default="", help="view name (default: the image's stem)")
    p.set_defaults(func=_cmd_from_phantom)


def _build_group(grp: argparse.ArgumentParser, wanted: Wanted) -> None:
    sub = grp.add_subparsers(dest="calibration_command", metavar="SUBCOMMAND")
    grp.set_defaults(func=lambda a: (grp.print_help(), 0)[1])
    add_command(
        sub, "convert", _build_convert, wanted, help="convert a calibration file to another format"
    )
    add_command(
        sub,
        "show",
        _build_show,
        wanted,
        help="print K, pose, source position and principal ray (and the angle between two views)",
    )
    add_command(
        sub,
        "from-phantom",
        _build_from_phantom,
        wanted,
        help="calibrate a view from a bead-phantom radiograph",
    )


def register(subparsers: Any, wanted: Wanted = None) -> None:
    """Add the ``calibration`` command group (see :mod:`._parsing` for ``wanted``)."""
    add_command(
        subparsers,
        "calibration",
        _build_group,
        wanted,
        help="read, convert and estimate X-ray view calibrations",
    )
