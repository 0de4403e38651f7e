""":class:`CaseResult`: a registered case as bones x frames, and its ``result.json``.

One format, :data:`RESULT_FORMAT`, in three layouts that keep every key where version 0.1 put
it (docs/cases.md, docs/frames.md, docs/bones.md):

- ``single`` (one bone, one frame): the pose (``rotation``, ``translation``) and ``views`` at
  the top level;
- ``frames`` (one bone, ``[[frames]]``): ``frames`` is the list of frame entries, the top-level
  pose is frame 0's;
- ``bones`` (``[[bones]]``): ``bones`` maps each bone's name to its entry (its pose per frame,
  its metrics), ``frames`` is the list of frame names.

Every document also states its shape: ``shape = {"layout", "bones", "frames"}`` (names). A key
this module does not know is kept (``extra``) and written back, so reading and writing a
document gives it unchanged. Lengths in mm, image errors in px, poses model -> world (OpenCV:
``X_cam = R @ X + t`` for the views).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "BONES",
    "FRAMES",
    "READ_FORMATS",
    "RESULT_FORMAT",
    "SINGLE",
    "BoneResult",
    "CaseResult",
    "FrameResult",
    "ViewResult",
    "jsonable",
    "read_result",
]

#: The format tag of every ``result.json`` this version writes.
RESULT_FORMAT = "biplanar-reg/result@2"
#: The format tags :meth:`CaseResult.from_json` reads (``@1``: version 0.1, without ``shape``).
READ_FORMATS = ("biplanar-reg/result@1", RESULT_FORMAT)
#: The layouts of ``result.json`` (``shape["layout"]``).
SINGLE, FRAMES, BONES = "single", "frames", "bones"
#: Bone and frame names of a 0.1 document that does not state them.
DEFAULT_BONE, DEFAULT_FRAME = "bone", "0"


def jsonable(x: Any) -> Any:
    """Plain JSON types; NaN/inf become None (strict JSON has no NaN)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def _array(x: Any) -> np.ndarray | None:
    """A float array of a JSON list (None stays None; a JSON null inside becomes NaN)."""
    return None if x is None else np.asarray(x, float)


def _split(doc: Mapping[str, Any], known: tuple[str, ...]) -> dict[str, Any]:
    """The keys of ``doc`` outside ``known`` (kept as they are, written back)."""
    return {k: v for k, v in doc.items() if k not in known}


#: Keys of a view entry in a frame of a multi-frame case, and in a single case (which adds the
#: per-point contour errors and the landmarks' noise and robust weights).
_FRAME_VIEW_KEYS = (
    "R",
    "t",
    "centre",
    "landmark_errors_px",
    "landmark_rms_px",
    "contour_error_stats_px",
)
_CASE_VIEW_KEYS = (
    "R",
    "t",
    "centre",
    "landmark_errors_px",
    "landmark_rms_px",
    "landmark_sigmas_px",
    "landmark_weights",
    "contour_errors_px",
    "contour_error_stats_px",
    "outline_coverage",
)


@dataclass(eq=False)
class ViewResult:
    """One view of one frame: the pose the registration used and the residuals there.

    Attributes
    ----------
    name : str
    R, t, centre : (3, 3), (3,), (3,) arrays
        World -> camera rotation, translation (mm) and the source position (world, mm).
    landmark_errors_px : dict
        Landmark name -> reprojection error, px.
    landmark_rms_px : float or None
    contour_error_stats_px : dict or None
        Summary (mean, rms, p95, max, ...) of the contour errors, px.
    contour_errors_px : list of float or None
        Per contour point, px (single-frame cases).
    landmark_sigmas_px, landmark_weights : dict or None
        Per landmark the noise sd of the final fit (px) and its robust weight.
    outline_coverage : any
        The share of the annotated outline the model's outline covers (single-frame cases).
    """

    name: str
    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    landmark_errors_px: dict[str, float] = field(default_factory=dict)
    landmark_rms_px: float | None = None
    contour_error_stats_px: dict[str, Any] | None = None
    contour_errors_px: list[float] | None = None
    landmark_sigmas_px: dict[str, float] | None = None
    landmark_weights: dict[str, float] | None = None
    outline_coverage: Any = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.R, self.t, self.centre = _array(self.R), _array(self.t), _array(self.centre)

    @classmethod
    def from_json(cls, name: str, doc: Mapping[str, Any]) -> ViewResult:
        """The view entry ``doc`` of ``result.json``."""
        kw = {k: doc[k] for k in _CASE_VIEW_KEYS if k in doc}
        return cls(name=name, **kw, extra=_split(doc, _CASE_VIEW_KEYS))

    def to_json(self, detailed: bool = True) -> dict[str, Any]:
        """The view's entry; ``detailed``: with the keys of a single-frame case."""
        keys = _CASE_VIEW_KEYS if detailed else _FRAME_VIEW_KEYS
        return {**{k: getattr(self, k) for k in keys}, **self.extra}


