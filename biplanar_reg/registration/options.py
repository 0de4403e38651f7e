"""Options and per-iteration records of the registration pipeline (:mod:`.register`).

Every number that sets how the pipeline behaves is a field of :class:`RegistrationOptions`
with its documented default, so a case file (``[registration]`` and ``[registration.expert]``
keys of the same names, docs/cases.md) or a caller can change it and ``result.json`` records
it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .gsft import DEFAULT_EPS

__all__ = ["RegistrationOptions", "IterationRecord"]

#: Default certificate above which the landmark-only relaxation counts as not tight (the rigid
#: mean-shape start is then tried too).
START_CERTIFICATE = 1e-2
#: Default gap (px) between the rounded relaxation and the returned fit above which a result is
#: flagged "relaxation not tight". Measured with known view poses, the gap (5-60 px) does not
#: predict the error (docs/registration.md, quality flags): the default sits above all those
#: fits, so the flag marks only a relaxation far off its result.
RELAXATION_FLAG_PX = 100.0
#: Default landmark reprojection error (px RMS) above which a result is flagged.
REPROJECTION_FLAG_PX = 5.0

#: Fields that must be whole numbers in ``[low, high]``. The upper bounds keep a typo (or
#: ``9223372036854775807``) from asking for hours of solves or gigabytes of rays; each is far
#: above any useful value.
COUNT_RANGES: dict[str, tuple[int, int]] = {
    "max_iterations": (0, 1000),
    "refine_iterations": (0, 10_000),
    "silhouette_points": (3, 100_000),
    "consensus_iterations": (1, 1000),
    "blunder_refine_iterations": (1, 10_000),
    "rigid_start_redundancy": (0, 10_000),
    "noise_rounds": (0, 100),
    "gp_rounds": (1, 100),
}
# fields that must be fractions in (0, 1]
_FRACTIONS = ("landmark_weight", "rejection_weight", "consensus_margin")
# fields that may be 0
_NON_NEGATIVE = ("prior_weight", "end_margin_px")
# fields with a range of their own: (low, high, low inclusive) with high inclusive
_RANGES = {
    "max_tangent_angle_deg": (0.0, 180.0, False),
    "rejected_sigma_factor": (1.0, np.inf, True),
    "gnc_factor": (1.0, np.inf, False),
    "joint_outline_sigma_factor": (1.0, np.inf, True),
    "unknown_outline_sigma_factor": (1.0, np.inf, True),
}


@dataclass(frozen=True)
class RegistrationOptions:
    """Options of :func:`.register.register_views` (documented defaults).

    Attributes
    ----------
    landmark_weight : float
        ``lambda`` in (0, 1]: landmarks weigh ``lambda``, outline matches ``1 - lambda``
        (per observation, relative to their counts; see :mod:`.outline_match`).
    max_iterations : int
        Maximum outline-boosting iterations with a convex re-solve each (0 to 1000).
    refine_iterations : int
        Maximum Levenberg-Marquardt iterations of the final joint local refinement on all terms
        (:func:`.outline_fit.refine_on_outlines`: every annotated outline point to the model's
        outline, re-matched at every step; no SDP); 0 to 10000.
    silhouette_points : int
        Model outline points used per view and iteration (fixed count: each iteration is a
        re-solve of a problem of the same size); 3 to 100000.
    gate_px : float
        Outline matches farther than this from the annotated outline are dropped, pixels.
    mutual : bool
        Keep only mutual nearest-neighbour matches.
    robust : bool
        Weight the landmarks by a robust (Geman-McClure) loss of their errors over their
        predicted sigmas (clicks and model truncation; :mod:`.blunders`), solved by graduated
        non-convexity; off: every landmark weighs 1.
    robust_threshold : float
        Width ``c`` of the robust loss in predicted sigmas (each landmark's annotated sigma
        combined with the model's truncation error at its vertex; with a model without
        truncation modes, in robust scales of the errors: their median scale, at least the
        annotated sigma). See docs/registration.md for the measurements behind the default.
        Also the number of robust sigmas of the landmark errors above which a landmark
        disagrees with the outlines (:mod:`.disagreement`; left out with known view poses).
    rejection_weight : float
        A landmark whose Geman-McClure weight at the fit is below this level (in (0, 1])
        counts as rejected and weighs 0; the others weigh 1. 0.1 is an error above 1.47 ``c``.
    gnc_factor : float
        Graduated non-convexity: the control parameter ``mu`` is divided by this (> 1) per
        reweighting step, from where the loss is nearly quadratic down to the loss itself.
    eps : float
        SDP trace weight (see :func:`.gsft.solve_gsft`).
    prior_weight : float
        Weight of the shape prior in the local refinement.
    tol : float
        Stop when the relative cost change between iterations is below this.
    contour_sigma_px : float
        Uncertainty of the annotated outlines, pixels.
    contour_spacing_px : float
        In the final refinement, annotated outline errors count as independent once every
        this many pixels along the outline (an outline is sampled at 1 px, and its errors are
        correlated over a few pixels: a traced outline wanders, it does not jitter).
    match_floor_px : float
        Smallest outlier threshold for outline matches after the first matching of a start,
        and for the final refinement's gate, pixels.
    blunder_refine_iterations : int
        Levenberg-Marquardt iterations of each refit between two reweightings of the graduated
        non-convexity (1 to 10000).
    consensus_iterations : int
        Boosting iterations of each short fit in the start choice and the robust start
        (1 to 1000).
    consensus_margin : float
        The robust start: a landmark-only start without one landmark replaces the robust
        landmark-only start when its short fit's robust cost is below this fraction (in
        (0, 1]) of the latter's (:func:`.stages.robust_start`).
    start_certificate : float
        Certificate above which the landmark-only relaxation counts as not tight: the rigid
        mean-shape start is then tried too.
    reprojection_flag_px : float
        Landmark reprojection RMS (px) above which a result is flagged.
    relaxation_flag_px : float
        A result is flagged "relaxation not tight" when the rounded solution of its convex
        relaxation and the returned fit differ by more than this in some view (RMS over the
        vertices of their projections, px; :func:`.register.relaxation_gap_px`; known view
        poses only; ``result.json`` ``metrics.relaxation_gap_px``). The gap was measured not
        to predict the error (5-60 px on realistic and real cases, good and bad fits alike):
        the default sits above all those fits.
    end_margin_px : float
        Outline matches (and, in the boosting cost, annotated points) within this many pixels
        of an open contour's ends are not used: the annotation says nothing beyond its ends,
        so a model point there is most likely outside the annotated part (>= 0).
    max_tangent_angle_deg : float
        An outline match is dropped when the model outline's direction and the annotated
        contour's differ by more than this (degrees, in (0, 180]), so the model's unannotated
        parts are not pulled onto a nearby annotated stretch running the other way.
    wide_gate_factor : float
        On the first matching from a landmark-only start the gate is widened to this multiple
        of the landmark reprojection RMS (when that exceeds ``gate_px``): a start still far off
        must not drop every match.
    rejected_sigma_factor : float
        Landmark weights are floored at ``1 / rejected_sigma_factor^2`` (>= 1): a landmark's
        sigma grows at most by this factor, so a rejected landmark no longer pulls the fit and
        the problem keeps its size (one structure for every solve).
    pose_sigma_deg : float
        ``poses = "refine"``: the expected rotation error (degrees) of each non-gauge view's
        calibration: the standard deviation of the Gaussian prior on the rotation corrections
        in the joint refinement of the views on the outlines (:mod:`.view_poses`).
    pose_sigma_mm : float
        ``poses = "refine"``: the same for the positions (mm): of the bone as seen through each
        view (``pose_prior_at_bone``) or of each view's source.
    rigid_start_redundancy : int
        The rigid mean-shape start is tried (when the relaxation is not tight) only while the
        weighted landmarks' coordinates exceed the pose and shape parameters by less than this:
        ``2 L - (6 + modes) < rigid_start_redundancy`` (:func:`.stages.choose_start`;
        0 to 10000, 0: never).
    joint_outline_sigma_factor : float
        ``poses = "refine"``: the outline sigma of the joint refinement of the
        views on the outlines is this multiple of the other stages' (>= 1). With every view's
        pose free, the outlines' systematic errors (a bone outside the model's span, an
        overlapping bone, samples correlated along the outline) are absorbed by the view poses
        along directions the images hardly see (a view's depth, the scene's scale), where the
        hundreds of outline samples outweigh the landmarks, the shape prior and the
        calibration prior (measured: ``benchmarks/results/realistic_poses.md``). The fit's own
        residuals do not show it (they stay near the click noise), so it is a fixed factor.
        5 was measured to help on realistic cases but to hurt on exact outlines of a bone
        inside the span (``benchmarks/pose_modes.py``), hence the default 1.
    unknown_outline_sigma_factor : float
        ``poses = "unknown"``: the same factor for its joint refinement (>= 1; default 5).
        Without any calibration, 3 landmarks per view fix each view's pose given the shape
        with no redundancy, so the outlines alone set the relative pose and, through the shape
        weights, the bone's size, which free view poses leave unobserved: at full weight
        their systematic errors shrank or grew the bone by up to 27 % and turned the second
        view by up to 17 deg on ``benchmarks/realistic.py`` unknown-3. 5 was chosen on seeds
        0-7 and checked on seeds 8-15 (aligned vertex RMS / known-3 median 3.17 -> 1.84 and
        2.69 -> 1.63; docs/registration.md, "Outlines in the pose modes").
    pose_prior_at_bone : bool
        ``poses = "refine"``: the calibration prior's position term is the move of the bone
        (the centre of the first registration) through each view's correction, rather than
        the move of the view's source. A calibration made with an object in the imaging volume
        (e.g. a calibration cube) is most accurate there: its errors are small at the bone and
        largest at the source (a 1 deg turn about the bone moves a source 1 m away by 17 mm).
        With it, the joint fit corrects only the directions of the corrections that the images
        see better than half the prior (:mod:`.calibration_subspace`); the others keep the
        given calibration. Default false: ``benchmarks/pose_modes.py`` (errors turning about
        the source) needs the prior on the sources.
    refine_landmark_weight : float
        In the final refinement (:func:`.stages.refine_once`) the landmarks' weight
        (``1 / sigma^2``) is multiplied by this (> 0). The landmarks carry what the outlines of
        a shaft-like bone barely show (its rotation about its long axis). 4 lowered the
        known-pose error of the realistic out-of-span cases (1.92 -> 1.77 x floor) but raised
        it where the model spans the truth and the outlines are accurate (silhouette benchmark,
        a sample case), so the default 1 keeps the convex stages' weighting
        (benchmarks/results/realistic_known_levers.md).
    noise : str
        ``"estimated"`` (default) or ``"stated"``. ``"estimated"``: each annotation group's
        noise (the landmarks of each view, the outline of each view) is estimated from the
        residuals, iterated with the final refinement (variance-component estimation,
        :mod:`.noise`); the stated sigmas keep
        only their ratios within a landmark group, so a click sigma stated as 1 or 3 px gives
        the same result. ``"stated"``: the stated landmark sigmas and ``contour_sigma_px``
        are used as they are. With ``poses`` other than ``"known"`` the noise is the stated
        one (the view poses' joint fit was tuned with it; estimated noise measured worse).
    noise_rounds : int
        Most refinements with re-estimated sigmas (0 to 100).
    start_landmark_sigma_px : float
        With ``noise = "estimated"``: the landmarks' sigmas until the noise is estimated
        (their median; the stated ratios kept), and the reference of the estimate's prior
        (:mod:`.noise`), pixels.
    gp : str
        ``"auto"`` (default) or ``"off"``. ``"auto"``: with known view poses, the fit is
        refined once more over the shape model's modes plus a smooth deformation kernel's,
        with the kernel's amplitude chosen from the data (:mod:`.gp_stage`); where the data do
        not support it, the SSM's fit is kept. A model augmented with ``ssm augment`` brings
        its own kernel. ``"off"``: the SSM's modes only (an augmented model's kernel modes
        stay at 0).
    gp_kernel : str
        The kernel when the model has none: ``"gaussian"`` (default: 3-D displacements, the
        standard Gaussian-process morphable model) or ``"gaussian-normal"`` (displacements
        along the mean shape's surface normals only; measured weaker on the realistic
        benchmark, docs/registration.md).
    gp_width_mm : float
        Width of the Gaussian deformation kernel (mm) when the model has none of its own.
    gp_amplitude_mm : float
        The kernel amplitude the data-driven choice starts from (mm) when the model has none.
    gp_rounds : int
        Most refinements of the Gaussian-process stage (1 to 100).
    gp_ssm : str
        What the Gaussian-process stage does with the SSM's weights: ``"held"`` (default) keeps
        them at their fit; ``"refit"`` refines them with the kernel's, under a prior centred
        at their fit that also charges the change for moving the vertices no outline sees,
        its scale chosen from the data like the kernel's amplitude (:mod:`.gp_stage`).
        Measured better on out-of-span synthetic cases and about neutral on the real
        radiographs (docs/registration.md).
    """

    landmark_weight: float = 0.5
    max_iterations: int = 6
    refine_iterations: int = 15
    silhouette_points: int = 150
    gate_px: float = 15.0
    mutual: bool = False
    robust: bool = True
    robust_threshold: float = 4.0
    rejection_weight: float = 0.1
    gnc_factor: float = 1.4
    eps: float = DEFAULT_EPS
    prior_weight: float = 1.0
    tol: float = 1e-4
    contour_sigma_px: float = 1.0
    contour_spacing_px: float = 5.0
    match_floor_px: float = 3.0
    blunder_refine_iterations: int = 5
    consensus_iterations: int = 1
    consensus_margin: float = 0.5
    start_certificate: float = START_CERTIFICATE
    reprojection_flag_px: float = REPROJECTION_FLAG_PX
    relaxation_flag_px: float = RELAXATION_FLAG_PX
    end_margin_px: float = 3.0
    max_tangent_angle_deg: float = 45.0
    wide_gate_factor: float = 2.0
    rejected_sigma_factor: float = 1e3
    pose_sigma_deg: float = 2.0
    pose_sigma_mm: float = 5.0
    rigid_start_redundancy: int = 14
    joint_outline_sigma_factor: float = 1.0
    unknown_outline_sigma_factor: float = 5.0
    pose_prior_at_bone: bool = False
    refine_landmark_weight: float = 1.0
    noise: str = "estimated"
    noise_rounds: int = 5
    start_landmark_sigma_px: float = 2.0
    gp: str = "auto"
    gp_kernel: str = "gaussian"
    gp_width_mm: float = 25.0
    gp_amplitude_mm: float = 1.0
    gp_rounds: int = 6
    gp_ssm: str = "held"

    def __post_init__(self) -> None:
        for f in fields(self):
            _check_field(f.name, getattr(self, f.name), f.default)


#: Fields that take one of a few words.
CHOICES: dict[str, tuple[str, ...]] = {
    "noise": ("estimated", "stated"),
    "gp": ("auto", "off"),
    "gp_kernel": ("gaussian", "gaussian-normal"),
    "gp_ssm": ("held", "refit"),
}


def _check_field(key: str, value: object, default: object) -> None:
    """Raise ``ValueError`` naming ``key`` when ``value`` is not a valid option value."""
    if key in CHOICES:
        _check_choice(key, value)
    elif isinstance(default, bool):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{key}: expected true or false, got {value!r}")
    else:
        _check_number(key, value)


def _check_choice(key: str, value: object) -> None:
    if value not in CHOICES[key]:
        raise ValueError(f"{key}: expected one of {list(CHOICES[key])}, got {value!r}")


def _check_number(key: str, value: object) -> None:
    """Raise ``ValueError`` naming ``key`` when ``value`` is not a valid number for it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ValueError(f"{key}: expected a number, got {value!r}")
    v = float(value)
    if key in COUNT_RANGES:
        if not np.isfinite(v) or not v.is_integer():
            raise ValueError(f"{key}: expected a whole number, got {value!r}")
        low, high = COUNT_RANGES[key]
        if value < low:
            raise ValueError(f"{key}: too small ({value}; at least {low})")
        if value > high:
            raise ValueError(f"{key}: too large ({value}; at most {high})")
    elif key in _FRACTIONS:
        if not 0.0 < v <= 1.0:
            raise ValueError(f"{key}: must be in (0, 1], got {value}")
    elif key in _NON_NEGATIVE:
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{key}: must be >= 0, got {value!r}")
    elif key in _RANGES:
        low, high, low_ok = _RANGES[key]
        if not (v >= low if low_ok else v > low) or not v <= high or not np.isfinite(v):
            raise ValueError(
                f"{key}: must be in {'[' if low_ok else '('}{low:g}, {high:g}], got {value!r}"
            )
    elif not np.isfinite(v) or v <= 0:
        raise ValueError(f"{key}: must be a positive number, got {value!r}")


@dataclass(frozen=True)
class IterationRecord:
    """One solve of the registration: iteration 0 is the landmark-only solve.

    ``kind`` is ``"sdp"`` for a convex re-solve (its ``certificate`` is that solve's; ``cost``
    the match-independent iteration cost of :mod:`.outline_match`, ``n_matches`` the outline
    matches used) and ``"local"`` for an accepted Levenberg-Marquardt step of the final
    refinement (``cost`` is the objective it minimises, :mod:`.outline_fit`, which never
    increases within one refinement; a re-admitted landmark starts a second refinement whose
    objective includes it, so the costs may rise once there; ``n_matches`` the annotated
    outline samples within its gate; ``certificate`` is the last SDP's).
    ``"noise"`` is an accepted step of a refinement with re-estimated sigmas (``noise =
    "estimated"``): its objective has other sigmas, so its costs continue on their own scale.
    The costs of different kinds are not on one scale.
    """

    index: int
    cost: float
    n_matches: int  # 0 at iteration 0
    certificate: float
    seconds: float
    kind: str = "sdp"
