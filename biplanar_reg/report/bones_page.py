"""The page of a multi-bone case (``report.html`` at the top of its ``out/``): links to each
bone's own report, the bones' metrics, the non-penetration check, the relative poses and the
views with every bone shaded (figures drawn by the case pipeline)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..result import CaseResult
from .html import data_uri, write_page

__all__ = ["write_bones_report"]

#: The per-bone metrics of the bones table (``bones[name].metrics``), px and mm.
BONE_METRICS = (
    "landmark_rms_px",
    "contour_rms_px",
    "vertex_rms_mm",
    "surface_rms_mm",
    "roi_surface_rms_mm",
    "roi_signed_mean_mm",
)


def _num(value: Any) -> str:
    """A table cell: three significant digits, empty when there is no value."""
    return "" if value is None else f"{value:.3g}"


def _contact_rows(result: CaseResult) -> list[dict[str, str]]:
    """One row per pair of bones and frame: the penetration depth (mm), the vertices inside
    each other and the clearance (mm)."""
    return [
        {
            "pair": f"{p['a']} / {p['b']}",
            "frame": str(f["frame"]),
            "depth": f"{f['depth_mm']:.2f}",
            "inside": f"{f['a_in_b']} / {f['b_in_a']}",
            "clearance": _num(f["clearance_mm"]),
        }
        for p in (result.contact or {}).get("pairs", [])
        for f in p["frames"]
    ]


def _relative_rows(result: CaseResult) -> list[dict[str, str]]:
    """One row per pair of bones and frame: the later bone's pose in the earlier one's model
    frame (translation mm, Cardan angles degrees)."""
    return [
        {
            "pair": f"{r['body']} in {r['reference']}",
            "frame": str(f["frame"]),
            "translation": ", ".join(f"{v:.2f}" for v in f["translation_mm"]),
            "angles": ", ".join(f"{v:.2f}" for v in f["angles_deg"]),
        }
        for r in result.relative or []
        for f in r["frames"]
    ]


def write_bones_report(
    folder: str | os.PathLike, result: CaseResult, figures: Sequence[str] = ()
) -> dict[str, Any]:
    """Write ``report.html`` of the multi-bone case ``result`` into ``folder``.

    Parameters
    ----------
    folder : path
        The case's output folder (its bones' reports under ``bones/<name>/``).
    result : CaseResult
        The case's result (layout "bones").
    figures : sequence of str
        PNG files in ``folder`` (one per view), embedded in the page.

    Returns
    -------
    dict
        ``html``, ``bones`` (the bones' report pages) and ``views`` (``figures``), for
        ``result.json["report"]``.
    """
    folder = Path(folder)
    bones = [
        {
            "name": name,
            "report": b.report,
            "cells": [_num(b.metrics.get(k)) for k in BONE_METRICS],
        }
        for name, b in result.bones.items()
    ]
    write_page(
        folder / "report.html",
        "bones.html",
        case_id=result.id,
        frame=result.coordinate_frame,
        figures=[{"src": f, "data": data_uri(folder / f)} for f in figures],
        metric_keys=BONE_METRICS,
        bones=bones,
        contact=result.contact or {"method": "", "warn_depth_mm": 0.0},
        contact_rows=_contact_rows(result),
        relative_rows=_relative_rows(result),
        flags=result.flags,
        warnings=result.warnings,
    )
    pages = [b.report for b in result.bones.values() if b.report]
    return {"html": "report.html", "bones": pages, "views": list(figures)}