#: Keys of a frame entry (``frames[f]`` of a multi-frame case); ``pose`` is derived.
_FRAME_KEYS = (
    "name",
    "rotation",
    "translation",
    "pose",
    "started_from",
    "landmark_errors_px",
    "landmark_rms_px",
    "landmark_max_px",
    "contour_rms_px",
    "contour_error_stats_px",
    "uncertainty",
    "ground_truth_metrics",
    "views",
)


@dataclass(eq=False)
class FrameResult:
    """One bone in one frame: its pose (model -> world) and, per view, its residuals.

    The per-frame summaries (``landmark_*``, ``contour_*``, ``uncertainty`` in mm,
    ``ground_truth_metrics`` in mm) are those of a multi-frame case; a single-frame case keeps
    them in :attr:`CaseResult.metrics`.
    """

    name: str
    rotation: np.ndarray
    translation: np.ndarray
    views: dict[str, ViewResult] = field(default_factory=dict)
    started_from: str | None = None
    landmark_errors_px: dict[str, dict[str, float]] | None = None
    landmark_rms_px: float | None = None
    landmark_max_px: float | None = None
    contour_rms_px: float | None = None
    contour_error_stats_px: dict[str, Any] | None = None
    uncertainty: dict[str, Any] | None = None
    ground_truth_metrics: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rotation, self.translation = _array(self.rotation), _array(self.translation)

    @property
    def pose(self) -> np.ndarray:
        """The model -> world pose, a 4x4 array (mm)."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.translation
        return T

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> FrameResult:
        """A frame entry of a multi-frame ``result.json``."""
        views = {n: ViewResult.from_json(n, v) for n, v in (doc.get("views") or {}).items()}
        skip = ("pose", "views")
        kw = {k: doc[k] for k in _FRAME_KEYS if k in doc and k not in skip}
        return cls(**kw, views=views, extra=_split(doc, _FRAME_KEYS))

    def to_json(self) -> dict[str, Any]:
        """The frame's entry of a multi-frame ``result.json``."""
        out = {k: getattr(self, k) for k in _FRAME_KEYS if k != "views"}
        out["views"] = {n: v.to_json(detailed=False) for n, v in self.views.items()}
        return {**out, **self.extra}


#: Keys of a bone entry of a multi-bone case (``bones[name]``).
_BONE_KEYS = (
    "out",
    "report",
    "rotation",
    "translation",
    "poses",
    "metrics",
    "flags",
    "rejected",
    "weights",
    "ground_truth",
    "model",
    "uncertainty",
)


