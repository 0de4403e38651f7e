"""Overlay previews: landmarks and contours drawn over each view's radiograph.

``read_case_views`` reads only what a preview needs from ``case.toml`` (the ``[[views]]``
``name``/``image`` keys and ``[annotations] file``); the full case loader lives elsewhere.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ._fileio import atomic_write_bytes
from .annotations import Annotations, ViewAnnotations
from .image import XrayImage, load_image

__all__ = ["draw_overlay", "compose_panels", "read_case_views", "preview_case"]

_CONTOUR_BGR = (40, 40, 230)  # red
_OPEN_END_BGR = (0, 200, 255)  # amber: ends of open contours
_LANDMARK_BGR = (60, 200, 60)  # green


def draw_overlay(image: XrayImage, ann: ViewAnnotations, *, scale: float = 1.0) -> np.ndarray:
    """Draw one view's annotations over its display image.

    Parameters
    ----------
    image : XrayImage
        The view's radiograph.
    ann : ViewAnnotations
        Its landmarks (cross + circle of radius 3 sigma + name) and contours (polylines; the ends
        of open contours marked).
    scale : float
        Output size relative to the image (e.g. 0.5 for a 1760 px radiograph).

    Returns
    -------
    (H', W', 3) uint8 BGR array
    """
    grey = image.display_uint8()
    if scale != 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    out = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    th = max(1, int(round(2 * scale + 0.5)))
    shift = 4  # fixed-point sub-pixel drawing: coordinates x 16

    def fp(uv: np.ndarray) -> np.ndarray:
        # pixel centre (u, v) maps to (u + 0.5) * scale - 0.5 in the resized image
        return np.round(((np.asarray(uv) + 0.5) * scale - 0.5) * (1 << shift)).astype(np.int32)

    for c in ann.contours:
        cv2.polylines(out, [fp(c.uv)], c.closed, _CONTOUR_BGR, th, cv2.LINE_AA, shift)
        if not c.closed:
            for end in (c.uv[0], c.uv[-1]):
                cv2.circle(out, tuple(fp(end)), 3 << shift, _OPEN_END_BGR, th, cv2.LINE_AA, shift)
    font_scale = max(0.4, 0.9 * scale)
    for name, lm in ann.landmarks.items():
        p = fp(lm.uv)
        r = int(max(3 * lm.sigma_px * scale, 4) * (1 << shift))
        cv2.circle(out, tuple(p), r, _LANDMARK_BGR, th, cv2.LINE_AA, shift)
        cv2.drawMarker(out, tuple(p >> shift), _LANDMARK_BGR, cv2.MARKER_CROSS, 10, th)
        org = (int(p[0] >> shift) + 8, int(p[1] >> shift) - 8)
        cv2.putText(out, name, org, cv2.FONT_HERSHEY_SIMPLEX, font_scale, _LANDMARK_BGR, th)
    return out


def compose_panels(panels: list[np.ndarray], titles: list[str]) -> np.ndarray:
    """Place BGR panels side by side (bottom-padded to the tallest) with a title on each."""
    h = max(p.shape[0] for p in panels)
    cols = []
    for p, title in zip(panels, titles, strict=True):
        pad = np.zeros((h - p.shape[0], p.shape[1], 3), np.uint8)
        col = np.vstack([p, pad])
        cv2.putText(col, title, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 0), 2)
        cols.append(col)
        cols.append(np.full((h, 4, 3), 255, np.uint8))
    return np.hstack(cols[:-1])


def read_case_views(
    case_dir: str | os.PathLike[str],
) -> tuple[list[tuple[str, Path | None]], Path]:
    """Minimal reader of ``case.toml``: (view name, image path or None) pairs, annotation file.

    Only ``[[views]] name``/``image`` and ``[annotations] file`` are read. Paths are resolved
    against the case folder.

    Raises
    ------
    ValueError
        Missing/malformed ``case.toml``, a view without a name, no ``[annotations] file``.
    """
    try:
        import tomllib
    except ImportError:  # Python 3.10
        raise ValueError("reading case.toml needs Python >= 3.11 (tomllib)") from None
    case = Path(case_dir)
    path = case / "case.toml"
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: case file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path}: cannot be read ({exc})") from None
    views = doc.get("views")
    if not isinstance(views, list) or not views:
        raise ValueError(f"{path}: [[views]]: expected at least one view table")
    out = []
    for i, v in enumerate(views):
        name = v.get("name") if isinstance(v, dict) else None
        if not isinstance(name, str) or not name:
            raise ValueError(f"{path}: views[{i}].name: expected a non-empty string")
        image = v.get("image")
        if image is not None and not isinstance(image, str):
            raise ValueError(f"{path}: views[{i}] ({name}).image: expected a path string")
        out.append((name, None if image is None else case / image))
    ann = doc.get("annotations", {})
    file = ann.get("file") if isinstance(ann, dict) else None
    if not isinstance(file, str):
        raise ValueError(f"{path}: [annotations] file: expected a path string")
    return out, case / file


def preview_case(
    case_dir: str | os.PathLike[str], out_png: str | os.PathLike[str], *, max_height: int = 900
) -> Path:
    """Write one PNG with every view's image (that has an ``image``) and its annotations.

    Views are drawn side by side, each scaled to at most ``max_height`` pixels high. The
    annotation file is validated against the case's view names and image sizes first.
    """
    from .annotations import load_annotations

    views, ann_path = read_case_views(case_dir)
    images = {name: load_image(p) for name, p in views if p is not None}
    if not images:
        raise ValueError(f"{Path(case_dir) / 'case.toml'}: no view has an 'image' to preview")
    ann: Annotations = load_annotations(
        ann_path,
        known_views={name for name, _ in views},
        image_sizes={n: im.size for n, im in images.items()},
    )
    panels, titles = [], []
    for name, im in images.items():
        va = ann.views.get(name, ViewAnnotations())
        scale = min(1.0, max_height / im.size[1])
        panels.append(draw_overlay(im, va, scale=scale))
        titles.append(f"{name}: {len(va.landmarks)} landmark(s), {len(va.contours)} contour(s)")
    ok, buf = cv2.imencode(".png", compose_panels(panels, titles))
    if not ok:  # pragma: no cover - encoding a uint8 BGR image does not fail
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(out_png, buf.tobytes())
