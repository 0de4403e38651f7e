"""Re-registration from a previous fit (a "warm start"): after a small edit of the annotations,
start from the last result instead of from the landmarks.

A cold registration spends most of its time finding the start (the landmark-only convex solve,
the robust start's short fits), estimating each annotation group's noise from the residuals and
choosing the Gaussian-process kernel's amplitude (:mod:`.gp_stage`), each by rounds of local
refinement. After an edit of a few landmarks or contours the previous fit is already near the
new optimum: :class:`PreviousFit` holds its pose, shape weights, registered vertices, estimated
noise and kernel amplitude, and :func:`.register.register_views` (``start_from=``) then runs the
outline boosting from that pose and shape, the final refinement with those sigmas as the start
of the noise estimate, and one refinement of the kernel's weights at that amplitude.

When the previous fit cannot be trusted as a start the registration runs cold and says why
(:func:`refusal`): another model, views, view-pose mode or options (:func:`setup_fingerprint`
differs), or a landmark the previous fit now misses by much more than before (a landmark
moved, added or re-assigned by more than :data:`SHIFT_SIGMAS` of its view's noise). After a warm
fit :func:`warm_problems` lists what makes it fall back to a cold start: the refinement did
not converge, the set of rejected landmarks changed, a landmark now disagrees with the
outlines, or the robust cost grew more than :data:`COST_RATIO` times the previous one.

Frames and units: world frame, mm; image quantities in pixels.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..pose import nearest_rotation
from ..ssm.model import ShapeModel
from .gp_stage import KernelBasis
from .gsft import GsftResult
from .noise import GroupNoise, with_noise
from .observations import ViewObservations
from .options import RegistrationOptions
from .problem import Problem, with_pose
from .stages import pose_start

__all__ = ["PreviousFit", "setup_fingerprint"]

#: A landmark whose error at the previous fit changed by more than this many times its view's
#: landmark sigma (px; the previous fit's estimate, else the stated one) sends the registration
#: to a cold start: a moved, added or re-assigned landmark the previous pose may not explain.
SHIFT_SIGMAS = 3.0
#: ... but never below this many pixels (a sigma estimated from few landmarks can be small).
SHIFT_MIN_PX = 5.0
#: A warm fit whose robust cost is above this many times the previous fit's falls back to cold.
COST_RATIO = 1.5
#: Flags of a warm fit that make it fall back to cold when the previous fit did not have them:
#: they say the fit may sit in another basin, which a cold start decides better.
FIT_FLAGS = (
    "local refinement did not converge",
    "landmark disagrees with the outlines",
    "shape outside the model's plausible range",
)


@dataclass(frozen=True)
class PreviousFit:
    """A previous registration of the same case to start from (world frame, mm).

    Attributes
    ----------
    rotation, translation : (3, 3), (3,) arrays
        The model's pose (model -> world).
    weights : (M,) array
        Shape weights of the SSM's modes (``RegistrationResult.weights``; the kernel modes of
        an augmented model, if any, are ignored).
    fingerprint : str
        :func:`setup_fingerprint` of the registration that made it.
    vertices : (N, 3) array, optional
        Its registered vertices (with the kernel's displacement): the kernel's weights start
        from their least-squares fit to them.
    gp_amplitude_mm : float, optional
        The kernel amplitude it used (None: the stage was off or not supported).
    noise : tuple of (kind, view, sigma_px, spacing_px)
        Each annotation group's sigma in its final fit (``result.json["noise"]["groups"]``).
    landmark_errors_px : mapping
        ``{view: {landmark: px}}`` at the previous fit (to see which landmarks moved).
    rejected : frozenset of (view, landmark)
    flags : tuple of str
    robust_cost : float, optional
        :func:`.blunders.robust_cost` of its final fit.
    """

    rotation: np.ndarray
    translation: np.ndarray
    weights: np.ndarray
    fingerprint: str
    vertices: np.ndarray | None = field(default=None, repr=False)
    gp_amplitude_mm: float | None = None
    noise: tuple = ()
    landmark_errors_px: Mapping = field(default_factory=dict)
    rejected: frozenset = frozenset()
    flags: tuple = ()
    robust_cost: float | None = None


def _digest_value(h, value) -> None:
    """Feed one value (array, number, string, nested dataclass or mapping) into hash ``h``."""
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(type(value).__name__.encode())
        for f in dataclasses.fields(value):
            h.update(f.name.encode())
            _digest_value(h, getattr(value, f.name))
    else:
        h.update(json.dumps(value, sort_keys=True, default=repr).encode())


def setup_fingerprint(
    model: ShapeModel,
    views: list[ViewObservations],
    poses: str,
    silhouettes: bool,
    options: RegistrationOptions,
) -> str:
    """A SHA-256 (hex) of what a registration is made of except its annotations: the model's
    mean, modes and faces, each view's name and camera (every field of its calibration), the
    view-pose mode, whether outlines are used and the options. Two registrations with the same
    fingerprint differ only in their landmarks and contours."""
    h = hashlib.sha256()
    for a in (model.mean, model.modes, model.faces):
        _digest_value(h, np.zeros(0) if a is None else np.asarray(a))
    for v in views:
        h.update(v.name.encode())
        _digest_value(h, v.view)
    _digest_value(h, [poses, bool(silhouettes), dataclasses.asdict(options)])
    return h.hexdigest()


def _landmark_limit(previous: PreviousFit, view: str, stated_px: float) -> float:
    """The change (px) of a landmark's error at the previous fit that counts as substantial."""
    sigma = stated_px
    for kind, name, s, _ in previous.noise:
        if kind == "landmarks" and name == view:
            sigma = float(s)
    return max(SHIFT_MIN_PX, SHIFT_SIGMAS * sigma)


def refusal(
    previous: PreviousFit, fingerprint: str, model: ShapeModel, views: list[ViewObservations]
) -> str | None:
    """Why ``previous`` cannot start this registration (one line), or None when it can.

    Refused: another setup (``fingerprint``), weights of another length, non-finite numbers,
    or a landmark whose reprojection error at the previous fit differs from the one recorded
    there (a new landmark: from 0) by more than :func:`_landmark_limit`.
    """
    if previous.fingerprint != fingerprint:
        return "the model, views or options changed since the previous result"
    w = np.asarray(previous.weights, float)
    if len(w) < model.n_modes:
        return f"the previous result has {len(w)} shape weights, the model {model.n_modes}"
    arrays = (previous.rotation, previous.translation, w)
    if not all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays):
        return "the previous result has non-finite numbers"
    X = previous.vertices  # the previous fit as registered (its kernel displacement too)
    if X is None or np.shape(X) != (model.n_vertices, 3) or not np.all(np.isfinite(X)):
        X = model.instance(w[: model.n_modes]) @ np.asarray(previous.rotation).T
        X = X + np.asarray(previous.translation)
    for v in views:
        if not len(v.landmark_ids):
            continue
        err = np.linalg.norm(v.view.project(X[v.landmark_ids]) - v.landmark_uv, axis=1)
        before = previous.landmark_errors_px.get(v.name, {})
        for name, e, s in zip(v.landmark_names, err, v.landmark_sigma_px, strict=True):
            shift = abs(float(e) - float(before.get(name, 0.0)))
            if shift > _landmark_limit(previous, v.name, float(s)):
                return f"landmark {v.name}/{name} changed by {shift:.0f} px at the previous fit"
    return None


