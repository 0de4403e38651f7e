"""The previous result of a case as the start of its re-registration (``run_case_dir(...,
warm=True)``, what the workbench's Register does after an edit).

:func:`previous_fit` reads ``result.json`` and ``registered.ply`` of an output folder into a
:class:`biplanar_reg.registration.previous.PreviousFit`; the registration decides whether it
may start from it (same model, views and options by the fingerprint ``result.json`` records
under ``restart``; no landmark moved far) and records in ``result.json["restart"]`` which start
it used and why.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..io import read_json, read_mesh
from ..registration.previous import PreviousFit

__all__ = ["previous_fit"]

#: ``result.json["restart"]["reason"]`` when a warm start was asked for without a previous result.
NO_PREVIOUS = "no previous result to start from"


def _noise(doc: dict[str, Any]) -> tuple:
    """``(kind, view, sigma_px, spacing_px)`` of each group of ``result.json["noise"]``."""
    groups = (doc.get("noise") or {}).get("groups") or []
    return tuple(
        (str(g["kind"]), str(g["view"]), float(g["sigma_px"]), float(g.get("correlation_px", 1)))
        for g in groups
        if isinstance(g, dict) and g.get("sigma_px") is not None
    )


def _gp_amplitude(doc: dict[str, Any]) -> float | None:
    gp = doc.get("gaussian_process") or {}
    return float(gp["amplitude_mm"]) if gp.get("used") and gp.get("amplitude_mm") else None


def previous_fit(folder: Path) -> PreviousFit | None:
    """The fit recorded in ``folder`` (``result.json``, ``registered.ply``), or None when there
    is none a registration could start from: no or an unreadable result, a multi-frame or
    multi-bone result (no single pose), one written without a ``restart`` record."""
    try:
        doc = read_json(Path(folder) / "result.json")
        restart = doc.get("restart") or {}
        fingerprint = restart.get("fingerprint")
        if not fingerprint or "rotation" not in doc or "frames" in doc:
            return None
        vertices, _ = read_mesh(Path(folder) / "registered.ply")
        cost = restart.get("robust_cost")
        return PreviousFit(
            rotation=np.asarray(doc["rotation"], float),
            translation=np.asarray(doc["translation"], float),
            weights=np.asarray(doc["weights"], float),
            fingerprint=str(fingerprint),
            vertices=np.asarray(vertices, float),
            gp_amplitude_mm=_gp_amplitude(doc),
            noise=_noise(doc),
            landmark_errors_px={
                str(v): dict(e.get("landmark_errors_px") or {})
                for v, e in (doc.get("views") or {}).items()
            },
            rejected=frozenset((str(v), str(n)) for v, n in doc.get("rejected") or []),
            flags=tuple(str(f) for f in doc.get("flags") or []),
            robust_cost=None if cost is None else float(cost),
        )
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None  # nothing usable: the registration starts cold and says so
