"""The pose aid: the model's mean shape posed by the clicked landmarks, drawn over each view.

Pure functions on numpy arrays: the mean shape of a case's model (:func:`mean_shape`), the
rigid pose that the landmark clicks fix (:func:`landmark_pose`, a G-SfT solve of the mean shape
without modes, as the registration's rigid mean-shape start) or why they fix none
(:func:`pose_ready`), the posed outline, landmarks and nudge axes in each view
(:func:`posed_overlay`), and the start-pose file (:func:`write_start`, :func:`read_start`).
:class:`PoseAid` keeps an open case's pose: the landmark pose, the user's nudges and typed
fields (:mod:`.pose_nudge`), their undo steps, and "propose outline"
(:mod:`.posed_outline`).

Frames: model coordinates in mm (the case's units scaled to mm), world = the calibration's
frame, mm; a pose (:class:`~biplanar_reg.pose.Pose`) maps model to world, ``X = R @ x + t``.
Pixels ``(u, v)`` as in the annotation format.
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

from .._validate import check_rotation
from ..cases import CaseSetup
from ..cases.case import UNIT_SCALE, CaseView
from ..io import atomic_write_json, atomic_write_text, read_json, read_mesh
from ..outline import cut_vertices
from ..pose import Pose
from ..registration import RayObservations, solve_gsft
from ..ssm import ShapeModel
from .pose_nudge import (
    axes_overlay,
    euler_xyz,
    nudge_frame,
    nudge_rotate,
    nudge_translate,
    pose_from_fields,
)
from .posed_outline import outline_pieces, propose_pieces
from .session import Conflict, NotFound, check_point, check_positive

__all__ = [
    "MIN_OBSERVATIONS",
    "mean_shape",
    "landmark_observations",
    "pose_ready",
    "landmark_pose",
    "posed_overlay",
    "write_start",
    "read_start",
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


def pose_ready(ids: Sequence[int], view_names: Sequence[str]) -> str | None:
    """None when these landmark observations (model vertex ids, one view name each) fix a
    rigid pose, else the reason, in the user's terms: the one place that says why the pose aid
    is not drawn (the rules of the registration's rigid start, ``check_rays``)."""
    n, k, distinct = len(view_names), len(set(view_names)), len(set(map(int, ids)))
    if n >= MIN_OBSERVATIONS and k >= 2 and distinct >= 3:
        return None
    needs = []
    if n < MIN_OBSERVATIONS:
        needs.append(f"{MIN_OBSERVATIONS} landmark clicks")
    if k < 2:
        needs.append("clicks in at least 2 views")
    if distinct < 3:
        needs.append("3 distinct landmarks (fewer than 3 distinct model points fix no pose)")
    return (
        f"{n} landmark click(s) of {distinct} distinct landmark(s) in {k} view(s); the pose "
        f"aid needs {' and '.join(needs)}"
    )


def landmark_pose(
    mean: np.ndarray,
    faces: np.ndarray | None,
    ids: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
) -> Pose:
    """The rigid pose (model -> world, mm) of the mean shape that the landmark rays fix:
    G-SfT with no modes (the registration's rigid mean-shape start, equal weights)."""
    rigid = ShapeModel(mean, np.zeros((0, mean.shape[0], 3)), faces=faces)
    res = solve_gsft(rigid, RayObservations(ids, origins, directions))
    return Pose(res.rotation, res.translation)


def posed_overlay(
    mean: np.ndarray,
    faces: np.ndarray | None,
    pose: Pose,
    views: Sequence[CaseView],
    landmarks: Mapping[str, int],
    cut: np.ndarray | None = None,
) -> dict[str, dict[str, Any]]:
    """What the page draws per view: ``{view: {"outline_px", "outline_closed",
    "landmarks_px", "centre_px", "axes", "camera"}}`` of the mean shape posed by ``pose``
    (pixels; ``camera``: the view's ``"forward"`` and ``"up"`` unit vectors at the bone, world
    frame, for a 3D view oriented like the radiograph).

    The outline is every piece of :func:`~.posed_outline.outline_pieces` without the template's
    cut (``cut``), longest first; the centre is the posed vertices' mean, about which nudges
    turn; ``axes`` the nudge axes of every view drawn in this one (:func:`axes_overlay`, a
    quarter of the bone's largest extent long).
    """
    V = pose.apply(mean)
    names = [n for n, i in landmarks.items() if 0 <= i < len(V)]
    ids = np.array([landmarks[n] for n in names], np.int64)
    out = {}
    centre = V.mean(axis=0)
    axes = axes_overlay(centre, views, 0.25 * float(np.ptp(V, axis=0).max()))
    for cv in views:
        _, ev, k = nudge_frame(cv.view, centre)
        lines, closed = outline_pieces(V, faces, cv.view, cut, min_length_px=0.0)
        uv = cv.view.project(V[ids]) if len(ids) else np.zeros((0, 2))
        out[cv.name] = {
            "centre_px": np.round(cv.view.project(centre[None])[0], 2).tolist(),
            "outline_px": [np.round(line, 2).tolist() for line in lines],
            "outline_closed": [bool(c) for c in closed],
            "landmarks_px": {n: np.round(p, 2).tolist() for n, p in zip(names, uv, strict=True)},
            "axes": axes[cv.name],
            "camera": {"forward": np.round(k, 9).tolist(), "up": np.round(-ev, 9).tolist()},
        }
    return out


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


def write_start(case_dir: str | os.PathLike, pose: Pose, units: str = "mm") -> Path:
    """Save ``pose`` (model -> world, mm) as the case's start pose: ``CASE_DIR/start.json``
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
    atomic_write_json(path, {"R": pose.R.tolist(), "t": (pose.t / scale).tolist()})
    if new_text != text:
        atomic_write_text(toml_path, new_text)
    return path


def read_start(case_dir: str | os.PathLike, units: str = "mm") -> Pose:
    """The case's saved start pose (model -> world, ``t`` in mm; ``[registration] start`` of
    ``case.toml``).

    Raises ``FileNotFoundError`` when the case has none, ``ValueError`` (naming the key) when
    it cannot be read: the loader refuses that case as well (``docs/cases.md``)."""
    case_dir = Path(case_dir).resolve()
    doc = tomllib.loads((case_dir / "case.toml").read_text(encoding="utf-8"))
    reg = doc.get("registration")
    name = reg.get("start") if isinstance(reg, dict) else None
    if name is None:
        raise FileNotFoundError("case.toml: no [registration] start")
    path = (case_dir / str(name)).resolve()
    if not path.is_relative_to(case_dir):
        raise ValueError(f"[registration] start: {name!r} is outside the case folder")
    start = read_json(path)
    if not isinstance(start, dict):
        raise ValueError(f'[registration] start: {name}: expected {{"R": [[3x3]], "t": [3]}}')
    R = check_rotation("R", np.asarray(start.get("R"), float), tol=1e-4)
    t = np.asarray(start.get("t"), float).reshape(3) * UNIT_SCALE[units]
    return Pose(R, t)


def _clicks(doc: Mapping[str, Any]) -> dict[str, dict[str, list[float]]]:
    """``{view: {landmark: [u, v]}}`` of an annotation document."""
    return {
        view: {n: list(lm["uv"]) for n, lm in va.get("landmarks", {}).items()}
        for view, va in doc.get("views", {}).items()
    }


def _key(clicks: Mapping[str, Mapping[str, Any]], landmarks: Mapping[str, int]) -> tuple:
    flat = sorted((v, n, *map(float, uv)) for v, c in clicks.items() for n, uv in c.items())
    return tuple(flat), tuple(sorted(landmarks.items()))


def _finite(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _vector3(x: object, field: str, limit: float) -> np.ndarray:
    """Three finite numbers within +-``limit`` (a pose field), else ``ValueError`` naming it."""
    ok = isinstance(x, list) and len(x) == 3 and all(_finite(v) for v in x)
    if not ok or max(abs(float(v)) for v in x) > limit:
        raise ValueError(f"{field}: expected 3 numbers within +-{limit:g}, got {x!r}")
    return np.asarray(x, float)


#: Pose steps kept for undo.
UNDO_STEPS = 100


class PoseAid:
    """The pose aid of an open workbench: the pose, its undo steps, the drawing.

    The pose is the landmark pose (solved from the clicks, and solved again when they change)
    until the user moves it: a nudge, typed fields or the saved start pose (read when the case
    is opened) make it the user's pose, which then stays as it is through landmark edits
    (``"landmarks_changed"`` says when the clicks changed since); "From landmarks"
    (:meth:`reset`) goes back to the landmark pose. Every change can be undone
    (:meth:`undo`, ``UNDO_STEPS`` steps).

    Parameters
    ----------
    wb : Workbench
        The open case (its annotations, views and model landmarks are read at each call).
    """

    def __init__(self, wb: Any):
        self.wb = wb
        self._lock = threading.Lock()
        self._mean: tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None = None
        self._pose: tuple[tuple, Pose] | None = None  # key, the landmark pose
        # the user's pose: {"pose", "source": nudged|typed|start, "key": the clicks then}
        self._user: dict[str, Any] | None = None
        self._undo: list[dict[str, Any] | None] = []
        self._saved: Pose | None = None
        self._start_note = ""
        try:
            pose = read_start(wb.case_dir, wb.setup.units)
            self._user = {"pose": pose, "source": "start", "key": None}
            self._saved = pose
        except FileNotFoundError:
            pass
        except (ValueError, OSError, tomllib.TOMLDecodeError) as exc:
            self._start_note = f"the saved start pose is not used: {exc}"

    def mean(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The model's mean shape (mm) and faces, read once."""
        return self._model()[:2]

    def _model(self) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Mean (mm), faces and the template's cut (:func:`cut_vertices`), computed once."""
        if self._mean is None:
            mean, faces = mean_shape(self.wb.setup)
            cut = None if faces is None else cut_vertices(mean, faces)
            self._mean = (mean, faces, cut)
        return self._mean

    def _landmark_pose(self) -> tuple[tuple, Pose] | str:
        """``(key, pose)`` from the current clicks, or the reason there is none."""
        landmarks = dict(self.wb.landmarks)
        clicks = _clicks(self.wb.annotations_document())
        key = _key(clicks, landmarks)
        if self._pose is not None and self._pose[0] == key:
            return self._pose
        ids, origins, dirs, names = landmark_observations(self.wb.setup.views, clicks, landmarks)
        why = pose_ready(ids, names)
        if why is not None:
            return why
        mean, faces = self.mean()
        try:
            pose = landmark_pose(mean, faces, ids, origins, dirs)
        except ValueError as exc:  # e.g. every ray parallel: the solver's own reason
            return f"the landmark clicks fix no pose: {exc}"
        self._pose = (key, pose)
        return self._pose

    def _current(self) -> tuple[Pose, str, bool] | str:
        """``(pose, source, landmarks changed since)`` or the reason there is no pose."""
        base = self._landmark_pose()
        if self._user is not None:
            u = self._user
            changed = u["key"] is not None and not isinstance(base, str) and base[0] != u["key"]
            return u["pose"], u["source"], changed
        if isinstance(base, str):
            return base + (f" ({self._start_note})" if self._start_note else "")
        return base[1], "landmarks", False

    def document(self) -> dict[str, Any]:
        """``GET /api/pose-aid``: ``{"ready": false, "reason"}`` or ``{"ready": true, "source":
        "landmarks"|"nudged"|"typed"|"start", "landmarks_changed", "saved", "undo", "R", "t"
        (mm), "centre_mm", "angles_deg" (:func:`~.pose_nudge.euler_xyz`), "views": {view:
        ...}}`` (:func:`posed_overlay`), with ``"seconds"``, the server's time for it."""
        t0 = time.perf_counter()
        with self._lock:
            cur = self._current()
            if isinstance(cur, str):
                return {"ready": False, "reason": cur, "undo": len(self._undo),
                        "seconds": time.perf_counter() - t0}  # fmt: skip
            return self._posed_document(*cur, t0)

    def _posed_document(self, pose: Pose, source: str, changed: bool, t0: float) -> dict[str, Any]:
        """The document of ``pose`` (the lock held)."""
        mean, faces, cut = self._model()
        views = posed_overlay(mean, faces, pose, self.wb.setup.views, self.wb.landmarks, cut)
        saved = self._saved is not None and all(
            np.allclose(a, b, atol=1e-9) for a, b in zip(self._saved.rt, pose.rt, strict=True)
        )
        return {
            "ready": True,
            "source": source,
            "landmarks_changed": changed,
            "saved": saved,
            "undo": len(self._undo),
            "R": np.round(pose.R, 9).tolist(),
            "t": np.round(pose.t, 6).tolist(),
            "centre_mm": np.round(pose.apply(mean.mean(axis=0)), 3).tolist(),
            "angles_deg": np.round(euler_xyz(pose.R), 3).tolist(),
            "views": views,
            "seconds": time.perf_counter() - t0,
        }

    def _need(self) -> Pose:
        """The current pose; ``Conflict`` when there is none."""
        cur = self._current()
        if isinstance(cur, str):
            raise Conflict(f"pose aid: no pose yet ({cur})")
        return cur[0]

    def _set_user(self, pose: Pose, source: str) -> None:
        """Make ``pose`` the user's pose, the previous one kept as an undo step."""
        base = self._pose[0] if self._pose is not None else None
        self._undo = [*self._undo, self._user][-UNDO_STEPS:]
        self._user = {"pose": pose, "source": source, "key": base}

    def nudge(
        self, view: object, translate_px: object, rotate_deg: object, preview: object = False
    ) -> dict[str, Any]:
        """Move the pose in ``view``'s plane (:mod:`.pose_nudge`): ``translate_px`` ``[du, dv]``
        pixels and/or ``rotate_deg`` degrees (clockwise on the screen) about the bone's
        centre. ``preview``: answer the document of the moved pose without keeping it (the
        page draws a drag's pose in every view while it lasts)."""
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
            pose = self._need()
            mean = self.mean()[0]
            if d_uv is not None:
                pose = nudge_translate(mean, pose, cv.view, d_uv)
            if angle is not None:
                pose = nudge_rotate(mean, pose, cv.view, angle)
            if preview is True:
                return self._posed_document(pose, "preview", False, time.perf_counter())
            self._set_user(pose, "nudged")
        return self.document()

    def set_fields(self, centre_mm: object, angles_deg: object) -> dict[str, Any]:
        """``POST /api/pose-aid/set``: the pose whose bone centre is ``centre_mm`` (world, mm)
        and whose rotation is ``angles_deg`` (x, y, z about the world axes,
        :func:`~.pose_nudge.rotation_xyz`)."""
        c = _vector3(centre_mm, "centre_mm", 1e6)
        a = _vector3(angles_deg, "angles_deg", 360.0)
        with self._lock:
            self._need()
            self._set_user(pose_from_fields(self.mean()[0], c, a), "typed")
        return self.document()

    def reset(self) -> dict[str, Any]:
        """Back to the landmark pose (an undo step)."""
        with self._lock:
            if self._user is not None:
                self._undo = [*self._undo, self._user][-UNDO_STEPS:]
                self._user = None
        return self.document()

    def undo(self) -> dict[str, Any]:
        """Undo the last pose change (409 when there is none)."""
        with self._lock:
            if not self._undo:
                raise Conflict("pose aid: nothing to undo")
            self._user = self._undo.pop()
        return self.document()

    def save_start(self) -> dict[str, Any]:
        """Write the current pose as the case's start pose (:func:`write_start`)."""
        with self._lock:
            pose = self._need()
            path = write_start(self.wb.case_dir, pose, self.wb.setup.units)
            self._saved = pose
        return {"file": path.name, "R": pose.R.tolist(), "t": pose.t.tolist()}

    def _case_view(self, view: object) -> CaseView:
        for cv in self.wb.setup.views:
            if cv.name == view:
                return cv
        raise NotFound(f"view: unknown view {view!r} (views: {', '.join(self.wb.views)})")

    def propose(self, view: str, spacing_px: object) -> dict[str, Any]:
        """``POST /api/views/{view}/propose-outline``: every piece of the posed outline of
        ``view`` (:func:`~.posed_outline.outline_pieces`: not the template's cut, none shorter
        than ``MIN_PIECE_PX``) snapped to the image's edges, ``{"pieces": [{"uv", "anchors",
        "closed"}, ...], "seconds"}`` (not saved: the page offers them to accept, each as a
        contour through its anchors)."""
        t0 = time.perf_counter()
        cv = self._case_view(view)
        v = self.wb.views[cv.name]
        v.need_image()
        spacing = check_positive(spacing_px, "spacing_px", 40.0)
        if not 5.0 <= spacing <= 500.0:
            raise ValueError(f"spacing_px: expected 5 to 500 pixels, got {spacing:g}")
        with self._lock:
            pose = self._need()
            mean, faces, cut = self._model()
        lines, closed = outline_pieces(pose.apply(mean), faces, cv.view, cut, v.size)
        if not lines:
            raise Conflict(f"view {view!r}: the posed model has no outline inside the image")
        pieces = propose_pieces(v.image, lines, closed, spacing_px=spacing, cost=v.cost())
        return {
            "pieces": [
                {
                    "uv": np.round(p["uv"], 3).tolist(),
                    "anchors": np.round(p["anchors"], 3).tolist(),
                    "closed": p["closed"],
                }
                for p in pieces
            ],
            "seconds": time.perf_counter() - t0,
        }
