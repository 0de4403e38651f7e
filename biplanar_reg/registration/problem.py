"""The registration problem every pipeline stage works on (:mod:`.stages`).

:class:`Problem` is fixed once the landmark-only start is known: the model, the annotated
views, the options, the landmarks as rays (with their pixels and sigmas), the prepared
annotated outlines and the per-view pixel sizes. Its methods are the pipeline's shared
vocabulary: landmark rays for a set of rejected landmarks, the model's outlines for a result,
the match-independent iteration cost, and the one call of the convex solver.

Frames and units: world frame, mm; image quantities in pixels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..ssm.model import ShapeModel
from .gsft import GsftResult, solve_gsft
from .observations import ViewObservations, landmark_rays, mm_per_pixel
from .options import RegistrationOptions
from .outline_match import (
    ModelOutline,
    OutlineTarget,
    mesh_topology,
    model_outline,
    outline_distances,
    prepare_outline,
)
from .rays import RayObservations

__all__ = ["Problem"]


@dataclass(frozen=True)
class Landmarks:
    """Every view's landmarks, stacked.

    Attributes
    ----------
    rays : RayObservations
        World-frame rays; ``sigmas`` are the annotators' pixel sigmas converted to mm at the
        object (not yet divided by the landmark weight).
    uv : (L, 2) array
        Annotated pixels.
    sigma_px : (L,) array
        Annotated pixel sigmas.
    names : list of (view, landmark)
        Owner of each observation.
    """

    rays: RayObservations
    uv: np.ndarray
    sigma_px: np.ndarray
    names: list[tuple[str, str]]
    stated_ratio: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rays)

    def ratios(self) -> np.ndarray:
        """Each landmark's stated sigma over the median stated sigma (what the noise estimate
        keeps of the statement: :mod:`.noise`)."""
        if self.stated_ratio is not None:
            return self.stated_ratio
        return self.sigma_px / float(np.median(self.sigma_px)) if len(self) else np.zeros(0)

    def px_errors(self, views: list[ViewObservations], vertices: np.ndarray) -> np.ndarray:
        """Reprojection error (px) of each landmark for registered ``vertices`` (N, 3)."""
        err = np.empty(len(self))
        ids, vi = self.rays.vertex_ids, self.rays.view_index
        for i, v in enumerate(views):
            sel = vi == i
            if np.any(sel):
                err[sel] = np.linalg.norm(v.view.project(vertices[ids[sel]]) - self.uv[sel], axis=1)
        return err


def stack_landmarks(views: list[ViewObservations], centre: np.ndarray | None) -> Landmarks:
    """The views' landmarks as :class:`Landmarks`; pixel sigmas converted to mm at ``centre``
    (mm, world; default: the point nearest to all landmark rays)."""
    rays = landmark_rays(views, centre)
    n = len(rays)
    sig_px = np.concatenate([v.landmark_sigma_px for v in views]) if n else np.zeros(0)
    uv = np.vstack([v.landmark_uv for v in views]) if n else np.zeros((0, 2))
    names = [(v.name, name) for v in views for name in v.landmark_names]
    return Landmarks(rays, uv, sig_px, names)


@dataclass(frozen=True)
class Problem:
    """What the stages share (fixed for one registration).

    Attributes
    ----------
    model : ShapeModel
    views : list of ViewObservations
        With the view poses used (known, refined or estimated).
    options : RegistrationOptions
    landmarks : Landmarks
    targets : dict
        ``{view index: OutlineTarget}`` for the views with annotated outlines.
    use_outlines : bool
        Outline boosting runs (asked for, and some view has outlines).
    topology : HalfEdges or None
        The model mesh's half-edge table (computed once).
    mm_per_px : dict
        ``{view index: pixel size at the object, mm}``.
    outline_spacing : dict
        ``{view index: px}``: the outline's samples count as independent once every this many
        pixels along it (``contour_spacing_px``, or the estimate of :mod:`.noise`).
    outline_sigma : dict
        ``{view index: sigma of one outline match, mm}`` (weighted by ``1 - landmark_weight``).
    say : callable
        Progress messages.
    """

    model: ShapeModel
    views: list[ViewObservations]
    options: RegistrationOptions
    landmarks: Landmarks
    targets: dict[int, OutlineTarget]
    use_outlines: bool
    topology: object
    mm_per_px: dict[int, float]
    outline_sigma: dict[int, float]
    say: Callable[[str], None]
    outline_spacing: dict[int, float] = field(default_factory=dict)
    centre: np.ndarray | None = None  # where the bone roughly is (world, mm)

    def outline_sigma_px(self, view: int) -> float:
        """View ``view``'s outline sigma of one sample in pixels (``outline_sigma`` is in mm and
        weighted by ``1 - landmark_weight``)."""
        w_out = np.sqrt(2.0 * max(1.0 - self.options.landmark_weight, 1e-12))
        return self.outline_sigma[view] / self.mm_per_px[view] * w_out

    def spacing(self, view: int) -> float:
        """The spacing (px) at which view ``view``'s outline samples count as independent."""
        return self.outline_spacing.get(view, self.options.contour_spacing_px)

    def landmark_rays(self, rejected: frozenset[int]) -> RayObservations:
        """Landmark rays with the solver's sigmas: divided by ``sqrt(2 lambda)`` for the
        landmark weight, and rejected landmarks down-weighted."""
        sig = self.landmarks.rays.sigmas / np.sqrt(2.0 * self.options.landmark_weight)
        for i in rejected:
            sig[i] *= self.options.rejected_sigma_factor
        return self.landmarks.rays.with_sigmas(sig)

    def landmark_px_errors(self, vertices: np.ndarray) -> np.ndarray:
        """Reprojection error (px) of each landmark for ``vertices``."""
        return self.landmarks.px_errors(self.views, vertices)

    def outlines(self, result: GsftResult) -> dict[int, ModelOutline]:
        """The model's outline in every view with annotated outlines, for ``result``."""
        return {
            i: model_outline(
                result.vertices,
                self.model,
                self.views[i].view,
                self.options.silhouette_points,
                self.topology,
            )
            for i in self.targets
        }

    def cost(
        self, result: GsftResult, outlines: dict[int, ModelOutline], rejected: frozenset[int]
    ) -> float:
        """The match-independent iteration cost of :mod:`.outline_match` (dimensionless)."""
        opts = self.options
        lam = opts.landmark_weight
        acc = np.array([i not in rejected for i in range(len(self.landmarks))], dtype=bool)
        e = self.landmark_px_errors(result.vertices)[acc] / self.landmarks.sigma_px[acc]
        cost = lam * float(np.mean(e**2)) if e.size else 0.0
        if self.use_outlines:
            d = np.concatenate(
                [outline_distances(outlines[i], self.targets[i]) for i in self.targets]
            )
            d = np.minimum(d, opts.gate_px) / opts.contour_sigma_px
            cost += (1.0 - lam) * float(np.mean(d**2)) if d.size else 0.0
        return cost

    def rigid_model(self) -> ShapeModel:
        """The mean shape without modes (6 pose parameters only)."""
        m = self.model
        return ShapeModel(m.mean, m.modes[:0], faces=m.faces)