def _flag_key(flag: str) -> str:
    """A flag without its numbers (``landmark disagrees with the outlines: cam1/tip``)."""
    return flag.split(" by ")[0].split(" (")[0]


def warm_problems(previous: PreviousFit, flags: list[str], rejected, robust_cost: float) -> str:
    """Why a warm fit falls back to a cold start (one line; "" when it is kept): new fit flags
    (:data:`FIT_FLAGS`), another set of rejected landmarks, or a robust cost above
    :data:`COST_RATIO` times the previous fit's."""
    before = {_flag_key(p) for p in previous.flags}
    for f in flags:
        if f.startswith(FIT_FLAGS) and _flag_key(f) not in before:
            return f"the warm fit has a new flag ({f})"
    now = frozenset((str(v), str(n)) for v, n in rejected)
    if now != previous.rejected:
        return "the warm fit rejects other landmarks than the previous result"
    before = previous.robust_cost
    if before is not None and np.isfinite(before) and robust_cost > COST_RATIO * before:
        return f"the warm fit's robust cost {robust_cost:.3g} is above {COST_RATIO} x {before:.3g}"
    return ""


def start_centre(previous: PreviousFit, model: ShapeModel) -> np.ndarray:
    """The previous fit's centre (mm, world): where the problem converts pixel sigmas to mm."""
    X = model.instance(np.asarray(previous.weights, float)[: model.n_modes])
    return X.mean(axis=0) @ np.asarray(previous.rotation, float).T + previous.translation


