"""``[[views]]`` of a case file: calibrations, image headers, and the geometry checks of the views
(shared viewpoints, landmark rays meeting behind a source).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..annotation import Annotations
from ..annotation.image import read_image_size
from ..calibration import FORMATS, load_calibration
from ..calibration.views import OrthographicView, PerspectiveView, SlotScanningView, View
from ..registration import ViewObservations
from ._case_file import (
    MAX_VIEWS,
    MIN_LANDMARK_OBSERVATIONS,
    MIN_VIEWS,
    _Ctx,
)
from .case_types import CaseView

__all__ = []


def _scale_view(view: View, scale: float) -> View:
    """The same view with world lengths multiplied by ``scale`` (e.g. 1000 for m -> mm).

    Perspective: only ``t`` scales (``K`` is in pixels). Orthographic: ``t`` scales and ``K``'s
    pixels-per-length entries divide. Slot-scanning: ``t`` and ``row_pitch`` scale.
    """
    if scale == 1.0:
        return view
    t = view.t * scale
    if isinstance(view, OrthographicView):
        K = view.K.copy()
        K[:2, :2] /= scale
        return dataclasses.replace(view, t=t, K=K)
    if isinstance(view, SlotScanningView):
        return dataclasses.replace(view, t=t, row_pitch=view.row_pitch * scale)
    if isinstance(view, PerspectiveView):
        return dataclasses.replace(view, t=t)
    raise ValueError(f"cannot convert the units of a {type(view).__name__}")


def _view_tables(ctx: _Ctx, doc: dict) -> Iterator[tuple[str, str, dict]]:
    """``(where, name, table)`` of each ``[[views]]`` table, its name checked (non-empty, unique).

    A generator, so that each view is checked in full before the next one's name: the first
    problem of the file is the one reported.
    """
    tables = doc.get("views")
    if not isinstance(tables, list) or not tables:
        raise ctx.error("[[views]]", "expected at least one [[views]] table")
    if len(tables) > MAX_VIEWS:
        raise ctx.error(
            "[[views]]",
            f"{len(tables):,} views; at most {MAX_VIEWS} are registered (the time grows with "
            "the views: 128 annotated views took 28 s, 1,000 views 30 s even without "
            "annotations): list only the views that show the bone (a sequence of frames goes in "
            "[[frames]], not in more views)",
        )
    seen: set[str] = set()
    for i, table in enumerate(tables):
        where = f"[[views]][{i}]"
        if not isinstance(table, dict):
            raise ctx.error(where, "expected a table")
        name = ctx.string(table, "name", where)
        where = f"[[views]][{i}] ({name})"
        if name in seen:
            raise ctx.error(f"{where} name", f"duplicate view name {name!r}")
        seen.add(name)
        yield where, name, table


def _load_views(ctx: _Ctx, doc: dict, scale: float) -> list[CaseView]:
    views: list[CaseView] = []
    for where, name, table in _view_tables(ctx, doc):
        ctx.unknown_keys(table, "views", where)
        fmt = table.get("calibration_format")
        if fmt is not None and (not isinstance(fmt, str) or fmt.lower() not in FORMATS):
            raise ctx.error(
                f"{where} calibration_format", f"unknown format {fmt!r}; expected one of {FORMATS}"
            )
        dlt_column = None
        if "dlt_column" in table:
            dlt_column = ctx.number(table, "dlt_column", where, int, None)
        image_path = ctx.path(table, "image", where, required=False)
        frame, size = 0, None
        if image_path is not None:  # the header only: pixels are decoded when needed
            frame = ctx.number(table, "image_frame", where, int, 0)
            with ctx.reraise(f"{where} image"):
                size = read_image_size(image_path, frame=frame)
            _check_pixels(ctx, f"{where} image", image_path)
        calib = ctx.path(table, "calibration", where)
        with ctx.reraise(f"{where} calibration"):
            view = load_calibration(calib, fmt, dlt_column=dlt_column, image_size=size, name=name)
        used_fmt = (fmt or _detected(calib)).lower()
        view = dataclasses.replace(view, name=name)
        if used_fmt != "dicom":  # DICOM geometry is mm by the standard
            with ctx.reraise(f"{where} calibration"):
                view = _scale_view(view, scale)
        key = f"{ctx.file}: {where} image"
        views.append(CaseView(name, view, calib, used_fmt, image_path, frame, size, key))
    if len(views) < MIN_VIEWS:
        names = ", ".join(v.name for v in views)
        raise ctx.error(
            "[[views]]",
            f"{len(views)} view ({names}); a biplanar registration needs at least {MIN_VIEWS} "
            "views (one view leaves the depth along its rays undetermined)",
        )
    return views


def _check_pixels(ctx: _Ctx, key: str, path: Path) -> None:
    """A DICOM image whose pixels cannot be decoded here (no decoder installed for its
    transfer syntax, no pixel data) is a case error now, not after the registration, when the
    report first decodes it. Only element headers are read."""
    from ..io.dicomfile import pixel_data_problem

    problem = pixel_data_problem(path)
    if problem:
        raise ctx.error(key, f"{path.name}: {problem}")


def _rel(ctx: _Ctx, path: Path) -> str:
    """``path`` relative to the case folder when inside it."""
    return str(path.relative_to(ctx.dir)) if path.is_relative_to(ctx.dir) else str(path)


def _annotated(annotations: list[Annotations]) -> set[str]:
    """Names of the views with a landmark or a contour in any of ``annotations``."""
    return {
        name for ann in annotations for name, va in ann.views.items() if va.landmarks or va.contours
    }


def _check_viewpoints(ctx: _Ctx, views: list[CaseView], annotated: set[str]) -> None:
    """Views that see the bone from one point (the same source position; orthographic: the
    same direction), e.g. one calibration given twice. When every annotated view shares one
    viewpoint the bone's depth along the rays is undetermined (the registration failed with
    "point(s) lie behind the source"): a case error; otherwise a warning per repeated view."""
    from ..registration.quality import same_viewpoint

    first = list(range(len(views)))  # each view -> the first view of its viewpoint
    for j in range(len(views)):
        for i in range(j):
            if first[i] == i and same_viewpoint(views[i].view, views[j].view):
                first[j] = i
                break
    repeated = [j for j in range(len(views)) if first[j] != j]
    if not repeated:
        return
    names = [k for k, v in enumerate(views) if v.name in annotated]
    if len(names) >= 2 and len({first[k] for k in names}) == 1:
        j = next(k for k in names if first[k] != k)
        raise ctx.error(
            f"[[views]][{j}] ({views[j].name}) calibration",
            f"{_same_as(ctx, views, j, first[j])} ({_rel(ctx, views[first[j]].calibration)}): "
            "the views see the bone from one point, so its depth along the rays is "
            "undetermined (one calibration given twice?); a biplanar registration needs views "
            "from two directions, ideally 60-90 deg apart",
        )
    for j in repeated:
        ctx.warn(
            f"[[views]][{j}] ({views[j].name}) calibration: {_same_as(ctx, views, j, first[j])} "
            "(one calibration given twice?); the view adds nothing to the depth the other "
            "views give"
        )


def _check_landmark_rays(
    ctx: _Ctx, key: str, path: Path, views: list[CaseView], ann: Annotations, landmarks: dict
) -> None:
    """Landmark rays whose nearest point lies behind a view's source cannot start the
    registration (it starts at that point, and failed with "point(s) lie behind the source"):
    a case error saying why, for a case the landmarks start (4 observations of 3 points; else
    the start is searched on the outlines). With the views nearly parallel their rays barely
    cross and the point falls anywhere along them; otherwise calibrations and landmarks
    disagree."""
    from ..registration.gsft import nearest_point_to_rays
    from ..registration.quality import NEARLY_PARALLEL_DEG

    obs = [o for o in _observations(views, ann, landmarks) if len(o.landmark_ids)]
    ids = np.concatenate([o.landmark_ids for o in obs]) if obs else np.zeros(0, np.int64)
    if len(ids) < MIN_LANDMARK_OBSERVATIONS or len(np.unique(ids)) < 3:
        return
    rays = [o.view.rays(o.landmark_uv) for o in obs]
    centre = nearest_point_to_rays(np.vstack([r[0] for r in rays]), np.vstack([r[1] for r in rays]))
    behind = [
        o.name for o in obs if o.view.kind != "orthographic" and o.view.to_camera(centre)[0, 2] <= 0
    ]
    if not behind:
        return
    # how far apart the views look: their central rays, and their landmark rays on average
    central = _line_angles(np.array([o.view.R[2] for o in obs]))
    mean = _line_angles(np.array([r[1].mean(axis=0) for r in rays]))
    i, j = sorted(np.unravel_index(int(np.argmax(central)), central.shape))
    why = (
        f"the views with landmarks are nearly parallel ({obs[i].name}/{obs[j].name}: central "
        f"rays {central[i, j]:.1f} deg apart), so the bone's depth along the rays is "
        "undetermined: check each view's calibration, or use views further apart (ideally "
        "60-90 deg)"
        if max(central.max(), mean.max()) < NEARLY_PARALLEL_DEG
        else "the calibrations and the landmarks disagree (a calibration wrong, mirrored or in "
        "other units, or landmarks in the wrong view?)"
    )
    raise ctx.error(
        key, f"{path.name}: the landmark rays meet behind the source of {behind[0]}: {why}"
    )


def _line_angles(directions: np.ndarray) -> np.ndarray:
    """Pairwise angles (degrees) between directions (K, 3) taken as lines (0-90)."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    sin = np.linalg.norm(np.cross(d[:, None], d[None]), axis=-1)
    return np.degrees(np.arctan2(sin, np.abs(d @ d.T)))


def _same_as(ctx: _Ctx, views: list[CaseView], j: int, i: int) -> str:
    """``"<calibration>: the same source position as <view i>"`` (the projection direction of
    orthographic views, else the calibration)."""
    same = {"perspective": "source position", "orthographic": "projection direction"}
    what = same.get(views[j].view.kind, "calibration")
    return f"{_rel(ctx, views[j].calibration)}: the same {what} as {views[i].name}"


def _detected(path: Path) -> str:
    from ..calibration import detect_format

    return detect_format(path)


def _observations(views, annotations, landmarks) -> list[ViewObservations]:
    out = []
    for cv in views:
        va = annotations.views.get(cv.name)
        names = [] if va is None else list(va.landmarks)
        lms = [] if va is None else [va.landmarks[n] for n in names]
        out.append(
            ViewObservations(
                name=cv.name,
                view=cv.view,
                landmark_names=names,
                landmark_ids=np.array([landmarks[n] for n in names], dtype=np.int64),
                landmark_uv=np.array([lm.uv for lm in lms], float).reshape(-1, 2),
                landmark_sigma_px=np.array([lm.sigma_px for lm in lms], float),
                contours=[] if va is None else list(va.contours),
            )
        )
    return out