def solve(
    model: ShapeModel,
    rays: RayObservations,
    options: RegistrationOptions,
    start: GsftResult | None = None,
    warm: GsftResult | None = None,
) -> GsftResult:
    """G-SfT on ``rays`` (world frame) with the options' trace and prior weights; the
    refinement also starts from ``start``'s pose and weights when given, and the SDP solve is
    warm-started from ``warm`` (``solve_gsft(..., warm_start=)``) when given."""
    initial = None if start is None else (start.rotation, start.translation, start.weights)
    return solve_gsft(
        model,
        rays,
        eps=options.eps,
        prior_weight=options.prior_weight,
        initial=initial,
        warm_start=warm,
    )


def rough_centre(
    model: ShapeModel, views: list[ViewObservations], options: RegistrationOptions
) -> np.ndarray:
    """Where the bone is (mm, world): the centroid of a first landmark-only solve with equal
    weights (the annotators' sigmas are not in mm yet)."""
    rays = stack_landmarks(views, None).rays.with_sigmas(None)
    res = solve_gsft(model, rays, eps=options.eps, prior_weight=options.prior_weight)
    return res.vertices.mean(axis=0)


def _normalised(landmarks: Landmarks, options: RegistrationOptions) -> Landmarks:
    """The landmarks with their stated sigmas scaled so that their median is
    ``start_landmark_sigma_px`` (their ratios kept): with the noise estimated from the data,
    the stated scale must not decide the convex stages' start either."""
    k = options.start_landmark_sigma_px / float(np.median(landmarks.sigma_px))
    return replace(
        landmarks,
        rays=landmarks.rays.with_sigmas(landmarks.rays.sigmas * k),
        sigma_px=landmarks.sigma_px * k,
        stated_ratio=landmarks.ratios(),
    )


def make_problem(
    model: ShapeModel,
    views: list[ViewObservations],
    options: RegistrationOptions,
    use_outlines: bool,
    say: Callable[[str], None],
    centre: np.ndarray | None = None,
) -> Problem:
    """The :class:`Problem` for ``views``; pixel sigmas are converted to mm at ``centre``
    (mm, world; default: :func:`rough_centre`)."""
    if centre is None:
        centre = rough_centre(model, views, options)
    margin = options.end_margin_px
    targets = {i: prepare_outline(v.contours, end_margin_px=margin) for i, v in enumerate(views)}
    targets = {i: t for i, t in targets.items() if t is not None}
    use_outlines = use_outlines and bool(targets)
    mmpp = {i: float(mm_per_pixel(views[i].view, centre)[0]) for i in targets}
    w_out = np.sqrt(2.0 * max(1.0 - options.landmark_weight, 1e-12))
    landmarks = stack_landmarks(views, centre)
    if options.noise == "estimated" and len(landmarks):
        landmarks = _normalised(landmarks, options)
    return Problem(
        model=model,
        views=views,
        options=options,
        landmarks=landmarks,
        targets=targets,
        use_outlines=use_outlines,
        topology=mesh_topology(model) if use_outlines else None,
        mm_per_px=mmpp,
        outline_sigma={i: options.contour_sigma_px * mmpp[i] / w_out for i in targets},
        say=say,
        centre=np.asarray(centre, float),
    )


def with_pose(result: GsftResult, rotation, translation, weights, vertices, **extra) -> GsftResult:
    """``result`` with another pose and shape (the solve's diagnostics kept)."""
    return replace(
        result,
        rotation=rotation,
        translation=translation,
        weights=weights,
        vertices=vertices,
        **extra,
    )