def previous_start(problem: Problem, previous: PreviousFit) -> GsftResult:
    """The previous fit's pose and shape as the boosting's start (iteration 0), a result
    without a convex solve (its relaxation diagnostics are the pose itself)."""
    model = problem.model
    R = nearest_rotation(np.asarray(previous.rotation, float))
    t = np.asarray(previous.translation, float)
    w = np.asarray(previous.weights, float)[: model.n_modes]
    quiet = dataclasses.replace(problem, say=lambda msg: None)
    start = pose_start(quiet, R, t).result  # the mean shape there; the shape follows
    return with_pose(start, R, t, w, model.instance(w) @ R.T + t, sdp_weights=w)


def previous_weights(problem: Problem, previous: PreviousFit) -> np.ndarray | None:
    """Landmark weights (L,) that reject what the previous fit rejected (None: none)."""
    if not previous.rejected or not len(problem.landmarks):
        return None
    names = [(str(v), str(n)) for v, n in problem.landmarks.names]
    return np.array([0.0 if n in previous.rejected else 1.0 for n in names])


def seeded_noise(problem: Problem, previous: PreviousFit) -> Problem:
    """``problem`` with the previous fit's group sigmas (``noise = "estimated"``): the noise
    estimate starts there and, after a small edit, is settled at once (:mod:`.noise`)."""
    if problem.options.noise != "estimated" or not previous.noise:
        return problem
    index = {v.name: i for i, v in enumerate(problem.views)}
    lm_views = set(np.unique(problem.landmarks.rays.view_index).tolist())
    groups = []
    for kind, view, sigma, spacing in previous.noise:
        i = index.get(view)
        ok = i is not None and (i in problem.targets if kind == "outline" else i in lm_views)
        if ok and np.isfinite(sigma) and sigma > 0 and np.isfinite(spacing) and spacing > 0:
            groups.append(GroupNoise(kind, i, float(sigma), 0.0, 0.0, float(spacing)))
    return with_noise(problem, groups)


def kernel_start(model: ShapeModel, basis: KernelBasis, previous: PreviousFit) -> np.ndarray | None:
    """The kernel weights (K,) at ``basis.start_amplitude_mm`` whose displacement best fits
    the previous fit's (its vertices in the model frame less its SSM shape; least squares), or
    None without its vertices."""
    if previous.vertices is None or len(previous.vertices) != model.n_vertices:
        return None
    R, t = np.asarray(previous.rotation, float), np.asarray(previous.translation, float)
    shape = model.instance(np.asarray(previous.weights, float)[: model.n_modes])
    d = (np.asarray(previous.vertices, float) - t) @ R - shape  # object frame
    A = basis.start_amplitude_mm * basis.modes.reshape(len(basis.modes), -1).T
    return np.linalg.lstsq(A, d.ravel(), rcond=None)[0]