@dataclass(eq=False)
class BoneResult:
    """One bone over the case's frames.

    Attributes
    ----------
    name : str
    frames : list of FrameResult
        One per frame of the case, in order.
    weights : (K,) array or None
        The shape model's mode weights.
    metrics, flags, rejected : dict, list, list
        The bone's metrics (px, mm), quality flags and rejected observations (the case's own
        for a case of one bone).
    ground_truth, model, uncertainty : dict or None
        As in ``result.json`` (docs/cases.md).
    out, report : str or None
        A bone of a multi-bone case: its output folder and report, relative to ``out/``.
    """

    name: str
    frames: list[FrameResult]
    weights: np.ndarray | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)
    rejected: list[Any] = field(default_factory=list)
    ground_truth: dict[str, Any] | None = None
    model: dict[str, Any] | None = None
    uncertainty: dict[str, Any] | None = None
    out: str | None = None
    report: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.weights = _array(self.weights)

    @property
    def poses(self) -> np.ndarray:
        """The bone's model -> world pose per frame, (F, 4, 4)."""
        return np.array([f.pose for f in self.frames], float)

    @classmethod
    def from_json(cls, name: str, doc: Mapping[str, Any], frame_names: list[str]) -> BoneResult:
        """A bone entry of a multi-bone ``result.json`` (its poses, one per frame name)."""
        poses = np.asarray(doc["poses"], float)
        frames = [
            FrameResult(n, T[:3, :3], T[:3, 3]) for n, T in zip(frame_names, poses, strict=True)
        ]
        skip = ("rotation", "translation", "poses")
        kw = {k: doc[k] for k in _BONE_KEYS if k in doc and k not in skip}
        return cls(name=name, frames=frames, **kw, extra=_split(doc, _BONE_KEYS))

    def to_json(self) -> dict[str, Any]:
        """The bone's entry of a multi-bone ``result.json`` (frame 0's pose at its top)."""
        f0 = self.frames[0]
        out = {k: getattr(self, k) for k in _BONE_KEYS if k not in ("rotation", "translation")}
        out = {"rotation": f0.rotation, "translation": f0.translation, **out}
        out["poses"] = self.poses
        return {k: out[k] for k in _BONE_KEYS} | self.extra


# Top-level keys of each layout, in the order they are written.
_COMMON = ("format", "shape", "id", "units", "frame")
_SINGLE_KEYS = (
    *_COMMON,
    *("rotation", "translation", "weights", "views", "certificate", "iterations"),
    *("best_iteration", "rejected", "flags", "metrics", "timings", "registration", "model"),
    *("ground_truth", "uncertainty", "noise", "gaussian_process", "warnings", "exports"),
    "report",
)
_FRAMES_KEYS = (
    *_COMMON,
    *("rotation", "translation", "weights", "frames", "metrics", "uncertainty", "converged"),
    *("flags", "timings", "registration", "model", "ground_truth", "warnings", "report"),
    "exports",
)
_BONES_KEYS = (
    *_COMMON,
    *("bones", "frames", "contact", "relative", "metrics", "flags", "rejected", "certificate"),
    *("warnings", "timings", "exports", "report"),
)


