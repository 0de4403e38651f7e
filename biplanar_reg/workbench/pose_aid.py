"""The pose aid: the model's mean shape posed by the clicked landmarks, drawn over each view.

Pure functions on numpy arrays (the session keeps the state): the mean shape of a case's
model (:func:`mean_shape`), the rigid pose that the landmark clicks fix (:func:`landmark_pose`,
a G-SfT solve of the mean shape without modes, as the registration's rigid mean-shape start),
the posed outline and landmarks in each view (:func:`posed_overlay`), the in-view nudges
(:func:`nudge_translate`, :func:`nudge_rotate`), the "propose outline" contour (the posed
outline snapped to the image's edges by livewire between points taken along it,
:func:`propose_outline`) and the start-pose file (:func:`write_start`).

Frames: model coordinates in mm (the case's units scaled to mm), world = the calibration's
frame, mm; a pose ``(R, t)`` maps model to world, ``X = R @ x + t``. Pixels ``(u, v)`` as in
the annotation format.
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..annotation import livewire
from ..calibration import View
from ..cases import CaseSetup
from ..cases.case import UNIT_SCALE, CaseView
from ..io import atomic_write_json, atomic_write_text, read_mesh
from ..outline import outline_polylines
from ..registration import RayObservations, solve_gsft
from ..ssm import ShapeModel
from .session import Conflict, NotFound, check_point, check_positive

__all__ = [
    "MIN_OBSERVATIONS",
    "mean_shape",
    "landmark_observations",
    "pose_ready",
    "landmark_pose",
    "posed_overlay",
    "nudge_translate",
    "nudge_rotate",
    "propose_outline",
    "write_start",
    "PoseAid",
]

#: Landmark observations (over >= 2 views) that fix a rigid pose: 6 unknowns, 2 per click,
#: with one to spare (the registration's minimum too).
MIN_OBSERVATIONS = 4
START_NAME = "start.json"


def mean_shape(setup: CaseSetup) -> tuple[np.ndarray, np.ndarray | None]:
    """The mean shape of the case's model, mm, and its faces.

    An ``ssm`` model's mean; a ``template`` model's template itself (the synthesised
    population's mean is close to it; building that population takes seconds).
    """
    scale = UNIT_SCALE[setup.units]
    if setup.model_path.suffix.lower() == ".npz":
        model = ShapeModel.load(setup.model_path)
        return np.asarray(model.mean, float) * scale, model.faces
    verts, faces = read_mesh(setup.model_path)
    # the loader scales a template before building its population: the same here
    return np.asarray(verts, float) * scale, faces


def landmark_observations(
    views: Sequence[CaseView],
    clicks: Mapping[str, Mapping[str, Any]],
    landmarks: Mapping[str, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The clicked landmarks as rays: ``(vertex ids, origins, directions, view names)``.

    ``clicks`` is ``{view: {landmark name: (u, v) pixels}}``; names the model does not define
    are skipped. Origins and directions in the world frame, mm.
    """
    ids, origins, dirs, names = [], [], [], []
    for cv in views:
        pts = [(landmarks[n], uv) for n, uv in clicks.get(cv.name, {}).items() if n in landmarks]
        if not pts:
            continue
        o, d = cv.view.rays(np.array([uv for _, uv in pts], float))
        ids += [i for i, _ in pts]
        origins.append(o)
        dirs.append(d)
        names += [cv.name] * len(pts)
    if not ids:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), []
    return np.array(ids, np.int64), np.vstack(origins), np.vstack(dirs), names


def pose_ready(view_names: Sequence[str]) -> str | None:
    """None when these observations (one view name each) fix a pose, else why not."""
    n, k = len(view_names), len(set(view_names))
    if n >= MIN_OBSERVATIONS and k >= 2:
        return None
    return (
        f"{n} landmark click(s) in {k} view(s); the pose aid needs {MIN_OBSERVATIONS} over at "
        "least 2 views"
    )


