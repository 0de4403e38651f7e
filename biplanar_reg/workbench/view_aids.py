"""Aids to seeing in the workbench: epipolar curves across views, marker detection, the
window of a box and contrast-enhanced (CLAHE) tiles.

* Epipolar curves: the ray of a pixel of one view drawn in every other view
  (:func:`biplanar_reg.calibration.epipolar.epipolar_curve`, any view kind), for the cursor
  and the selected landmark.
* Markers: :func:`biplanar_reg.annotation.markers.detect_markers` on a view's radiograph,
  each proposed as a circular exclusion zone (the page adds the accepted ones through the
  exclusion-zone route of :mod:`.outline_tools`).
* Box window: the 1st-99th percentile of the raw pixels in a box drawn on the image.
* CLAHE tiles: :meth:`biplanar_reg.workbench.tiles.Pyramid.tile` with ``clahe=True``; they
  change the display only: the livewire's cost stays on the image itself, so that a contour
  does not depend on how it was shown.

Pixels are ``(u, v)`` = (column, row), 0-based; the world frame is the calibration's, mm.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np

from ..annotation.markers import BEAD_RADII_PX, DISC_RADII_PX, detect_markers
from ..calibration.epipolar import epipolar_curve, scene_sphere
from .session import NotFound, Workbench, check_point

__all__ = ["ViewAids", "view_aid_routes"]

#: Marker kinds: the radii searched, pixels.
MARKER_KINDS = {"beads": BEAD_RADII_PX, "discs": DISC_RADII_PX}
#: A proposed zone's radius: the marker's times this plus ZONE_MARGIN_PX (covers the rim and
#: the blur around it, which the livewire would otherwise follow).
ZONE_SCALE = 1.5
ZONE_MARGIN_PX = 2.0
#: Percentiles of the pixels in a box that make its automatic window.
BOX_PERCENTILES = (1.0, 99.0)


def _rounded(points: np.ndarray) -> list[list[float]]:
    return np.round(np.asarray(points, float), 2).tolist()


class ViewAids:
    """The aids over one open workbench (scene sphere and marker results kept)."""

    def __init__(self, wb: Workbench):
        self.wb = wb
        self._scene: tuple[np.ndarray, float] | None = None
        self._markers: dict[tuple[str, str, float], list[dict[str, Any]]] = {}
        self._lock = threading.Lock()

    def scene(self) -> tuple[np.ndarray, float]:
        """The scene sphere of the case's views (centre mm, radius mm), computed once."""
        with self._lock:
            if self._scene is None:
                self._scene = scene_sphere([v.cv.view for v in self.wb.views.values()])
            return self._scene

    def epipolar(self, view: str, u: object, v: object) -> dict[str, Any]:
        """The epipolar curves of pixel ``(u, v)`` of ``view`` in every other view:
        ``{"view", "uv", "curves": {name: [[[u, v], ...], ...]}, "seconds"}``."""
        t0 = time.perf_counter()
        src = self.wb._view(view)
        size = src.size
        uv = check_point([_number(u, "u"), _number(v, "v")], "uv", size)
        scene = self.scene()
        curves: dict[str, list[list[list[float]]]] = {}
        for name, other in self.wb.views.items():
            if name == view or other.size is None:
                continue
            pieces = epipolar_curve(src.cv.view, uv, other.cv.view, scene, other.size)
            curves[name] = [_rounded(p) for p in pieces]
        return {
            "view": view,
            "uv": [float(x) for x in uv],
            "curves": curves,
            "seconds": time.perf_counter() - t0,
        }

    def markers(self, view: str, kind: object, min_contrast: object) -> dict[str, Any]:
        """Markers detected on ``view``'s radiograph, strongest first: ``{"markers": [{"uv",
        "radius_px", "contrast", "zone_radius_px"}], "kind", "seconds"}`` (kept per view,
        kind and threshold)."""
        t0 = time.perf_counter()
        v = self.wb._view(view)
        v.need_image()
        kind = "beads" if kind in (None, "") else kind
        if kind not in MARKER_KINDS:
            raise ValueError(f"kind: expected 'beads' or 'discs', got {str(kind)[:40]!r}")
        contrast = 0.035 if min_contrast in (None, "") else _number(min_contrast, "min_contrast")
        if not 0 < contrast < 1:
            raise ValueError(f"min_contrast: expected a number in (0, 1), got {contrast:g}")
        key = (view, str(kind), contrast)
        if key not in self._markers:
            found = detect_markers(v.image, radii_px=MARKER_KINDS[kind], min_contrast=contrast)
            self._markers[key] = [
                {
                    "uv": [round(m.uv[0], 2), round(m.uv[1], 2)],
                    "radius_px": m.radius_px,
                    "contrast": round(m.contrast, 4),
                    "zone_radius_px": round(ZONE_SCALE * m.radius_px + ZONE_MARGIN_PX, 2),
                }
                for m in found
            ]
        return {"markers": self._markers[key], "kind": kind, "seconds": time.perf_counter() - t0}

    def box_window(self, view: str, box: object) -> dict[str, Any]:
        """The display window of the pixels in ``box`` = ``"u0,v0,u1,v1"`` (pixels, any two
        opposite corners, clipped to the image): their 1st and 99th percentiles, raw units.
        ``{"window": [lo, hi], "box": [u0, v0, u1, v1], "pixels": n}``."""
        v = self.wb._view(view)
        p = v.pyramid()
        parts = str(box if box is not None else "").split(",")
        if len(parts) != 4:
            raise ValueError(f"box: expected u0,v0,u1,v1 (pixels), got {str(box)[:60]!r}")
        u0, v0, u1, v1 = (_number(x, "box") for x in parts)
        c0 = max(0, math.floor(min(u0, u1) + 0.5))
        c1 = min(p.width, math.floor(max(u0, u1) + 0.5) + 1)
        r0 = max(0, math.floor(min(v0, v1) + 0.5))
        r1 = min(p.height, math.floor(max(v0, v1) + 0.5) + 1)
        if c1 - c0 < 2 or r1 - r0 < 2:
            raise ValueError(
                f"box: at least 2 x 2 pixels inside the {p.width}x{p.height} image, got "
                f"{max(c1 - c0, 0)} x {max(r1 - r0, 0)}"
            )
        pixels = p.level(0)[r0:r1, c0:c1]
        lo, hi = (float(x) for x in np.percentile(pixels, BOX_PERCENTILES))
        if not hi > lo:  # a flat box: one grey level either side
            lo, hi = lo - 1.0, hi + 1.0
        return {"window": [lo, hi], "box": [c0, r0, c1 - 1, r1 - 1], "pixels": int(pixels.size)}

    def tile(
        self, view: str, level: int, tx: int, ty: int, lo: float | None, hi: float | None
    ) -> bytes:
        """A CLAHE-enhanced PNG tile of ``view`` (display only)."""
        try:
            return self.wb._view(view).pyramid().tile(level, tx, ty, lo, hi, clahe=True)
        except LookupError as exc:
            raise NotFound(str(exc)) from None


