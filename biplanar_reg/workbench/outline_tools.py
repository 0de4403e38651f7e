"""Outline editing in the workbench: anchors re-traced, stretches erased, exclusion zones,
GrabCut, per-contour quality and per-contour residuals.

The numerics are the library's (:func:`biplanar_reg.annotation.livewire`,
:func:`biplanar_reg.annotation.clean.cut_polyline`, :func:`biplanar_reg.annotation.
grabcut_outline`, :func:`biplanar_reg.annotation.features.gradient_magnitude`,
:func:`biplanar_reg.report.contour_residuals`); this module applies them to one open case and
saves the outcome through :meth:`Workbench.edit_contours`, so that ``annotations.json`` always
holds the contours as ``biplanar-reg register`` will use them.

**Exclusion zones** are polygons (pixels) of a view where no outline is trusted (a marker bead,
an overlapping bone). Adding one cuts the view's contours at once (the points inside are
dropped; a contour may become several pieces), and every contour traced, re-traced or made by
GrabCut through this module afterwards is cut the same way. The zones are kept in
``CASE_DIR/.workbench-cleaning.json`` (``biplanar-reg/workbench-cleaning@1``: ``{"views":
{view: {"cleaning": {"exclusion_zones": [[[u, v], ...], ...]}}}}``, the ``cleaning`` block of
a contour recipe, see ``docs/annotation.md``); the annotation file holds the cut contours, so
``register`` needs no zone file to see the same contour. The same file keeps each contour as it
was before a zone cut it (``uncut``, :mod:`biplanar_reg.workbench.zone_restore`): removing a
zone puts back what it cut, unless a piece was edited since.

A piece of a cut or erased contour keeps the anchors that lie on it, plus its two ends, so
that it can be edited like any traced contour: re-tracing runs the livewire through its
anchors and cuts the path by the zones again.

Pixels are ``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..annotation import Contour, grabcut_outline, livewire
from ..annotation.clean import cut_polyline
from ..annotation.features import gradient_magnitude
from ..io import atomic_write_json, read_json
from .edge_strength import FAINT, WEAK, edge_scale, grade
from .session import (
    LIVEWIRE_SIGMA_PX,
    MAX_ANCHORS,
    NotFound,
    Workbench,
    _fingerprint,
    check_flag,
    check_point,
    check_points,
    check_positive,
    require_version,
)
from .zone_restore import digest, new_record, note_cut

__all__ = ["OutlineTools", "outline_routes"]

log = logging.getLogger(__name__)

CLEANING_NAME = ".workbench-cleaning.json"
CLEANING_FORMAT = "biplanar-reg/workbench-cleaning@1"
#: Vertices of the polygon that stands for an exclusion circle (circumscribed: the circle lies
#: inside it).
CIRCLE_VERTICES = 32
MAX_ZONES = 500
#: An anchor within this distance of a piece stays one of its anchors, pixels (the livewire
#: moves anchors by up to 2 px onto the edge).
ANCHOR_TOL_PX = 3.0
#: An outline whose points lie on another part of it (:func:`self_overlap`) for more than this
#: share is refused: it runs over the same edge more than once (anchors placed twice).
MAX_OVERLAP = 0.25
OVERLAP_GAP = 10
GRABCUT_MAX_ITERATIONS = 20
#: Largest GrabCut box, square pixels (800 x 800 px). Measured on the 1760 px wrist
#: radiograph (benchmarks/workbench_bounds.py): an 800 px box took 2-4 s and ~145 MB more;
#: GrabCut's time grows quickly beyond (a 1000 px box took 68-88 s).
GRABCUT_MAX_AREA_PX = 640_000
#: GrabCut learns the background from the image outside the box: it must leave this much of
#: the image outside the box on at least one side, pixels.
GRABCUT_MIN_BACKGROUND_PX = 4


# -- pure helpers (pixels) -----------------------------------------------------------------------


def circle_polygon(center: np.ndarray, radius_px: float, n: int = CIRCLE_VERTICES) -> np.ndarray:
    """The ``n``-gon circumscribing the circle (centre and radius in pixels), (n, 2)."""
    r = radius_px / math.cos(math.pi / n)
    t = 2 * math.pi * np.arange(n) / n
    return np.column_stack([center[0] + r * np.cos(t), center[1] + r * np.sin(t)])


def brush_polygons(points: np.ndarray, radius_px: float) -> list[np.ndarray]:
    """Outlines (pixels) of a brush stroke: the points joined by a line ``2 radius_px`` wide.

    Rasterised at 4 sub-pixels per pixel on a crop around the stroke, outer boundaries only.
    """
    scale = 4
    lo = np.floor(points.min(axis=0) - radius_px - 2)
    hi = np.ceil(points.max(axis=0) + radius_px + 2)
    w, h = ((hi - lo) * scale + 1).astype(int)
    mask = np.zeros((h, w), np.uint8)
    pts = np.round((points - lo) * scale).astype(np.int32)
    r = max(int(round(radius_px * scale)), 1)
    for p in pts:
        cv2.circle(mask, (int(p[0]), int(p[1])), r, 1, -1)
    if len(pts) > 1:
        cv2.polylines(mask, [pts.reshape(-1, 1, 2)], False, 1, 2 * r + 1)
    found, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in found:
        poly = c.reshape(-1, 2).astype(float) / scale + lo
        if len(poly) >= 3:
            out.append(poly)
    return out


def _nearest(points: np.ndarray, p: np.ndarray) -> tuple[int, float]:
    d = np.linalg.norm(points - p, axis=1)
    k = int(np.argmin(d))
    return k, float(d[k])


def piece_anchors(piece: np.ndarray, closed: bool, anchors: np.ndarray | None) -> list | None:
    """Anchors of a piece of a contour: the old ``anchors`` within :data:`ANCHOR_TOL_PX` of it,
    in order along it, and (open pieces) its two ends; None when fewer than two."""
    chosen: list[tuple[int, np.ndarray]] = []
    if anchors is not None:
        for a in anchors:
            k, d = _nearest(piece, a)
            if d <= ANCHOR_TOL_PX:
                chosen.append((k, a))
    if not closed:
        chosen = [(k, a) for k, a in chosen if 0 < k < len(piece) - 1]
        chosen = [(0, piece[0]), *chosen, (len(piece) - 1, piece[-1])]
    chosen.sort(key=lambda item: item[0])
    out: list[list[float]] = []
    for _, a in chosen:
        if not out or np.hypot(*(np.asarray(out[-1]) - a)) > 1.0:
            out.append([round(float(a[0]), 3), round(float(a[1]), 3)])
    need = 3 if closed else 2
    return out if len(out) >= need else None


def self_overlap(path: np.ndarray, closed: bool, gap: int = OVERLAP_GAP) -> float:
    """The share of the points of ``path`` (pixels) that lie within 1 px of a point of it more
    than ``gap`` points away along it (around, for a closed one): 0 for an outline that follows
    an edge once, about 2/3 for one that runs three times over the same edge."""
    path = np.asarray(path, float).reshape(-1, 2)
    n = len(path)
    if n <= 2 * gap:
        return 0.0
    pairs = cKDTree(path).query_pairs(1.0, output_type="ndarray")
    d = np.abs(pairs[:, 0] - pairs[:, 1])
    if closed:
        d = np.minimum(d, n - d)
    return len(np.unique(pairs[d > gap].ravel())) / n


def erase_stretch(uv: np.ndarray, closed: bool, a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """``uv`` without the stretch between its points nearest to ``a`` and ``b`` (both
    dropped); for a closed contour the shorter of the two stretches. Pieces of < 3 points
    are dropped; the result is open."""
    i, _ = _nearest(uv, a)
    j, _ = _nearest(uv, b)
    i, j = min(i, j), max(i, j)
    if not closed:
        pieces = [uv[:i], uv[j + 1 :]]
    else:
        seg = np.linalg.norm(np.diff(np.vstack([uv, uv[:1]]), axis=0), axis=1)
        inner = float(seg[i:j].sum())  # i -> j
        if inner <= float(seg.sum()) - inner:  # drop i..j, keep j+1 .. n-1, 0 .. i-1
            pieces = [np.vstack([uv[j + 1 :], uv[:i]])]
        else:  # drop j..n-1, 0..i
            pieces = [uv[i + 1 : j]]
    return [p for p in pieces if len(p) >= 3]


# -- the tools over one workbench ------------------------------------------------------------------


class OutlineTools:
    """The outline tools over an open :class:`Workbench` (see the module docstring).

    Every method checks its input first (``ValueError`` starting with the field, as the
    session's) and writes nothing unless the whole request is valid.
    """

    def __init__(self, wb: Workbench):
        self.wb = wb
        self.path: Path = wb.case_dir / CLEANING_NAME
        self._lock = wb.edit_lock  # one lock for every edit: the undo history's too
        self._grad_lock = threading.Lock()
        self._grad: dict[str, tuple[np.ndarray, float, float]] = {}
        # (zones, uncut) of each view: replaced, never changed in place (the undo history
        # keeps the old values)
        self._state: tuple[dict[str, list], dict[str, list]] = self._read()
        wb.history.part("cleaning", lambda: self._state, self._put)

    @property
    def _zones(self) -> dict[str, list[list[list[float]]]]:
        return self._state[0]

    @property
    def _uncut(self) -> dict[str, list[dict]]:
        return self._state[1]

    # -- the zone file ---------------------------------------------------------------------

    def _read(self) -> tuple[dict[str, list], dict[str, list]]:
        if not self.path.is_file() or not self.path.resolve().is_relative_to(self.wb.case_dir):
            return {}, {}
        try:
            doc = read_json(self.path)
            out, uncut = {}, {}
            for view, entry in doc["views"].items():
                if view in self.wb.views:
                    zones = entry["cleaning"]["exclusion_zones"]
                    out[view] = [np.asarray(z, float).reshape(-1, 2).tolist() for z in zones]
                    uncut[view] = _records(entry.get("uncut", []))
            return out, uncut
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            log.warning("%s: ignored (%s)", self.path, exc)
            return {}, {}

    def _write(self, zones: dict[str, list], uncut: dict[str, list] | None = None) -> None:
        self._put((zones, self._uncut if uncut is None else uncut))

    def _put(self, state: tuple[dict[str, list], dict[str, list]]) -> None:
        """Save and adopt ``(zones, uncut)`` (an edit, or a state of the undo history)."""
        zones, uncut = state
        views = {}
        for v in sorted(set(zones) | set(uncut)):
            if zones.get(v) or uncut.get(v):
                views[v] = {"cleaning": {"exclusion_zones": zones.get(v, [])},
                            "uncut": uncut.get(v, [])}  # fmt: skip
        atomic_write_json(self.path, {"format": CLEANING_FORMAT, "views": views})
        self._state = (zones, uncut)

    def zones(self, view: str) -> list[list[list[float]]]:
        """The exclusion polygons of ``view`` (pixels)."""
        self._view(view)
        return [list(z) for z in self._zones.get(view, [])]

    # -- helpers -------------------------------------------------------------------------------

    def _view(self, name: str) -> Any:
        v = self.wb.views.get(name)
        if v is None:
            raise NotFound(f"view: unknown view {name!r} (views: {', '.join(self.wb.views)})")
        return v

    def _cut(self, view: str, uv: np.ndarray, closed: bool, zones=None):
        zones = self._zones.get(view, []) if zones is None else zones
        if not zones:
            return [uv], [closed]
        return cut_polyline(uv, closed, exclusion_zones=[np.asarray(z) for z in zones])

    def _pieces(self, view, uv, closed, anchors, zones=None) -> list[tuple[Contour, Any]]:
        """The contour ``uv`` cut by the zones, each piece with its anchor entry."""
        pieces, flags = self._cut(view, uv, closed, zones)
        out = []
        for p, c in zip(pieces, flags, strict=True):
            contour = Contour(p, c)
            if len(pieces) == 1 and c == closed and anchors is not None:
                kept = np.round(np.asarray(anchors, float), 3).tolist()
            else:
                kept = piece_anchors(p, c, None if anchors is None else np.asarray(anchors))
            entry = None if kept is None else {**_fingerprint(contour), "anchors": kept}
            out.append((contour, entry))
        return out

    def _replace(
        self,
        view: str,
        ref: int | str | None,
        make: Callable,
        version: int | None = None,
        label: str = "",
        source: tuple | None = None,
    ) -> dict[str, Any]:
        """Replace contour ``ref`` (an index or a contour id, at ``version`` when given; append
        when None) by the pieces ``make(contour, entry)`` returns; answers ``{"index",
        "pieces", "view"}``. ``source`` = ``(uv, closed, anchors)``: the contour before the
        zones cut it (kept when they did, so that removing a zone restores it); ``label``
        names the edit in the undo history."""
        info: dict[str, Any] = {}
        uncut: dict[str, list] = {}

        def change(contours: list[Contour], saved: list[Any]) -> None:
            index = None if ref is None else self.wb.contour_index(view, ref, version)
            old = (None, None) if index is None else (contours[index], saved[index])
            pieces = make(*old)
            if source is not None and _was_cut(source[0], pieces):
                record = new_record(*source, [c for c, _ in pieces])
                uncut.update(self._uncut)
                uncut[view] = [*self._uncut.get(view, []), record]
            at = len(contours) if index is None else index
            if index is not None:
                del contours[index], saved[index]
            for k, (c, e) in enumerate(pieces):
                contours.insert(at + k, c)
                saved.insert(at + k, e)
            info.update(index=at, pieces=len(pieces))

        with self._lock, self.wb.history.step(label or f"contours of {view} edited"):
            doc = self.wb.edit_contours(view, change, label)
            if uncut:
                self._write(self._zones, uncut)
        return {**info, "view": doc}

    # -- tracing and editing ---------------------------------------------------------------

    def _trace(self, view: str, anchors: object, closed: object) -> tuple[np.ndarray, Any, bool]:
        v = self._view(view)
        v.need_image()
        is_closed = check_flag(closed, "closed", False)
        pts = check_points(anchors, "anchors", v.size, 3 if is_closed else 2, MAX_ANCHORS)
        path = livewire(v.image, pts, is_closed, sigma_px=LIVEWIRE_SIGMA_PX, cost=v.cost())
        share = self_overlap(path, is_closed)
        if share > MAX_OVERLAP:
            raise ValueError(
                f"anchors: the outline runs over itself ({100 * share:.0f}% of its points lie on "
                "another part of it): place the anchors once along the edge"
            )
        return np.round(path, 3), pts, is_closed

    def _nonempty(self, pieces: list, field: str) -> list:
        if not pieces:
            raise ValueError(f"{field}: the outline lies entirely inside exclusion zones")
        return pieces

    def trace(self, view: str, anchors: object, closed: object = None) -> dict[str, Any]:
        """A new contour: the livewire through ``anchors``, cut by the view's zones, appended
        (one contour per piece). ``{"index": first piece, "pieces", "view"}``."""
        path, pts, is_closed = self._trace(view, anchors, closed)
        pieces = self._nonempty(self._pieces(view, path, is_closed, pts), "anchors")
        label = f"contour traced in {view}"
        return self._replace(view, None, lambda *_: pieces, None, label, (path, is_closed, pts))

    def retrace(
        self,
        view: str,
        index: int | str,
        anchors: object,
        closed: object = None,
        version: int | None = None,
    ) -> dict[str, Any]:
        """Contour ``index`` (an index or a contour id, at ``version`` when given) traced
        again through the edited ``anchors`` (an anchor dragged, inserted or deleted): the
        livewire between neighbours, cut by the zones; the pieces take its place. ``{"index",
        "pieces", "view"}``."""
        self._view(view)
        self.wb.contour_index(view, index, version)  # a stale edit: before the tracing
        path, pts, is_closed = self._trace(view, anchors, closed)
        pieces = self._nonempty(self._pieces(view, path, is_closed, pts), "anchors")
        label, source = f"contour of {view} re-traced", (path, is_closed, pts)
        return self._replace(view, index, lambda *_: pieces, version, label, source)

    def erase(
        self,
        view: str,
        index: int | str,
        start: object,
        end: object,
        version: int | None = None,
    ) -> dict[str, Any]:
        """Contour ``index`` (an index or a contour id, at ``version`` when given) without the
        stretch between its points nearest to ``start`` and ``end`` (pixels); nothing left
        removes the contour; two clicks on the same point of it (a stretch of no length)
        change nothing. ``{"index", "pieces", "view"}``."""
        v = self._view(view)
        a = check_point(start, "from", v.size)
        b = check_point(end, "to", v.size)

        def make(contour: Contour, entry: Any) -> list:
            uv = np.asarray(contour.uv, float)
            if _nearest(uv, a)[0] == _nearest(uv, b)[0]:
                return [(contour, entry)]  # nothing between: the contour stays whole
            anchors = None if entry is None else np.asarray(entry["anchors"], float)
            pieces = erase_stretch(uv, contour.closed, a, b)
            return [
                (Contour(p, False), _entry(p, piece_anchors(p, False, anchors))) for p in pieces
            ]

        return self._replace(view, index, make, version, f"stretch erased in {view}")

    def grabcut(self, view: str, box: object, iterations: object = None) -> dict[str, Any]:
        """A closed contour from GrabCut in ``box`` = ``[u0, v0, u1, v1]`` (pixels, inside the
        image), cut by the zones and appended. ``{"index", "pieces", "view", "seconds"}``."""
        t0 = time.perf_counter()
        v = self._view(view)
        v.need_image()
        if not isinstance(box, list) or len(box) != 4:
            raise ValueError(f"box: expected [u0, v0, u1, v1] in pixels, got {box!r:.60}")
        p0 = check_point(box[:2], "box[0:2]", v.size)
        p1 = check_point(box[2:], "box[2:4]", v.size)
        lo, hi = np.minimum(p0, p1), np.maximum(p0, p1)
        _check_box(lo, hi, v.size, box)
        its = 5 if iterations is None else iterations
        if isinstance(its, bool) or not isinstance(its, int):
            raise ValueError(f"iterations: expected a whole number, got {its!r:.60}")
        if not 1 <= its <= GRABCUT_MAX_ITERATIONS:
            raise ValueError(f"iterations: expected 1 to {GRABCUT_MAX_ITERATIONS}, got {its}")
        outline = grabcut_outline(v.image, box=np.r_[lo, hi], iterations=its)
        pieces = self._nonempty(self._pieces(view, outline, True, None), "box")
        label, source = f"GrabCut contour in {view}", (outline, True, None)
        doc = self._replace(view, None, lambda *_: pieces, None, label, source)
        return {**doc, "seconds": _since(t0)}

    # -- exclusion zones -------------------------------------------------------------------

    def _zone_polygons(self, v: Any, body: dict[str, Any]) -> list[np.ndarray]:
        given = [k for k in ("circle", "polygon", "brush") if body.get(k) is not None]
        if len(given) != 1:
            raise ValueError("body: give exactly one of circle, polygon and brush")
        kind = given[0]
        if kind == "polygon":
            return [check_points(body["polygon"], "polygon", v.size, 3, MAX_ANCHORS)]
        spec = body[kind]
        if not isinstance(spec, dict):
            raise ValueError(f"{kind}: expected an object, got {spec!r:.60}")
        limit = float(max(v.size)) if v.size else 1e6
        radius = check_positive(spec.get("radius_px"), f"{kind}.radius_px", None)
        if radius is None or radius > limit:
            raise ValueError(f"{kind}.radius_px: expected a number in (0, {limit:g}] pixels")
        if kind == "circle":
            return [circle_polygon(check_point(spec.get("center"), "circle.center", v.size),
                                   radius)]  # fmt: skip
        pts = check_points(spec.get("points"), "brush.points", v.size, 1, MAX_ANCHORS)
        return brush_polygons(pts, radius)

    def add_zone(self, view: str, body: dict[str, Any]) -> dict[str, Any]:
        """Add an exclusion zone to ``view`` and cut its contours by it: ``body`` has one of
        ``{"circle": {"center": [u, v], "radius_px": r}}``, ``{"polygon": [[u, v], ...]}``,
        ``{"brush": {"points": [[u, v], ...], "radius_px": r}}`` (pixels). Returns ``{"zones",
        "added", "cut": [indices of the contours it cut, before the cut], "view"}``."""
        v = self._view(view)
        polys = [np.round(p, 3).tolist() for p in self._zone_polygons(v, body)]
        cut: list[int] = []
        label = f"exclusion zone added in {view}"
        with self._lock, self.wb.history.step(label):
            zones = {k: list(z) for k, z in self._zones.items()}
            if len(zones.get(view, [])) + len(polys) > MAX_ZONES:
                raise ValueError(f"zones: at most {MAX_ZONES} per view")
            zones[view] = zones.get(view, []) + polys
            uncut = dict(self._uncut)

            def change(contours: list[Contour], saved: list[Any]) -> None:
                new_c, new_s, records = [], [], list(uncut.get(view, []))
                for i, (c, e) in enumerate(zip(contours, saved, strict=True)):
                    anchors = None if e is None else e["anchors"]
                    pieces = self._pieces(view, np.asarray(c.uv), c.closed, anchors, polys)
                    if _was_cut(c.uv, pieces):
                        cut.append(i)
                        records = note_cut(records, c, anchors, [p[0] for p in pieces])
                    else:
                        pieces = [(c, e)]
                    new_c += [p[0] for p in pieces]
                    new_s += [p[1] for p in pieces]
                contours[:], saved[:] = new_c, new_s
                uncut[view] = records

            doc = self.wb.edit_contours(view, change, label)
            self._write(zones, uncut)
        return {"zones": zones[view], "added": len(polys), "cut": cut, "view": doc}

    def delete_zone(self, view: str, index: int) -> dict[str, Any]:
        """Remove zone ``index`` of ``view`` and put back what it cut (each contour it cut,
        cut by the remaining zones, in place of its pieces; not one whose pieces were edited
        since): ``{"zones", "restored", "not_restored": contours, "view"}``."""
        self._view(view)
        label = f"exclusion zone removed from {view}"
        with self._lock, self.wb.history.step(label):
            zones = {k: list(z) for k, z in self._zones.items()}
            have = zones.get(view, [])
            if not 0 <= index < len(have):
                raise NotFound(f"zones.{view}[{index}]: no such zone ({len(have)} in the view)")
            removed = np.asarray(have.pop(index), float)
            zones[view] = have
            uncut = dict(self._uncut)
            count = {"restored": 0, "not_restored": 0}

            def change(contours: list[Contour], saved: list[Any]) -> None:
                records = uncut.get(view, [])
                args = (records, removed, have, count)
                uncut[view] = self._restore(view, contours, saved, *args)

            doc = self.wb.edit_contours(view, change, label)
            self._write(zones, uncut)
        return {"zones": have, **count, "view": doc}

    def _restore(
        self,
        view: str,
        contours: list[Contour],
        saved: list[Any],
        records: list[dict],
        removed: np.ndarray,
        remaining: list,
        count: dict[str, int],
    ) -> list[dict]:
        """Put back, in ``contours`` / ``saved`` (edited in place), each recorded contour that
        the ``removed`` zone cut, cut by the ``remaining`` zones; returns the records that
        stay."""
        keep = []
        for r in records:
            src = np.asarray(r["uv"], float)
            if not _was_cut(src, self._pieces(view, src, r["closed"], None, [removed])):
                keep.append(r)  # this zone did not cut it
                continue
            keys = [digest(c) for c in contours]
            at = [keys.index(d) for d in r["pieces"] if d in keys]
            if len(at) != len(r["pieces"]):
                count["not_restored"] += 1  # a piece was edited or removed since
                continue
            pieces = self._pieces(view, src, r["closed"], r["anchors"], remaining)
            pos = min(at) if at else len(contours)
            for i in sorted(at, reverse=True):
                del contours[i], saved[i]
            contours[pos:pos] = [c for c, _ in pieces]
            saved[pos:pos] = [e for _, e in pieces]
            count["restored"] += 1
            if _was_cut(src, pieces):
                keep.append({**r, "pieces": [digest(c) for c, _ in pieces]})
        return keep

    # -- quality and residuals -------------------------------------------------------------

    def _gradient(self, view: str) -> tuple[np.ndarray, float, float]:
        """The view's gradient magnitude and its edge scale (:func:`edge_scale`), once."""
        v = self._view(view)
        v.need_image()
        with self._grad_lock:
            if view not in self._grad:
                g = gradient_magnitude(v.image.display.astype(np.float64), LIVEWIRE_SIGMA_PX)
                self._grad[view] = (g, *edge_scale(g))
            return self._grad[view]

    def quality(self, view: str) -> dict[str, Any]:
        """Edge strength along each contour of ``view`` (:mod:`biplanar_reg.workbench.
        edge_strength`: gradient magnitude / the image's typical edge): ``{"contours":
        [{"index", "strength": per point, "median", "weak_fraction", "strong_fraction",
        "verdict"}], "weak", "faint", "strong"}``."""
        g, typical, strong = self._gradient(view)
        va = self.wb.view_document(view)
        out = [
            {"index": i, **grade(g, np.asarray(c["uv"], float), typical, strong)}
            for i, c in enumerate(va["contours"])
        ]
        return {"contours": out, "weak": WEAK, "faint": FAINT, "strong": round(strong, 3)}

    def residuals(self) -> dict[str, Any]:
        """Per-contour residuals of the current contours against the last registration's
        outline (:func:`biplanar_reg.report.contour_residuals`): ``{"views": {view: [{"index",
        "mean_px", "max_px", "worst_mean_px", "worst_uv", "length_px"}]}}``; 404 before any
        registration."""
        from ..report import contour_residuals

        result = self.wb.result()
        views: dict[str, list[dict[str, Any]]] = {}
        for name in self.wb.views:
            outline = [np.asarray(p, float) for p in result["views"][name]["outline_px"]]
            contours = [
                Contour(np.asarray(c["uv"], float), c["closed"])
                for c in self.wb.view_document(name)["contours"]
            ]
            views[name] = [
                {
                    "index": r.index,
                    "mean_px": _finite(r.mean_px),
                    "max_px": _finite(r.max_px),
                    "worst_mean_px": _finite(r.worst_mean_px),
                    "worst_uv": np.round(r.worst_uv, 2).tolist(),
                    "length_px": round(r.length_px, 2),
                }
                for r in contour_residuals(contours, outline)
            ]
        return {"views": views}


def _check_box(lo: np.ndarray, hi: np.ndarray, size: tuple[int, int], box: object) -> None:
    """A GrabCut box (corners ``lo``, ``hi`` inside the image): at least 8 px each way, at most
    :data:`GRABCUT_MAX_AREA_PX`, some background left outside it."""
    (wd, ht), (w, h) = hi - lo, size
    if wd < 8 or ht < 8:
        raise ValueError(f"box: must be at least 8 px wide and high, got {box}")
    if wd * ht > GRABCUT_MAX_AREA_PX:
        raise ValueError(
            f"box: at most {GRABCUT_MAX_AREA_PX} square px (e.g. 800 x 800 px; GrabCut's time "
            f"and memory grow with it), got {wd:.0f} x {ht:.0f} px = {wd * ht:.0f}"
        )
    u0, v0, u1, v1 = np.round(np.r_[lo, hi]).astype(int)
    outside = max(u0, v0, w - 1 - u1, h - 1 - v1)
    if outside < GRABCUT_MIN_BACKGROUND_PX:
        raise ValueError(
            f"box: leaves no background around it (GrabCut learns the background outside the "
            f"box): keep it at least {GRABCUT_MIN_BACKGROUND_PX} px inside the image's edge on "
            f"one side, got {box}"
        )


def _was_cut(uv: Any, pieces: list) -> bool:
    """Whether ``pieces`` (``(Contour, entry)`` pairs) are not just the contour ``uv``."""
    return len(pieces) != 1 or len(pieces[0][0].uv) != len(uv)


def _records(value: object) -> list[dict]:
    """The ``uncut`` records of a view as read from the cleaning file (checked for shape)."""
    out = []
    for r in value if isinstance(value, list) else []:
        uv = np.asarray(r["uv"], float).reshape(-1, 2)
        pieces = [str(p) for p in r["pieces"]]
        anchors = r.get("anchors")
        anchors = None if anchors is None else np.asarray(anchors, float).reshape(-1, 2).tolist()
        out.append({"uv": uv.tolist(), "closed": bool(r["closed"]), "anchors": anchors,
                    "pieces": pieces})  # fmt: skip
    return out


def _entry(piece: np.ndarray, anchors: list | None) -> dict[str, Any] | None:
    return None if anchors is None else {**_fingerprint(Contour(piece, False)), "anchors": anchors}


def _finite(x: float) -> float | None:
    return round(float(x), 3) if math.isfinite(x) else None


def _since(t0: float) -> float:
    return time.perf_counter() - t0


# -- routes ---------------------------------------------------------------------------------------


def outline_routes(
    wb: Workbench,
    guarded: Callable[[Callable[..., Awaitable[Any]]], Any],
    body: Callable[..., Awaitable[dict[str, Any]]],
    call: Callable[..., Awaitable[Any]],
) -> list[Any]:
    """The API routes of the outline tools (``docs/workbench.md``); ``guarded``, ``body`` and
    ``call`` are the server's error mapping, JSON body reader and thread-pool runner."""
    from starlette.requests import Request
    from starlette.responses import JSONResponse
    from starlette.routing import Route

    tools = OutlineTools(wb)

    async def outlines(request: Request) -> JSONResponse:
        b = await body(request)
        view = request.path_params["view"]
        return JSONResponse(await call(tools.trace, view, b.get("anchors"), b.get("closed")))

    async def retrace(request: Request) -> JSONResponse:
        version = require_version(request.query_params.get("version"))
        b = await body(request)
        p = request.path_params
        args = (p["view"], p["ref"], b.get("anchors"), b.get("closed"), version)
        return JSONResponse(await call(tools.retrace, *args))

    async def erase(request: Request) -> JSONResponse:
        version = require_version(request.query_params.get("version"))
        b = await body(request)
        p = request.path_params
        args = (p["view"], p["ref"], b.get("from"), b.get("to"), version)
        return JSONResponse(await call(tools.erase, *args))

    async def grabcut(request: Request) -> JSONResponse:
        b = await body(request)
        args = (request.path_params["view"], b.get("box"), b.get("iterations"))
        return JSONResponse(await call(tools.grabcut, *args))

    async def zones(request: Request) -> JSONResponse:
        view = request.path_params["view"]
        if request.method == "GET":
            return JSONResponse({"zones": await call(tools.zones, view)})
        return JSONResponse(await call(tools.add_zone, view, await body(request)))

    async def zone(request: Request) -> JSONResponse:
        p = request.path_params
        return JSONResponse(await call(tools.delete_zone, p["view"], p["index"]))

    async def quality(request: Request) -> JSONResponse:
        return JSONResponse(await call(tools.quality, request.path_params["view"]))

    async def residuals(request: Request) -> JSONResponse:
        return JSONResponse(await call(tools.residuals))

    v = "/api/views/{view}"
    table = [
        (v + "/outlines", outlines, ["POST"]),
        (v + "/contours/{ref}/anchors", retrace, ["PUT"]),
        (v + "/contours/{ref}/erase", erase, ["POST"]),
        (v + "/grabcut", grabcut, ["POST"]),
        (v + "/exclusions", zones, ["GET", "POST"]),
        (v + "/exclusions/{index:int}", zone, ["DELETE"]),
        (v + "/quality", quality, ["GET"]),
        ("/api/result/contours", residuals, ["GET"]),
    ]
    return [Route(path, guarded(fn), methods=m) for path, fn, m in table]