def landmark_pose(
    mean: np.ndarray,
    faces: np.ndarray | None,
    ids: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The rigid pose ``(R (3, 3), t (3,) mm)`` of the mean shape that the landmark rays fix:
    G-SfT with no modes (the registration's rigid mean-shape start, equal weights)."""
    rigid = ShapeModel(mean, np.zeros((0, mean.shape[0], 3)), faces=faces)
    res = solve_gsft(rigid, RayObservations(ids, origins, directions))
    return np.asarray(res.rotation, float), np.asarray(res.translation, float)


def posed_overlay(
    mean: np.ndarray,
    faces: np.ndarray | None,
    R: np.ndarray,
    t: np.ndarray,
    views: Sequence[CaseView],
    landmarks: Mapping[str, int],
) -> dict[str, dict[str, Any]]:
    """What the page draws per view: ``{view: {"outline_px", "outline_closed",
    "landmarks_px", "centre_px"}}`` of the mean shape posed by ``(R, t)`` (pixels; the
    centre is the posed vertices' mean, about which nudges turn; outlines by
    :func:`biplanar_reg.outline.outline_polylines`, longest first)."""
    V = mean @ R.T + t
    names = [n for n, i in landmarks.items() if 0 <= i < len(V)]
    ids = np.array([landmarks[n] for n in names], np.int64)
    out = {}
    centre = V.mean(axis=0)
    for cv in views:
        lines, closed = outline_polylines(V, cv.view, faces)
        uv = cv.view.project(V[ids]) if len(ids) else np.zeros((0, 2))
        out[cv.name] = {
            "centre_px": np.round(cv.view.project(centre[None])[0], 2).tolist(),
            "outline_px": [np.round(line, 2).tolist() for line in lines],
            "outline_closed": [bool(c) for c in closed],
            "landmarks_px": {n: np.round(p, 2).tolist() for n, p in zip(names, uv, strict=True)},
        }
    return out


def _centre(mean: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return mean.mean(axis=0) @ R.T + t


def nudge_translate(
    mean: np.ndarray, R: np.ndarray, t: np.ndarray, view: View, d_uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move the posed bone parallel to ``view``'s detector so that its centre's projection
    moves by ``d_uv`` pixels (its distance from the source kept). Returns the new ``(R, t)``."""
    c = _centre(mean, R, t)
    uv = view.project(c[None])[0] + np.asarray(d_uv, float)
    o, d = view.rays(uv[None])
    o, d = o[0], d[0]
    # the point of the new ray at the centre's depth along that ray's direction
    o_c, d_c = view.rays(view.project(c[None]))
    depth = float(np.dot(c - o_c[0], d_c[0]))
    return R, t + (o + depth * d - c)


def nudge_rotate(
    mean: np.ndarray, R: np.ndarray, t: np.ndarray, view: View, degrees: float
) -> tuple[np.ndarray, np.ndarray]:
    """Turn the posed bone about ``view``'s ray through its centre by ``degrees`` (positive:
    clockwise on the screen, v pointing down). Returns the new ``(R, t)``."""
    c = _centre(mean, R, t)
    _, d = view.rays(view.project(c[None]))
    k = d[0] / np.linalg.norm(d[0])
    a = math.radians(degrees)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    dR = np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx
    return dR @ R, dR @ (t - c) + c


def _resample_closed(line: np.ndarray, closed: bool, spacing: float) -> np.ndarray:
    """Points every ``spacing`` px along a polyline (arc length), the first included."""
    pts = np.vstack([line, line[:1]]) if closed else line
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    n = max(int(total // spacing), 3 if closed else 2)
    at = np.linspace(0.0, total, n, endpoint=not closed)
    return np.column_stack([np.interp(at, s, pts[:, 0]), np.interp(at, s, pts[:, 1])])


def propose_outline(
    image: Any,
    outline_px: np.ndarray,
    closed: bool,
    size: tuple[int, int],
    *,
    spacing_px: float = 40.0,
    cost: np.ndarray | None = None,
    sigma_px: float = 1.5,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The projected outline snapped to the image's edges.

    Anchors are taken every ``spacing_px`` along ``outline_px`` (the part inside the ``(W, H)``
    image: the longest run inside it when the outline leaves it) and joined by
    :func:`biplanar_reg.annotation.livewire`. Returns ``(contour uv, anchors, closed)``,
    pixels. Raises ``ValueError`` when too little of the outline is inside the image.
    """
    line = np.asarray(outline_px, float)
    w, h = size
    inside = (line[:, 0] >= 0) & (line[:, 0] <= w - 1) & (line[:, 1] >= 0) & (line[:, 1] <= h - 1)
    if not inside.all():
        closed = False
        line = _longest_run(line, inside)
    if len(line) < 2 or np.linalg.norm(np.diff(line, axis=0), axis=1).sum() < 2 * spacing_px:
        raise ValueError("view: the posed outline is (almost) outside the image")
    anchors = _resample_closed(line, closed, spacing_px)
    uv = livewire(image, anchors, closed, sigma_px=sigma_px, cost=cost)
    return uv, anchors, closed


def _longest_run(line: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The longest run of consecutive kept points (a closed line is rolled to start outside)."""
    if not keep.any():
        return line[:0]
    start = int(np.argmin(keep))  # an outside point first, so no run wraps around
    line, keep = np.roll(line, -start, axis=0), np.roll(keep, -start)
    best, cur = (0, 0), None
    for i, k in enumerate([*keep, False]):
        if k and cur is None:
            cur = i
        elif not k and cur is not None:
            best = max(best, (cur, i), key=lambda r: r[1] - r[0])
            cur = None
    return line[best[0] : best[1]]


_REGISTRATION = re.compile(r"^\s*\[registration\]\s*(#.*)?$")
_TABLE = re.compile(r"^\s*\[")
_START_KEY = re.compile(r"^\s*start\s*=")


def _with_start_key(toml_text: str, name: str) -> str:
    """``case.toml``'s text with ``[registration] start = "name"`` set (other lines kept)."""
    lines = toml_text.splitlines()
    entry = f'start = "{name}"'
    at = next((i for i, line in enumerate(lines) if _REGISTRATION.match(line)), None)
    if at is None:
        body = toml_text.rstrip("\n")
        return f"{body}\n\n[registration]\n{entry}\n"
    end = next((j for j in range(at + 1, len(lines)) if _TABLE.match(lines[j])), len(lines))
    for j in range(at + 1, end):
        if _START_KEY.match(lines[j]):
            lines[j] = entry
            break
    else:
        lines.insert(at + 1, entry)
    return "\n".join(lines) + "\n"


def write_start(
    case_dir: str | os.PathLike, R: np.ndarray, t: np.ndarray, units: str = "mm"
) -> Path:
    """Save ``(R, t)`` (model -> world, mm) as the case's start pose: ``CASE_DIR/start.json``
    ``{"R": [[3x3]], "t": [3]}`` in the case's units, and ``[registration] start =
    "start.json"`` in ``case.toml`` (both atomic; the rest of ``case.toml`` is kept as it is).
    Returns the start file's path."""
    case_dir = Path(case_dir)
    toml_path = case_dir / "case.toml"
    text = toml_path.read_text(encoding="utf-8")
    new_text = _with_start_key(text, START_NAME)
    tomllib.loads(new_text)  # never write a case.toml the loader cannot parse
    path = case_dir / START_NAME
    scale = UNIT_SCALE[units]
    atomic_write_json(
        path, {"R": np.asarray(R, float).tolist(), "t": (np.asarray(t, float) / scale).tolist()}
    )
    if new_text != text:
        atomic_write_text(toml_path, new_text)
    return path


def _clicks(doc: Mapping[str, Any]) -> dict[str, dict[str, list[float]]]:
    """``{view: {landmark: [u, v]}}`` of an annotation document."""
    return {
        view: {n: list(lm["uv"]) for n, lm in va.get("landmarks", {}).items()}
        for view, va in doc.get("views", {}).items()
    }


def _key(clicks: Mapping[str, Mapping[str, Any]], landmarks: Mapping[str, int]) -> tuple:
    flat = sorted((v, n, *map(float, uv)) for v, c in clicks.items() for n, uv in c.items())
    return tuple(flat), tuple(sorted(landmarks.items()))


class PoseAid:
    """The pose aid of an open workbench: the landmark pose, the user's nudges, the drawing.

    The pose follows the landmark clicks: each change of the clicks (or of the model's
    landmarks) recomputes it and drops the nudges made on the previous one; nudges move the
    current pose until then (:meth:`reset` drops them).

    Parameters
    ----------
    wb : Workbench
        The open case (its annotations, views and model landmarks are read at each call).
    """

    def __init__(self, wb: Any):
        self.wb = wb
        self._lock = threading.Lock()
        self._mean: tuple[np.ndarray, np.ndarray | None] | None = None
        self._pose: tuple[tuple, np.ndarray, np.ndarray] | None = None  # key, R, t (landmarks)
        self._nudged: tuple[tuple, np.ndarray, np.ndarray] | None = None  # key, R, t

    def mean(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The model's mean shape (mm) and faces, read once."""
        if self._mean is None:
            self._mean = mean_shape(self.wb.setup)
        return self._mean

    def _landmark_pose(self) -> tuple[tuple, np.ndarray, np.ndarray] | str:
        """``(key, R, t)`` from the current clicks, or the reason there is none."""
        landmarks = dict(self.wb.landmarks)
        clicks = _clicks(self.wb.annotations_document())
        key = _key(clicks, landmarks)
        if self._pose is not None and self._pose[0] == key:
            return self._pose
        ids, origins, dirs, names = landmark_observations(self.wb.setup.views, clicks, landmarks)
        why = pose_ready(names)
        if why is not None:
            return why
        mean, faces = self.mean()
        R, t = landmark_pose(mean, faces, ids, origins, dirs)
        self._pose = (key, R, t)
        return self._pose

    def _current(self) -> tuple[np.ndarray, np.ndarray, str] | str:
        base = self._landmark_pose()
        if isinstance(base, str):
            return base
        if self._nudged is not None and self._nudged[0] == base[0]:
            return self._nudged[1], self._nudged[2], "nudged"
        self._nudged = None
        return base[1], base[2], "landmarks"

    def document(self) -> dict[str, Any]:
        """``GET /api/pose-aid``: ``{"ready", "reason"?, "source": "landmarks"|"nudged", "R",
        "t" (mm), "views": {view: {"outline_px", "outline_closed", "landmarks_px"}},
        "seconds"}`` (``seconds``: the server's time for this answer)."""
        t0 = time.perf_counter()
        with self._lock:
            cur = self._current()
            if isinstance(cur, str):
                return {"ready": False, "reason": cur, "seconds": time.perf_counter() - t0}
            R, t, source = cur
            mean, faces = self.mean()
            views = posed_overlay(mean, faces, R, t, self.wb.setup.views, self.wb.landmarks)
        return {
            "ready": True,
            "source": source,
            "R": np.round(R, 9).tolist(),
            "t": np.round(t, 6).tolist(),
            "views": views,
            "seconds": time.perf_counter() - t0,
        }

    def _need(self) -> tuple[np.ndarray, np.ndarray]:
        cur = self._current()
        if isinstance(cur, str):
            raise Conflict(f"pose aid: no pose yet ({cur})")
        return cur[0], cur[1]

    def nudge(self, view: object, translate_px: object, rotate_deg: object) -> dict[str, Any]:
        """Move the current pose in ``view``'s plane: ``translate_px`` ``[du, dv]`` pixels and/or
        ``rotate_deg`` degrees (clockwise on the screen) about the bone's centre."""
        cv = self._case_view(view)
        d_uv = None if translate_px is None else check_point(translate_px, "translate_px", None)
        angle = None
        if rotate_deg is not None:
            if not _finite(rotate_deg) or abs(rotate_deg) > 360:
                raise ValueError(f"rotate_deg: expected degrees in -360..360, got {rotate_deg!r}")
            angle = float(rotate_deg)
        if d_uv is None and angle is None:
            raise ValueError("translate_px: missing (give translate_px [du, dv] or rotate_deg)")
        with self._lock:
            R, t = self._need()
            mean = self.mean()[0]
            if d_uv is not None:
                R, t = nudge_translate(mean, R, t, cv.view, d_uv)
            if angle is not None:
                R, t = nudge_rotate(mean, R, t, cv.view, angle)
            self._nudged = (self._pose[0], R, t)
        return self.document()

    def reset(self) -> dict[str, Any]:
        """Drop the nudges: back to the landmark pose."""
        with self._lock:
            self._nudged = None
        return self.document()

    def save_start(self) -> dict[str, Any]:
        """Write the current pose as the case's start pose (:func:`write_start`)."""
        with self._lock:
            R, t = self._need()
            path = write_start(self.wb.case_dir, R, t, self.wb.setup.units)
        return {"file": path.name, "R": R.tolist(), "t": t.tolist()}

    def _case_view(self, view: object) -> CaseView:
        for cv in self.wb.setup.views:
            if cv.name == view:
                return cv
        raise NotFound(f"view: unknown view {view!r} (views: {', '.join(self.wb.views)})")

    def propose(self, view: str, spacing_px: object) -> dict[str, Any]:
        """``POST /api/views/{view}/propose-outline``: the longest posed outline of ``view``
        snapped to its edges, ``{"uv", "anchors", "closed", "seconds"}`` (not saved: the
        page offers it to accept, as a contour through those anchors)."""
        t0 = time.perf_counter()
        cv = self._case_view(view)
        v = self.wb.views[cv.name]
        v.need_image()
        spacing = check_positive(spacing_px, "spacing_px", 40.0)
        if not 5.0 <= spacing <= 500.0:
            raise ValueError(f"spacing_px: expected 5 to 500 pixels, got {spacing:g}")
        with self._lock:
            R, t = self._need()
            mean, faces = self.mean()
        lines, closed = outline_polylines(mean @ R.T + t, cv.view, faces)
        if not lines:
            raise Conflict(f"view {view!r}: the posed model has no outline in this view")
        uv, anchors, is_closed = propose_outline(
            v.image, lines[0], bool(closed[0]), v.size, spacing_px=spacing, cost=v.cost()
        )
        return {
            "uv": np.round(uv, 3).tolist(),
            "anchors": np.round(anchors, 3).tolist(),
            "closed": is_closed,
            "seconds": time.perf_counter() - t0,
        }


def _finite(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
