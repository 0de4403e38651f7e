"""One open case folder: its lock, its views, and every edit saved as it is made.

A :class:`Workbench` reads the case with :func:`biplanar_reg.cases.read_case_setup` (the case
loader's rules: paths resolved and kept inside the case folder), holds the lock file
``CASE_DIR/.workbench.lock`` while it is open, and saves each edit at once, atomically, in the
documented formats: ``annotations.json`` (``biplanar-reg/annotations@1``, through
:func:`biplanar_reg.annotation.save_annotations`) and ``model/landmarks.json`` (``{"name":
vertex index}``), so ``biplanar-reg register CASE_DIR`` runs the edited case unchanged. The
livewire anchors of each contour, which the annotation format has no place for, are kept in
``CASE_DIR/.workbench.json`` (the workbench's own file; ``register`` does not read it).

Inputs are checked before anything is written; a bad one raises ``ValueError`` whose message
starts with the field (``uv: ...``, ``anchors[2]: ...``), an unknown view or contour raises
:class:`NotFound`, an edit that cannot be applied now raises :class:`Conflict`. Pixels are
``(u, v)`` = (column, row), 0-based, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..annotation import (
    Annotations,
    Contour,
    Landmark,
    ViewAnnotations,
    livewire,
    load_annotations,
    save_annotations,
    snap_landmark,
)
from ..annotation.features import edge_cost
from ..annotation.snap import MAX_RADIUS_PX
from ..cases import CaseSetup, read_case_setup
from ..cases.case import CaseView
from ..errors import CaseError, one_line
from ..io import atomic_write_json, read_json
from .caselock import CaseLock
from .checks import (  # the others import some of these from here
    MAX_POINTS,  # noqa: F401
    check_flag,
    check_point,
    check_points,
    check_positive,
    check_version,  # noqa: F401
    require_version,  # noqa: F401
    short,
)
from .contour_ids import ContourIds
from .failures import Conflict, NotFound, StaleContour, WorkbenchError  # noqa: F401
from .history import History, NothingToUndo
from .tiles import TILE_SIZE, Pyramid

__all__ = ["Workbench", "WorkbenchError"]

log = logging.getLogger(__name__)

LOCK_NAME = ".workbench.lock"
STATE_NAME = ".workbench.json"
STATE_FORMAT = "biplanar-reg/workbench-state@1"
#: Livewire edge-cost scale (the default of :func:`biplanar_reg.annotation.livewire`), pixels.
LIVEWIRE_SIGMA_PX = 1.5
MAX_ANCHORS = 2_000


_ALLOW_OUTSIDE = re.compile(r"\s*\(pass --allow-outside to permit it\)")
INSIDE_ONLY = (
    "(the workbench opens only files inside it: move or copy the file into the case folder)"
)


def inside_only(message: str) -> str:
    """A case loader's message without its ``--allow-outside`` advice (an option of
    ``register`` and ``batch``, not of the workbench, which writes into the folder)."""
    return _ALLOW_OUTSIDE.sub(" " + INSIDE_ONLY, message)


# -- one view -------------------------------------------------------------------------------------


class _View:
    """A view of the open case with its lazily built tile pyramid and livewire cost."""

    def __init__(self, cv: CaseView):
        self.cv = cv
        self.name = cv.name
        self.image = cv.image
        self.size = cv.image_size  # (W, H) or None
        self._pyramid: Pyramid | None = None
        self._cost: np.ndarray | None = None
        self._lock = threading.Lock()

    def need_image(self) -> None:
        if self.image is None:
            raise NotFound(f"view {self.name!r}: has no image (case.toml [[views]] image)")

    def pyramid(self) -> Pyramid:
        self.need_image()
        with self._lock:
            if self._pyramid is None:
                self._pyramid = Pyramid(self.image, TILE_SIZE)
            return self._pyramid

    def cost(self) -> np.ndarray:
        """The livewire edge cost of the whole image, computed once (~0.15 s on 1760 px)."""
        self.need_image()
        with self._lock:
            if self._cost is None:
                disp = self.image.display.astype(np.float64)
                self._cost = edge_cost(disp, LIVEWIRE_SIGMA_PX)
            return self._cost

    def info(self) -> dict[str, Any]:
        """The view's entry of ``GET /api/case``."""
        w, h = self.size if self.size is not None else (None, None)
        entry: dict[str, Any] = {"name": self.name, "width": w, "height": h}
        if self.image is None:
            return {**entry, "has_image": False, "levels": 0, "tile_size": TILE_SIZE,
                    "window": None, "range": None}  # fmt: skip
        p = self.pyramid()
        return {
            **entry,
            "has_image": True,
            "levels": p.levels,
            "tile_size": p.tile_size,
            "window": list(p.window),
            "range": list(p.range),
            "inverted": p.inverted,
            "file_format": self.image.file_format,
        }


