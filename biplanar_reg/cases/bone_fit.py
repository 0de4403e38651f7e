"""One bone registered over its frames: :func:`fit_bone` and what it returns, :class:`BoneFit`.

A case is bones x frames; each bone is registered over its list of frames (one frame for a
case without ``[[frames]]``). The registration library has two entry points:
:func:`~biplanar_reg.registration.register_views` (one frame: poses known, refined or unknown,
a warm start) and :func:`~biplanar_reg.registration.frames.register_frames` (one shape over
several frames, poses known). :func:`fit_bone` is the one call of the case pipeline: it takes
the frames and runs the joint registration when the case lists its frames (``[[frames]]``, even
one), the single-frame one otherwise. :class:`BoneFit` is its result in one shape, per frame
(pose, posed vertices, residuals, uncertainty), with the fields of
:class:`~biplanar_reg.result.CaseResult` that only that registration reports.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CaseError, CaseFailure, ObservationError, SolverFailure
from ..io.transforms import rigid_pose
from ..registration import RegistrationResult, ViewObservations, register_views
from ..registration.frames import FrameRegistrationResult, register_frames
from ..result import FRAMES, SINGLE
from .case import Case
from .metrics import contour_errors, model_outlines
from .outputs import uncertainty_summary
from .warm import NO_PREVIOUS, previous_fit

__all__ = ["BoneFit", "fit_bone"]

Frames = list[list[ViewObservations]]

#: ``result.json["uncertainty"]["by_frames_method"]`` of a multi-frame case.
BY_FRAMES_METHOD = (
    "per n: the per-vertex posterior sd of the bone posed in frame 'frame' from the first n "
    "frames' information only (Laplace approximation of the joint objective at the all-frame "
    "fit, the other frames' poses eliminated; registration/frames_uncertainty.py); sd_*: pose, "
    "weights and model truncation; shape_sd_*: the shape weights alone (model frame)"
)
#: ``result.json["metrics"]["contour_errors_source"]``: who measured the contour errors.
SOLVER_SOURCE = "solver: annotated contours resampled at 1 px, open ends excluded"
REPORT_SOURCE = "report: annotated points to the registered mesh's occluding contour"


@dataclasses.dataclass
class BoneFit:
    """A bone registered over F frames, as the case pipeline reads it (world frame, mm; px).

    Attributes
    ----------
    layout : {"single", "frames"}
        The layout of the bone's ``result.json`` (``frames``: registered jointly).
    names : list of str
        The frame names.
    poses : (F, 4, 4) array
        Model -> world pose per frame.
    frame_vertices : list of (N, 3) arrays
        The registered surface posed in each frame (world, mm).
    model_vertices : (N, 3) array or None
        The shared shape in the model frame (a joint registration; ``registered_model.ply``).
    vertex_sd : list of (N,) arrays or None
        Per frame the per-vertex posterior sd (mm; NaN where the frame's data cannot tell).
    landmark_errors_px, contour_errors_px : list of dict
        Per frame ``{view: {landmark: px}}`` and ``{view: (P,) px}``.
    outlines : list of dict
        Per frame ``{view: polylines (px)}`` of the registered outline, where known.
    view_poses : dict
        ``{view: {"R", "t", "centre"}}`` the registration estimated (frame 0).
    view_fields : dict
        ``{view: ViewResult keywords}`` only the single-frame registration reports.
    frame_fields : list of dict
        Per frame the :class:`~biplanar_reg.result.FrameResult` keywords of a joint fit.
    case_fields, metric_fields : dict
        :class:`~biplanar_reg.result.CaseResult` keywords and ``metrics`` keys only this
        registration reports (``registration``: its entries besides the case's settings).
    rejected : list of (view, landmark)
    result : RegistrationResult or FrameRegistrationResult
        The library's result (``weights``, ``flags``, ``timings``: its stages in s).
    """

    layout: str
    names: list[str]
    poses: np.ndarray
    frame_vertices: list[np.ndarray]
    model_vertices: np.ndarray | None
    vertex_sd: list[np.ndarray | None]
    landmark_errors_px: list[dict[str, dict[str, float]]]
    contour_errors_px: list[dict[str, np.ndarray]]
    outlines: list[dict[str, list[np.ndarray]]]
    view_poses: dict[str, dict[str, np.ndarray]]
    view_fields: dict[str, dict[str, Any]]
    frame_fields: list[dict[str, Any]]
    case_fields: dict[str, Any]
    metric_fields: dict[str, Any]
    rejected: list[tuple[str, str]]
    result: RegistrationResult | FrameRegistrationResult

    @classmethod
    def of(
        cls, case: Case, frames: Frames, res: RegistrationResult | FrameRegistrationResult
    ) -> BoneFit:
        """The fit ``res`` of :func:`fit_bone` over ``frames`` (the contour errors of a view
        the single-frame registration reported none for measured here, on the outline)."""
        if isinstance(res, FrameRegistrationResult):
            return _joint_fit(case, frames, res)
        return _single_fit(case, frames[0], res)


def fit_bone(
    case: Case, frames: Frames, say: Callable[[str], None], warm_from: Path | None = None
) -> RegistrationResult | FrameRegistrationResult:
    """Register the bone of ``case`` over ``frames`` (per frame its views' observations).

    ``say`` receives the stage messages; ``warm_from``: the output folder whose result a
    single-frame registration may start from (:mod:`.warm`; a joint registration over frames
    starts cold). Failures become :class:`CaseFailure` (exit 1) or :class:`CaseError` (the
    case's input, exit 2), one line naming the case file.
    """
    key = "[[frames]]" if case.frames else "[registration]"
    try:
        if case.frames:
            return register_frames(
                case.model,
                frames,
                names=[f.name for f in case.frames],
                silhouettes=case.silhouettes,
                options=case.options,
                progress=say,
            )
        res = register_views(
            case.model,
            frames[0],
            silhouettes=case.silhouettes,
            poses=case.poses,
            options=case.options,
            progress=say,
            start=case.start,
            start_from=None if warm_from is None else previous_fit(warm_from),
        )
    except SolverFailure as exc:
        raise CaseFailure(f"{case.case_file}: registration failed: {exc}") from None
    except (np.linalg.LinAlgError, FloatingPointError, ArithmeticError) as exc:
        raise CaseFailure(f"{case.case_file}: registration failed (numerical): {exc}") from None
    except ObservationError as exc:  # what the annotations hold, not how the case registers
        where = "[[frames]]" if case.frames else _relative(case.annotations_path, case.case_file)
        raise CaseError(f"{case.case_file}: {where}: {' '.join(str(exc).split())}") from None
    except ValueError as exc:
        raise CaseError(f"{case.case_file}: {key}: {' '.join(str(exc).split())}") from None
    if not np.all(np.isfinite(res.vertices)):
        raise CaseFailure(f"{case.case_file}: registration failed: non-finite vertices")
    if warm_from is not None and not res.restart.get("reason") and res.restart["start"] == "cold":
        res = dataclasses.replace(res, restart={**res.restart, "reason": NO_PREVIOUS})
    return res


def _relative(path: Path, case_file: Path) -> str:
    """``path`` relative to the case folder (as the case file names it), else as it is."""
    try:
        return Path(path).resolve().relative_to(Path(case_file).resolve().parent).as_posix()
    except ValueError:
        return str(path)


def _single_fit(case: Case, obs: list[ViewObservations], res: RegistrationResult) -> BoneFit:
    """One frame: the outlines and contour errors of views the solver reported none for
    (e.g. silhouettes off) from the registered mesh's exact occluding contour."""
    errs: dict[str, np.ndarray] = {}
    outlines: dict[str, list[np.ndarray]] = {}
    sources = set()
    for o in obs:
        sil = [np.asarray(s, float) for s in res.silhouettes_px.get(o.name, [])]
        if not sil and case.model.faces is not None:
            sil = model_outlines(res.vertices, case.model.faces, o.view)
        outlines[o.name] = sil
        err = np.asarray(res.contour_errors_px.get(o.name, np.zeros(0)), float)
        if len(err) == 0 and o.contours:
            err = contour_errors(o, sil)
            sources.add(REPORT_SOURCE)
        elif len(err):
            sources.add(SOLVER_SOURCE)
        errs[o.name] = err
    marks = res.noise.get("landmarks", {})
    measured = any(np.isfinite(e).any() for e in errs.values())
    return BoneFit(
        layout=SINGLE,
        names=["0"],
        poses=rigid_pose(res.rotation, res.translation)[None],
        frame_vertices=[res.vertices],
        model_vertices=None,
        vertex_sd=[res.vertex_sd_mm],
        landmark_errors_px=[res.landmark_errors_px],
        contour_errors_px=[errs],
        outlines=[outlines],
        view_poses=res.view_poses,
        view_fields={
            o.name: {
                "landmark_sigmas_px": {n: m["sigma_px"] for n, m in marks.get(o.name, {}).items()},
                "landmark_weights": {n: m["weight"] for n, m in marks.get(o.name, {}).items()},
                "outline_coverage": res.outline_coverage.get(o.name),
                "extra": {"landmarks_disagreeing_px": res.disagreeing_px.get(o.name, {})},
            }
            for o in obs
        },
        frame_fields=[{}],
        case_fields={
            "certificate": res.certificate,
            "iterations": [dataclasses.asdict(r) for r in res.iterations],
            "best_iteration": res.best_iteration,
            "registration": {"pose_estimation": res.pose_info},
            "noise": {k: v for k, v in res.noise.items() if k != "landmarks"} or None,
            "gaussian_process": res.gp or None,
            "uncertainty": uncertainty_summary(res.vertex_sd_mm),
            "extra": {"restart": res.restart or None},
        },
        metric_fields={
            "contour_errors_source": "; ".join(sorted(sources)) if measured else None,
            "certificate": res.certificate,
            "relaxation_gap_px": res.relaxation_gap_px,
        },
        rejected=[(v, n) for v, n in res.rejected],
        result=res,
    )


def _joint_fit(case: Case, frames: Frames, res: FrameRegistrationResult) -> BoneFit:
    """Several frames registered jointly: one shape (model frame), a pose per frame."""
    n = res.n_frames
    sd = [None] * n if res.vertex_sd_mm is None else list(res.vertex_sd_mm)
    return BoneFit(
        layout=FRAMES,
        names=list(res.frame_names),
        poses=res.poses(),
        frame_vertices=[res.frame_vertices(f) for f in range(n)],
        model_vertices=res.vertices,
        vertex_sd=sd,
        landmark_errors_px=res.landmark_errors_px,
        contour_errors_px=res.contour_errors_px,
        outlines=[{} for _ in range(n)],
        view_poses={},
        view_fields={},
        frame_fields=[
            {
                "started_from": res.started_from[f],
                "landmark_rms_px": res.landmark_rms_px[f],
                "contour_rms_px": res.contour_rms_px[f],
            }
            for f in range(n)
        ],
        case_fields={
            "converged": res.converged,
            "registration": {"frames": len(frames)},
            "uncertainty": _frames_uncertainty(res),
            "extra": {
                "registered_ply": "the shape posed in frame 0 (world frame)",
                "joint_objective": {"before": res.cost_before, "after": res.cost_after},
            },
        },
        metric_fields={},
        rejected=[],
        result=res,
    )


def _frames_uncertainty(res: FrameRegistrationResult) -> dict[str, Any] | None:
    """``result.json["uncertainty"]`` of a joint fit: frame 0's summary (the bone of
    ``registered.ply``) and the shape's uncertainty as frames are added."""
    if res.vertex_sd_mm is None:
        return None
    sd0 = res.vertex_sd_mm[0]
    out = (uncertainty_summary(sd0) if np.isfinite(sd0).all() else None) or {}
    out.update(
        {
            "frame": res.frame_names[0],
            "by_frames": res.uncertainty_by_frames,
            "by_frames_method": BY_FRAMES_METHOD,
        }
    )
    return out