@dataclass(eq=False)
class CaseResult:
    """A registered case: bones x frames, its metrics, flags and what was written.

    Attributes
    ----------
    id : str
    layout : {"single", "frames", "bones"}
        How ``result.json`` lays it out (module docstring).
    bones : dict of str to BoneResult
        One per bone, in the case's order (one for a single-bone case).
    frame_names : list of str
        The frames' names (``["0"]`` for a single-frame case).
    units, coordinate_frame : dict, str
        ``result.json["units"]`` and ``["frame"]`` (the world frame, in words).
    metrics : dict
        Errors in px and mm (docs/cases.md); of a multi-bone case the worst over the bones.
    flags, warnings : list
        Quality flags (with advice in the report) and notes on the input and outputs.
    timings : dict
        Seconds per stage.
    rejected, certificate, registration, iterations, best_iteration, noise, gaussian_process,
    contact, relative, converged, exports, report
        As in ``result.json``; None (or empty) where the layout has none.
    extra : dict
        Top-level keys this class does not know, written back as they are.
    """

    id: str
    layout: str
    bones: dict[str, BoneResult]
    frame_names: list[str]
    units: dict[str, Any] = field(default_factory=dict)
    coordinate_frame: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)
    warnings: list[Any] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    rejected: list[Any] = field(default_factory=list)
    certificate: float | None = None
    registration: dict[str, Any] = field(default_factory=dict)
    iterations: list[dict[str, Any]] = field(default_factory=list)
    best_iteration: int | None = None
    noise: dict[str, Any] | None = None
    gaussian_process: dict[str, Any] | None = None
    contact: dict[str, Any] | None = None
    relative: list[dict[str, Any]] | None = None
    converged: bool | None = None
    exports: list[str] = field(default_factory=list)
    report: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.layout not in (SINGLE, FRAMES, BONES):
            raise ValueError(
                f"CaseResult: layout {self.layout!r} is not one of single/frames/bones"
            )

    # -- what the readers ask -------------------------------------------------------------
    @property
    def bone(self) -> BoneResult:
        """The bone of a single-bone case."""
        if len(self.bones) != 1:
            raise ValueError(f"{self.id}: {len(self.bones)} bones; ask result.bones[name]")
        return next(iter(self.bones.values()))

    @property
    def views(self) -> dict[str, ViewResult]:
        """The views of the first bone's first frame (empty for a multi-bone case, whose views
        are in each bone's own result)."""
        return next(iter(self.bones.values())).frames[0].views

    @property
    def options(self) -> dict[str, Any]:
        """The registration options the case ran with (``registration["options"]``)."""
        return dict((self.registration or {}).get("options") or {})

    @property
    def poses(self) -> str | None:
        """The case's ``poses`` setting ("known", "refine", "unknown")."""
        return (self.registration or {}).get("poses")

    @property
    def silhouettes(self) -> Any:
        """The case's ``silhouettes`` setting."""
        return (self.registration or {}).get("silhouettes")

    @property
    def phi(self) -> dict[str, dict[str, str]]:
        """DICOM patient identifiers per file (``--include-phi``; empty otherwise)."""
        return dict(self.extra.get("phi") or {})

    @property
    def shape(self) -> dict[str, Any]:
        """``result.json["shape"]``: the layout and the names of the bones and frames."""
        return {"layout": self.layout, "bones": list(self.bones), "frames": self.frame_names}

    # -- JSON -----------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The content of ``result.json`` (plain JSON types; NaN as None)."""
        doc = _WRITERS[self.layout](self)
        head = {"format": RESULT_FORMAT, "shape": self.shape, "id": self.id}
        head |= {"units": self.units, "frame": self.coordinate_frame}
        return jsonable({**head, **doc, **self.extra})

    @classmethod
    def from_json(cls, doc: Any, source: str = "result.json") -> CaseResult:
        """A result document (this version's or version 0.1's, any layout).

        Raises
        ------
        ValueError
            One line naming ``source``: not a JSON object, an unknown format, or a key
            missing or of the wrong type.
        """
        if not isinstance(doc, Mapping):
            raise ValueError(f"{source}: expected a JSON object, got {type(doc).__name__}")
        fmt = doc.get("format")
        if fmt not in READ_FORMATS:
            raise ValueError(f"{source}: format {fmt!r} is not one of {', '.join(READ_FORMATS)}")
        try:
            layout = _layout(doc)
            return _READERS[layout](doc, layout)
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            what = f"missing key {exc}" if isinstance(exc, KeyError) else str(exc)
            raise ValueError(f"{source}: not a {fmt} document: {what}") from None


def read_result(path: str | os.PathLike) -> CaseResult:
    """:meth:`CaseResult.from_json` of the file ``path`` (a ``ValueError`` naming it when it
    cannot be read or is not a result)."""
    from ..io import read_json

    return CaseResult.from_json(read_json(path), source=str(path))


def _layout(doc: Mapping[str, Any]) -> str:
    """The layout a document states (``shape``) or, for version 0.1, has."""
    shape = doc.get("shape")
    if isinstance(shape, Mapping):
        if shape.get("layout") not in (SINGLE, FRAMES, BONES):
            raise ValueError(f"shape.layout {shape.get('layout')!r}: not single/frames/bones")
        return shape["layout"]
    if isinstance(doc.get("bones"), Mapping):
        return BONES
    frames = doc.get("frames")
    return (
        FRAMES if isinstance(frames, list) and frames and isinstance(frames[0], Mapping) else SINGLE
    )


def _names(doc: Mapping[str, Any], key: str, default: list[str]) -> list[str]:
    """``shape[key]`` of a document that states it, else ``default``."""
    shape = doc.get("shape")
    return [str(n) for n in shape[key]] if isinstance(shape, Mapping) else default