def _copy(ann: Annotations) -> Annotations:
    """A copy that can be edited without touching ``ann`` (landmarks and contours are frozen)."""
    return Annotations(
        views={
            n: ViewAnnotations(landmarks=dict(v.landmarks), contours=list(v.contours))
            for n, v in ann.views.items()
        }
    )


def _stamp(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_mtime_ns, st.st_size


def _fingerprint(contour: Contour) -> dict[str, Any]:
    """What ties saved anchors to their contour: its point count and first point."""
    return {"n": len(contour.uv), "first": [float(x) for x in contour.uv[0]]}


def _anchors_of(entry: object, contour: Contour) -> list[list[float]] | None:
    """The anchors of a state-file entry if the entry still describes ``contour``."""
    if not isinstance(entry, dict) or not isinstance(entry.get("anchors"), list):
        return None
    fp = _fingerprint(contour)
    first = entry.get("first")
    if entry.get("n") != fp["n"] or not isinstance(first, list) or len(first) != 2:
        return None
    if not np.allclose(first, fp["first"], atol=1e-6):
        return None  # the contour was replaced outside the workbench
    return entry["anchors"]


def _rounded(points: np.ndarray, digits: int = 3) -> list[list[float]]:
    """Points as JSON lists; a thousandth of a pixel is below any annotation's precision."""
    return np.round(np.asarray(points, float), digits).tolist()


class Workbench:
    """One case folder opened for editing.

    Parameters
    ----------
    case_dir : path
        The case folder (``case.toml``; see ``docs/cases.md``). Its annotation file and its
        ``[model] landmarks`` file may not exist yet: they are created by the first edit.
    port : int
        Recorded in the lock file (update it with :meth:`set_port` once the server listens).

    Raises
    ------
    CaseError
        The case folder is invalid (names the file and key).
    WorkbenchError
        Another workbench holds the folder's lock (``CASE_DIR/.workbench.lock``).
    AnnotationError
        The existing annotation file is invalid for the case.
    """

    def __init__(self, case_dir: str | os.PathLike, *, port: int = 0):
        try:
            setup = read_case_setup(case_dir)  # CaseError before any file is created
        except CaseError as exc:
            raise CaseError(inside_only(str(exc))) from None
        self.setup: CaseSetup = setup
        self.case_dir: Path = setup.case_dir
        self._lock = CaseLock(self.case_dir / LOCK_NAME, {"pid": os.getpid(), "port": port})
        self._lock.acquire()
        try:
            self._open(setup)
        except BaseException:
            self._lock.release()
            raise

    def _open(self, setup: CaseSetup) -> None:
        from .jobs import RegistrationJob

        self.views: dict[str, _View] = {cv.name: _View(cv) for cv in setup.views}
        self.landmarks: dict[str, int] = dict(setup.landmarks)
        self._edit = threading.RLock()  # one edit at a time: read, change, save
        self._ann_path = setup.annotations_path
        self._ids = ContourIds()
        self._ann, self._ann_stamp = self._read_annotations()
        self._ids.follow(None, self._ann)
        self._state_path = self.case_dir / STATE_NAME
        self._anchors = self._read_state()
        self.history = History(self._edit)  # undo / redo of this launch (history.py)
        self.history.part("annotations", lambda: self._ann, self._restore_annotations)
        self.history.part("anchors", lambda: self._anchors, self._restore_anchors)
        self.history.part("landmarks", lambda: self.landmarks, self._restore_landmarks)
        self.job = RegistrationJob(self.case_dir, self.out_dir)
        self._review: tuple[object, dict[str, Any]] | None = None

    # -- lifetime -------------------------------------------------------------------------------

    @property
    def lock_path(self) -> Path:
        """``CASE_DIR/.workbench.lock``."""
        return self._lock.path

    @property
    def edit_lock(self) -> threading.RLock:
        """Held by every edit (read, change, save) and by undo / redo."""
        return self._edit

    @property
    def out_dir(self) -> Path:
        """Where the registration writes (``CASE_DIR/out``, as ``biplanar-reg register``)."""
        return self.case_dir / "out"

    def set_port(self, port: int) -> None:
        """Record the server's port in the lock file."""
        self._lock.update(port=port)

    def close(self) -> None:
        """Release the lock (edits are already saved)."""
        self._lock.release()

    def __enter__(self) -> Workbench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def warm_up(self) -> None:
        """Build every view's tile levels and livewire cost now (the first requests are then
        fast); meant for a background thread."""
        for v in self.views.values():
            if v.image is not None:
                p = v.pyramid()
                p.level(p.levels - 1)
                v.cost()
                # a tiny trace fills the sub-pixel fit's template cache, so that the first
                # preview is as fast as the next ones
                livewire(v.image, [[0, 0], [4, 4]], sigma_px=LIVEWIRE_SIGMA_PX, cost=v.cost())

    # -- reading --------------------------------------------------------------------------------

    def _sizes(self) -> dict[str, tuple[int, int]]:
        return {n: v.size for n, v in self.views.items() if v.size is not None}

    def _read_annotations(self) -> tuple[Annotations, tuple[int, int] | None]:
        stamp = _stamp(self._ann_path)
        if stamp is None:
            return Annotations(), None
        ann = load_annotations(
            self._ann_path,
            known_views=list(self.views),
            known_landmarks=self.landmarks,
            image_sizes=self._sizes(),
        )
        return ann, stamp

    def _read_state(self) -> dict[str, list[Any]]:
        """The contour anchors of ``.workbench.json`` (a bad file is ignored: only anchors)."""
        if not self._state_path.is_file() or not self._inside(self._state_path):
            return {}
        try:
            doc = read_json(self._state_path)
            anchors = doc["contour_anchors"]
            return {str(k): list(v) for k, v in anchors.items() if isinstance(v, list)}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            log.warning("%s: ignored (%s)", self._state_path, one_line(exc))
            return {}

    def _current(self) -> Annotations:
        """The annotations, re-read when the file was changed outside the workbench."""
        with self._edit:
            stamp = _stamp(self._ann_path)
            if stamp != self._ann_stamp:
                try:
                    ann, self._ann_stamp = self._read_annotations()
                    self._ids.follow(self._ann, ann)
                    self._ann = ann
                except ValueError as exc:
                    raise Conflict(
                        f"{self._ann_path.name}: changed outside the workbench and is not valid "
                        f"now: {one_line(exc)}"
                    ) from None
                log.info("%s: changed on disk, re-read", self._ann_path)
                # undoing would overwrite what the other program wrote
                self.history.clear(
                    f"the undo history was cleared: {self._ann_path.name} was changed outside "
                    f"the workbench at {time.strftime('%H:%M:%S')}"
                )
            return self._ann

    def _inside(self, path: Path) -> bool:
        """Whether ``path`` (symlinks resolved) stays inside the case folder."""
        return path.resolve().is_relative_to(self.case_dir)

    def _view(self, name: str) -> _View:
        v = self.views.get(name)
        if v is None:
            raise NotFound(f"view: unknown view {name!r} (views: {', '.join(self.views)})")
        return v

    def _known_landmark(self, name: str) -> None:
        if name not in self.landmarks:
            known = ", ".join(self.landmarks) or "none"
            raise ValueError(f"name: unknown landmark {name!r} (the model's landmarks: {known})")

    def case_info(self) -> dict[str, Any]:
        """The content of ``GET /api/case``."""
        rel = self.case_dir
        lm_path = self.setup.landmarks_path
        return {
            "id": self.setup.id,
            "views": [v.info() for v in self.views.values()],
            "landmark_names": list(self.landmarks),
            "model_landmarks": dict(self.landmarks),
            "n_vertices": self.setup.n_vertices,
            "poses": self.setup.poses,
            "silhouettes": self.setup.silhouettes,
            "annotations_file": str(self._ann_path.relative_to(rel)),
            "landmarks_file": None if lm_path is None else str(lm_path.relative_to(rel)),
            "has_result": (self.out_dir / "result.json").is_file(),
        }

    def view_document(self, view: str) -> dict[str, Any]:
        """One view's annotations (``biplanar-reg/annotations@1``), each contour with the
        ``anchors`` it was traced through when the workbench knows them."""
        self._view(view)
        with self._edit:
            va = self._current().views.get(view) or ViewAnnotations()
            saved = self._anchors.get(view, [])
            ids = self._ids.views.get(view, [])
            contours = []
            for i, c in enumerate(va.contours):
                entry = c.to_json()
                if i < len(ids):
                    entry["id"], entry["version"] = ids[i]
                anchors = _anchors_of(saved[i], c) if i < len(saved) else None
                if anchors is not None:
                    entry["anchors"] = anchors
                contours.append(entry)
            return {
                "landmarks": {k: lm.to_json() for k, lm in va.landmarks.items()},
                "contours": contours,
            }

    def annotations_document(self) -> dict[str, Any]:
        """The whole annotation document, every view of the case included (empty ones too)."""
        return {
            "format": "biplanar-reg/annotations@1",
            "views": {name: self.view_document(name) for name in self.views},
        }

    # -- saving ---------------------------------------------------------------------------------

    def _commit(self, ann: Annotations, anchors: dict[str, list[Any]] | None = None) -> None:
        """Save ``ann`` (validated, atomic), then the anchors; only then adopt them."""
        self._restore_annotations(ann)
        if anchors is not None:
            self._restore_anchors(anchors)

    def _restore_annotations(self, ann: Annotations) -> None:
        """Save and adopt ``ann`` (an edit, or a state of the undo history)."""
        save_annotations(ann, self._ann_path)
        self._ids.follow(self._ann, ann)
        self._ann, self._ann_stamp = ann, _stamp(self._ann_path)

    def _restore_anchors(self, anchors: dict[str, list[Any]]) -> None:
        atomic_write_json(self._state_path, {"format": STATE_FORMAT, "contour_anchors": anchors})
        self._anchors = anchors

    def _restore_landmarks(self, landmarks: dict[str, int]) -> None:
        path = self._landmark_file()
        if landmarks:
            atomic_write_json(path, landmarks)
        else:  # undoing the first definition: the file did not exist (it may not be empty)
            path.unlink(missing_ok=True)
        self.landmarks = landmarks

    # -- undo / redo ----------------------------------------------------------------------------

    def undo(self) -> dict[str, Any]:
        """Undo the last edit (:mod:`biplanar_reg.workbench.history`); returns
        :meth:`history_document` with ``"done"``: what was undone. :class:`Conflict` when there
        is nothing to undo."""
        return self._travel(self.history.undo)

    def redo(self) -> dict[str, Any]:
        """Redo the last undone edit; as :meth:`undo`."""
        return self._travel(self.history.redo)

    def _travel(self, move: Any) -> dict[str, Any]:
        with self._edit:
            self._current()  # a file changed by someone else clears the history first
            try:
                step = move()
            except NothingToUndo as exc:
                raise Conflict(str(exc)) from None
            return {**self.history_document(), "done": step.label}

    def history_document(self) -> dict[str, Any]:
        """``{"history": the undo status, "annotations": the whole annotation document,
        "model_landmarks"}``: what the page shows after an undo or a redo."""
        with self._edit:
            return {
                "history": self.history.status(),
                "annotations": self.annotations_document(),
                "model_landmarks": dict(self.landmarks),
            }

    def set_landmark(
        self, view: str, name: str, uv: object, sigma_px: object = None
    ) -> dict[str, Any]:
        """Place or move landmark ``name`` in ``view`` at ``uv`` (pixels); ``sigma_px``
        defaults to the landmark's current one (1 for a new landmark). Returns the view's
        annotations."""
        v = self._view(view)
        self._known_landmark(name)
        p = check_point(uv, "uv", v.size)
        sigma = check_positive(sigma_px, "sigma_px", None)
        with self._edit, self.history.step(f"{name} placed in {view}"):
            ann = _copy(self._current())
            va = ann.views.setdefault(view, ViewAnnotations())
            old = va.landmarks.get(name)
            if sigma is None:
                sigma = old.sigma_px if old is not None else 1.0
            va.landmarks[name] = Landmark(p, sigma)
            self._commit(ann)
            return self.view_document(view)

    def delete_landmark(self, view: str, name: str) -> dict[str, Any]:
        """Remove landmark ``name`` from ``view``; returns the view's annotations."""
        self._view(view)
        with self._edit, self.history.step(f"{name} removed from {view}"):
            ann = _copy(self._current())
            va = ann.views.get(view)
            if va is None or name not in va.landmarks:
                raise NotFound(f"views.{view}.landmarks.{name}: not placed in this view")
            del va.landmarks[name]
            self._commit(ann)
            return self.view_document(view)

    def _checked_contour(
        self, v: _View, uv: object, closed: object, anchors: object
    ) -> tuple[Contour, dict[str, Any] | None]:
        pts = check_points(uv, "uv", v.size, 3)
        contour = Contour(pts, check_flag(closed, "closed", False))
        if anchors is None:
            return contour, None
        a = check_points(anchors, "anchors", v.size, 2, MAX_ANCHORS)
        return contour, {**_fingerprint(contour), "anchors": a.tolist()}

    def edit_contours(self, view: str, change: Any, label: str = "") -> dict[str, Any]:
        """Apply ``change(contours, anchors)`` to ``view`` and save; returns the view's
        annotations. ``contours`` (of :class:`Contour`) and ``anchors`` (the anchor entry of
        each, or None) are edited in place, in step; nothing is saved when ``change`` raises.
        For the outline tools (:mod:`biplanar_reg.workbench.outline_tools`); ``label`` names
        the edit in the undo history."""
        self._view(view)
        return self._edit_contours(view, change, label)

    def _edit_contours(self, view: str, change: Any, label: str = "") -> dict[str, Any]:
        """Apply ``change(contours, anchors)`` (both lists, edited in place) and save; a
        change that leaves every contour and anchor entry as it was saves nothing."""
        with self._edit, self.history.step(label or f"contours of {view} edited"):
            ann = _copy(self._current())
            va = ann.views.setdefault(view, ViewAnnotations())
            anchors = {k: list(x) for k, x in self._anchors.items()}
            saved = anchors.get(view, [])
            saved = (saved + [None] * len(va.contours))[: len(va.contours)]
            before = [*va.contours, *saved]
            change(va.contours, saved)
            after = [*va.contours, *saved]
            same = len(before) == len(after)
            if same and all(a is b for a, b in zip(before, after, strict=True)):
                return self.view_document(view)
            anchors[view] = saved
            self._commit(ann, anchors)
            return self.view_document(view)

    def add_contour(
        self, view: str, uv: object, closed: object = None, anchors: object = None
    ) -> tuple[int, dict[str, Any]]:
        """Append a contour (``uv``: >= 3 points, pixels); returns its index and the view's
        annotations. ``anchors`` (optional) are kept in ``.workbench.json``."""
        v = self._view(view)
        contour, entry = self._checked_contour(v, uv, closed, anchors)
        index: list[int] = []

        def change(contours: list[Contour], saved: list[Any]) -> None:
            index.append(len(contours))
            contours.append(contour)
            saved.append(entry)

        doc = self._edit_contours(view, change, f"contour added in {view}")
        return index[0], doc

    def contour_index(self, view: str, ref: object, version: int | None = None) -> int:
        """The current index of contour ``ref`` of ``view``: its ``id`` (as in the answers)
        or its index, checked to be at ``version`` when given (the HTTP API always gives it).
        Raises :class:`NotFound` (no such index) or :class:`StaleContour` (a 409: the contour
        was removed or changed since that version). Call it inside an edit, e.g. from the
        ``change`` of :meth:`edit_contours`, so that nothing changes in between."""
        self._view(view)
        with self._edit:
            self._current()
            return self._ids.find(view, ref, version)

    def replace_contour(
        self,
        view: str,
        index: int | str,
        uv: object,
        closed: object = None,
        anchors: object = None,
        *,
        version: int | None = None,
    ) -> dict[str, Any]:
        """Replace contour ``index`` (an index or a contour ``id``) of ``view``, at ``version``
        when given (else :class:`StaleContour`); returns the view's annotations."""
        v = self._view(view)
        contour, entry = self._checked_contour(v, uv, closed, anchors)

        def change(contours: list[Contour], saved: list[Any]) -> None:
            i = self._ids.find(view, index, version)
            contours[i], saved[i] = contour, entry

        return self._edit_contours(view, change, f"contour of {view} replaced")

    def delete_contour(
        self, view: str, index: int | str, *, version: int | None = None
    ) -> dict[str, Any]:
        """Remove contour ``index`` (an index or a contour ``id``) of ``view``, at ``version``
        when given (else :class:`StaleContour`); returns the view's annotations."""
        self._view(view)

        def change(contours: list[Contour], saved: list[Any]) -> None:
            i = self._ids.find(view, index, version)
            del contours[i], saved[i]

        return self._edit_contours(view, change, f"contour of {view} removed")

    # -- model landmarks ------------------------------------------------------------------------

    def _landmark_file(self) -> Path:
        path = self.setup.landmarks_path
        if path is None:
            raise Conflict(
                "[model] landmarks: case.toml names no landmark file (the landmarks are in the "
                "model file, which the workbench does not rewrite)"
            )
        return path

    def set_model_landmark(self, name: object, vertex: object) -> dict[str, Any]:
        """Define or move the model landmark ``name`` to vertex ``vertex`` (writes the case's
        ``[model] landmarks`` file, ``{"name": vertex index}``); returns ``{"landmarks"}``."""
        if not isinstance(name, str) or not name.strip() or len(name) > 200:
            raise ValueError(f"name: expected a non-empty landmark name, got {short(name)}")
        n = self.setup.n_vertices
        if isinstance(vertex, bool) or not isinstance(vertex, int) or not 0 <= vertex < n:
            raise ValueError(f"vertex: expected a vertex index in 0..{n - 1}, got {short(vertex)}")
        self._landmark_file()
        with self._edit, self.history.step(f"model landmark {name} set"):
            self._restore_landmarks({**self.landmarks, name: vertex})
            return {"landmarks": dict(self.landmarks)}

    def delete_model_landmark(self, name: str) -> dict[str, Any]:
        """Remove a model landmark that no view uses; returns ``{"landmarks"}``."""
        self._landmark_file()
        with self._edit, self.history.step(f"model landmark {name} removed"):
            if name not in self.landmarks:
                raise NotFound(f"landmarks.{name}: no such model landmark")
            used = [n for n, va in self._current().views.items() if name in va.landmarks]
            if used:
                raise Conflict(f"landmarks.{name}: still placed in view(s) {', '.join(used)}")
            if len(self.landmarks) == 1:
                raise Conflict(f"landmarks.{name}: the last landmark (the file must not be empty)")
            self._restore_landmarks({k: i for k, i in self.landmarks.items() if k != name})
            return {"landmarks": dict(self.landmarks)}

    # -- tools ----------------------------------------------------------------------------------

    def tile(
        self, view: str, level: int, tx: int, ty: int, lo: float | None, hi: float | None
    ) -> bytes:
        """A PNG tile of ``view`` (see :mod:`biplanar_reg.workbench.tiles`)."""
        try:
            return self._view(view).pyramid().tile(level, tx, ty, lo, hi)
        except LookupError as exc:
            raise NotFound(str(exc)) from None

    def snap(
        self, view: str, uv: object, mode: object = None, radius_px: object = None
    ) -> dict[str, Any]:
        """:func:`biplanar_reg.annotation.snap_landmark` at ``uv``: ``{"uv", "clicked",
        "shift_px", "mode", "strength"}`` (pixels)."""
        v = self._view(view)
        v.need_image()
        p = check_point(uv, "uv", v.size)
        mode = "corner" if mode is None else mode
        if mode not in ("corner", "edge"):
            raise ValueError(f"mode: expected 'corner' or 'edge', got {short(mode)}")
        radius = check_positive(radius_px, "radius_px", 5.0)
        if radius > MAX_RADIUS_PX:
            raise ValueError(
                f"radius_px: at most {MAX_RADIUS_PX:g} px (a snap looks next to the click), got "
                f"{radius:g}"
            )
        res = snap_landmark(v.image, p, radius_px=radius, mode=mode)
        return {
            "uv": [float(x) for x in res.uv],
            "clicked": [float(x) for x in res.clicked],
            "shift_px": float(res.shift_px),
            "mode": res.mode,
            "strength": float(res.strength),
        }

    def livewire(self, view: str, anchors: object, closed: object = None) -> dict[str, Any]:
        """:func:`biplanar_reg.annotation.livewire` through ``anchors`` on the view's cached
        edge cost: ``{"uv": [[u, v], ...], "seconds": s}`` (``seconds``: the server's time)."""
        t0 = time.perf_counter()
        v = self._view(view)
        v.need_image()
        is_closed = check_flag(closed, "closed", False)
        pts = check_points(anchors, "anchors", v.size, 3 if is_closed else 2, MAX_ANCHORS)
        path = livewire(v.image, pts, is_closed, sigma_px=LIVEWIRE_SIGMA_PX, cost=v.cost())
        return {"uv": _rounded(path), "seconds": time.perf_counter() - t0}

    # -- registration ---------------------------------------------------------------------------

    def _out_inside(self, *files: Path) -> None:
        for path in (self.out_dir, *files):
            if path.exists() and not self._inside(path):
                raise Conflict(f"{path}: points outside the case folder; remove the link")

    def start_registration(self) -> dict[str, Any]:
        """Start ``biplanar-reg register CASE_DIR`` in the background; returns the job status.

        Raises :class:`Conflict` when one is running.
        """
        self._out_inside()
        if not self.job.start():
            raise Conflict("register: a registration is already running")
        return self.job.status()

    def result(self) -> dict[str, Any]:
        """The registered outline and landmarks per view, metrics and flags (``GET
        /api/result``), from ``out/result.json`` and ``out/registered.ply``; computed once per
        result. Raises :class:`NotFound` before any registration."""
        from .jobs import review

        files = [self.out_dir / "result.json", self.out_dir / "registered.ply"]
        self._out_inside(*files)
        key = (tuple(_stamp(f) for f in files), tuple(self.landmarks.items()))
        if None in key[0]:
            raise NotFound("result: no registration result yet (POST /api/register)")
        cached = self._review
        if cached is not None and cached[0] == key:
            return cached[1]
        try:
            doc = review(self.setup.views, dict(self.landmarks), self.out_dir)
        except FileNotFoundError:  # replaced by a registration finishing right now
            raise NotFound("result: being replaced by a new registration; ask again") from None
        self._review = (key, doc)
        return doc