def _number(value: object, field: str) -> float:
    """A finite number from a query value (string or number); ``ValueError`` naming it."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected a number, got {str(value)[:40]!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{field}: must be finite, got {value!r}")
    return x


def view_aid_routes(
    aids: ViewAids,
    guarded: Callable[[Callable[..., Awaitable[Any]]], Any],
    call: Callable[..., Awaitable[Any]],
) -> list[Any]:
    """The routes of the aids (``docs/workbench.md``); ``guarded`` and ``call`` are the
    server's error mapping and thread-pool runner."""
    from starlette.requests import Request
    from starlette.responses import JSONResponse
    from starlette.routing import Route

    async def epipolar(request: Request) -> JSONResponse:
        q = request.query_params
        view = request.path_params["view"]
        return JSONResponse(await call(aids.epipolar, view, q.get("u"), q.get("v")))

    async def markers(request: Request) -> JSONResponse:
        q = request.query_params
        view = request.path_params["view"]
        return JSONResponse(await call(aids.markers, view, q.get("kind"), q.get("min_contrast")))

    async def window(request: Request) -> JSONResponse:
        view = request.path_params["view"]
        return JSONResponse(await call(aids.box_window, view, request.query_params.get("box")))

    v = "/api/views/{view}"
    return [
        Route(v + "/window", guarded(window), methods=["GET"]),
        Route(v + "/epipolar", guarded(epipolar), methods=["GET"]),
        Route(v + "/markers", guarded(markers), methods=["GET"]),
    ]