def _case(doc, layout, bones, frame_names, known) -> CaseResult:
    """The :class:`CaseResult` of ``doc``: the case-level keys, the given bones."""
    fields = {f.name for f in dataclasses.fields(CaseResult)}
    skip = {"id", "layout", "bones", "frame_names", "extra", "frames"}
    kw = {k: doc[k] for k in known if k in fields and k not in skip and k in doc}
    return CaseResult(
        id=doc["id"],
        layout=layout,
        bones=bones,
        frame_names=frame_names,
        coordinate_frame=doc.get("frame", ""),
        **kw,
        extra=_split(doc, known),
    )


def _bone_of(doc: Mapping[str, Any], frames: list[FrameResult]) -> BoneResult:
    """The one bone of a single- or multi-frame document (its metrics, flags and rejected
    observations are the case's)."""
    return BoneResult(
        _names(doc, "bones", [DEFAULT_BONE])[0],
        frames,
        weights=doc.get("weights"),
        ground_truth=doc.get("ground_truth"),
        model=doc.get("model"),
        uncertainty=doc.get("uncertainty"),
    )


def _one_bone(result: CaseResult) -> CaseResult:
    """Share the case's metrics, flags and rejected list with its one bone."""
    bone = result.bone
    bone.metrics, bone.flags, bone.rejected = result.metrics, result.flags, result.rejected
    return result


def _read_single(doc: Mapping[str, Any], layout: str) -> CaseResult:
    views = {n: ViewResult.from_json(n, v) for n, v in doc["views"].items()}
    frame_names = _names(doc, "frames", [DEFAULT_FRAME])
    frame = FrameResult(frame_names[0], doc["rotation"], doc["translation"], views)
    bone = _bone_of(doc, [frame])
    return _one_bone(_case(doc, layout, {bone.name: bone}, frame_names, _SINGLE_KEYS))


def _read_frames(doc: Mapping[str, Any], layout: str) -> CaseResult:
    frames = [FrameResult.from_json(f) for f in doc["frames"]]
    bone = _bone_of(doc, frames)
    names = [f.name for f in frames]
    return _one_bone(_case(doc, layout, {bone.name: bone}, names, _FRAMES_KEYS))


def _read_bones(doc: Mapping[str, Any], layout: str) -> CaseResult:
    frame_names = [str(n) for n in doc["frames"]]
    bones = {n: BoneResult.from_json(n, b, frame_names) for n, b in doc["bones"].items()}
    return _case(doc, layout, bones, frame_names, _BONES_KEYS)


def _write_single(r: CaseResult) -> dict[str, Any]:
    bone = r.bone
    frame = bone.frames[0]
    return {
        "rotation": frame.rotation,
        "translation": frame.translation,
        "weights": bone.weights,
        "views": {n: v.to_json() for n, v in frame.views.items()},
        **_fields(r, ("certificate", "iterations", "best_iteration", "rejected", "flags")),
        **_fields(r, ("metrics", "timings", "registration")),
        **_fields(bone, ("model", "ground_truth", "uncertainty")),
        **_fields(r, ("noise", "gaussian_process", "warnings", "exports", "report")),
    }


def _write_frames(r: CaseResult) -> dict[str, Any]:
    bone = r.bone
    return {
        "rotation": bone.frames[0].rotation,
        "translation": bone.frames[0].translation,
        "weights": bone.weights,
        "frames": [f.to_json() for f in bone.frames],
        "metrics": r.metrics,
        "uncertainty": bone.uncertainty,
        **_fields(r, ("converged", "flags", "timings", "registration")),
        **_fields(bone, ("model", "ground_truth")),
        **_fields(r, ("warnings", "report", "exports")),
    }


def _write_bones(r: CaseResult) -> dict[str, Any]:
    return {
        "bones": {n: b.to_json() for n, b in r.bones.items()},
        "frames": r.frame_names,
        **_fields(r, ("contact", "relative", "metrics", "flags", "rejected", "certificate")),
        **_fields(r, ("warnings", "timings", "exports", "report")),
    }


def _fields(obj: Any, names: tuple[str, ...]) -> dict[str, Any]:
    return {n: getattr(obj, n) for n in names}


_READERS = {SINGLE: _read_single, FRAMES: _read_frames, BONES: _read_bones}
_WRITERS = {SINGLE: _write_single, FRAMES: _write_frames, BONES: _write_bones}
