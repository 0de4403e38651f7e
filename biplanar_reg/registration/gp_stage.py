"""The Gaussian-process stage: a last refinement beyond the shape model's span.

The convex stages and the final refinement (:mod:`.stages`) fit the SSM's few modes; a bone
outside their span keeps the model's floor however good the radiographs are. This stage adds a
smooth deformation kernel's modes (:mod:`biplanar_reg.ssm.gaussian_process`: the model's own
kernel modes when it was augmented with ``ssm augment``, else a kernel ``gp_kernel`` of width
``gp_width_mm`` on the mean shape) to the SSM's fit and refines the pose and the kernel's
weights on the same objective (:mod:`.outline_fit`), choosing the kernel's amplitude ``A`` from
the data by type-II maximum likelihood (MacKay 1992, "Bayesian interpolation"): with the kernel
weights ``u`` in units of ``A`` (prior ``N(0, 1 / lambda)``, ``lambda`` the prior weight) and
the Gauss-Newton posterior covariance ``C`` of the objective at the fit, the number of kernel
parameters the data determine is ``gamma = K - lambda tr(C_uu)``, and the evidence is
stationary at

    A_new^2 = A^2 lambda |u|^2 / gamma.

The refinement, the annotation groups' noise (``noise = "estimated"``, :mod:`.noise`) and the
amplitude are re-estimated in turn until the amplitude settles (at most ``gp_rounds``
refinements). When the data do not support the kernel (``A`` falls below
:data:`MIN_AMPLITUDE_MM`) the stage returns the SSM's fit unchanged and says so.

By default (``gp_ssm = "held"``) the SSM's weights stay those of its fit. Refined jointly
with the kernel's, they were measured to slide: the kernel took over the fit where the
radiographs see the bone, which freed an SSM mode to reshape what they do not (the realistic
benchmark's seed 10: the far 20 % of the bone went from 0.5 to 2.6 mm off while the rest
improved). ``gp_ssm = "refit"`` refines them all the same, their change ``dw`` from the fit
under the prior ``lambda dw^T (I + mu U) dw / b^2`` (:func:`change_basis`: centred at the
fit, and charging the change for moving the vertices no annotated outline sees), with its
scale ``b`` chosen by the same fixed point as ``A``, each block's ``gamma`` computed alike.
The kernel's own displacement decays
within about its width from the annotated outlines and landmarks, so it changes the bone only
where the images show it. An annotated point is matched across the model's outline
(:mod:`.outline_fit`), so a kernel could also slide points along it; only the landmarks, which
stay in the objective with their estimated sigmas, pin points along the outline (no further
guard against sliding: on the real wrist cases the stage was measured neutral, with one case
worse, docs/registration.md).

Frames and units: world frame, mm; amplitudes in mm.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._content import ContentCache, content_key
from ..ssm.gaussian_process import (
    DEFAULT_REL_TOL,
    orthogonal_kernel_modes,
    split_modes,
    ssm_part,
)
from ..ssm.model import ShapeModel
from .noise import group_noise, with_noise
from .problem import Problem, with_pose
from .stages import Recorder, Refined, refine_once, refine_terms
from .uncertainty import linearise_fit

__all__: list[str] = []

#: Below this amplitude (mm) the kernel is switched off: the data do not support it.
MIN_AMPLITUDE_MM = 0.05
#: The amplitude has settled when it changes by less than this (relative).
AMPLITUDE_TOL = 0.1
#: ``gp_ssm = "refit"``: the least scale of the SSM weights' change (SSM sds); below it the
#: change is as good as held, and the scale stays positive for the rescaling of the weights.
MIN_SSM_SCALE = 1e-3
#: ``gp_ssm = "refit"``: a vertex is seen when it projects within this many pixels of an
#: annotated outline point in some view (at the SSM's fit).
SEEN_PX = 15.0
#: ``gp_ssm = "refit"``: how much more the prior charges the SSM weights' change for moving the
#: vertices no outline sees than the SSM's own prior does (:func:`change_basis`). Measured
#: (``benchmarks/gp_levers.py --real``, columns ``refit`` and ``refit, no charge``): without
#: it two realistic seeds and four of the 40 real registrations ended more than 10 % worse
#: than with the weights held; with it one real registration (docs/registration.md).
UNSEEN_FIRMNESS = 30.0


@dataclass(frozen=True)
class KernelBasis:
    """The kernel's modes at unit amplitude and where they come from.

    Attributes
    ----------
    modes : (K, N, 3) array
        Kernel modes at ``A = 1 mm`` (mm per unit weight), object frame.
    start_amplitude_mm : float
        The amplitude the stage starts from (the model's, or ``gp_amplitude_mm``).
    width_mm : float
    from_model : bool
        True when the modes are the model's own (an augmented model).
    """

    modes: np.ndarray
    start_amplitude_mm: float
    width_mm: float
    from_model: bool
    kernel: str = "gaussian"


def kernel_basis(
    model: ShapeModel, kernel: str, width_mm: float, amplitude_mm: float
) -> KernelBasis:
    """The kernel modes of ``model`` (augmented), or of ``kernel`` (one of
    :data:`biplanar_reg.ssm.gaussian_process.KERNELS`) on its mean shape, made orthogonal to
    the SSM's modes. (The kernel's own modes were measured better on the realistic cases and
    worse on the real wrist cases with the CT template: docs/registration.md, step 9.)"""
    info = split_modes(model)
    if info is not None:
        extra = model.modes[info.ssm_modes :] / info.amplitude_mm
        return KernelBasis(extra, info.amplitude_mm, info.width_mm, True, info.kernel)
    if kernel == "gaussian-normal" and model.faces is None:
        kernel = "gaussian"  # a point model has no normals
    faces = np.zeros((0, 3), int) if model.faces is None else model.faces
    key = (content_key(model.mean, model.modes, faces), kernel, float(width_mm))
    modes = _KERNEL_MODES.get(key, lambda: _unit_modes(model, kernel, width_mm))
    return KernelBasis(modes, float(amplitude_mm), float(width_mm), False, kernel)


#: Kernel modes by model content, kernel and width: the same for every case of a batch.
_KERNEL_MODES: ContentCache[np.ndarray] = ContentCache()


def _unit_modes(model: ShapeModel, kernel: str, width_mm: float) -> np.ndarray:
    """The kernel's modes at unit amplitude, orthogonal to the model's (read-only: shared)."""
    modes, _ = orthogonal_kernel_modes(model, kernel, width_mm, 1.0, DEFAULT_REL_TOL)
    modes.setflags(write=False)
    return modes


def registration_model(model: ShapeModel) -> ShapeModel:
    """The model the convex stages run on: the SSM's modes of an augmented model."""
    return ssm_part(model)


def _augmented(base: ShapeModel, basis: KernelBasis, amplitude: float) -> ShapeModel:
    return ShapeModel(
        base.mean,
        np.concatenate([base.modes, amplitude * basis.modes]),
        faces=base.faces,
        landmarks=base.landmarks,
        truncation_modes=base.truncation_modes,
    )


def _stage_model(
    base: ShapeModel,
    weights: np.ndarray,
    basis: KernelBasis,
    amplitude: float,
    ssm_change: np.ndarray | None = None,
) -> ShapeModel:
    """The model the stage refines: the SSM's fit as the mean, the kernel's modes at
    ``amplitude`` as the modes (``gp_ssm = "held"``: the pose and the kernel's weights only),
    preceded with ``gp_ssm = "refit"`` by ``ssm_change``, the modes of the SSM weights' change
    (:func:`change_basis`, at its scale)."""
    parts = [] if ssm_change is None else [ssm_change]
    parts.append(amplitude * basis.modes)
    return ShapeModel(
        base.instance(weights),
        np.concatenate(parts),
        faces=base.faces,
        landmarks=base.landmarks,
        truncation_modes=base.truncation_modes,
    )


def seen_vertices(problem: Problem, vertices: np.ndarray) -> np.ndarray:
    """(N,) bool: the vertices (world frame, mm) that project within :data:`SEEN_PX` of an
    annotated outline point in some view."""
    from scipy.spatial import cKDTree  # only here: a registration leaves scipy unloaded

    seen = np.zeros(len(vertices), bool)
    for i, target in problem.targets.items():
        uv = problem.views[i].view.project(vertices)
        distance, _ = cKDTree(target.points).query(uv)
        seen |= distance < SEEN_PX
    return seen


def change_basis(model: ShapeModel, seen: np.ndarray) -> np.ndarray:
    """(M, M) ``S``: with ``gp_ssm = "refit"`` the SSM weights' change is ``dw = S z``, ``z``
    under the SSM's prior ``N(0, 1 / lambda)``, so that the change's prior is
    ``lambda dw^T (I + mu U) dw``: ``U`` the mean squared displacement per weight of the
    vertices not ``seen`` over that of all vertices (trace / M), ``mu`` =
    :data:`UNSEEN_FIRMNESS`. Why: freed, the SSM's modes otherwise reshape what no
    radiograph shows to fit what they do (docs/registration.md)."""
    M = model.n_modes
    P = model.modes.reshape(M, -1)
    unseen = model.modes[:, ~seen].reshape(M, -1)
    if unseen.shape[1] == 0:
        return np.eye(M)
    U = (unseen @ unseen.T / np.count_nonzero(~seen)) / (np.trace(P @ P.T) / model.n_vertices / M)
    values, vectors = np.linalg.eigh(np.eye(M) + UNSEEN_FIRMNESS * U)
    return vectors @ np.diag(values**-0.5) @ vectors.T


def evidence_terms(
    problem: Problem, result, weights: np.ndarray | None, blocks: list[slice]
) -> list[tuple[float, float]]:
    """``(lambda |x|^2, gamma)`` of each block ``x`` of the shape weights at ``result``
    (module docstring: ``gamma`` the number of the block's parameters the data determine)."""
    lm, terms = refine_terms(problem, problem.outlines(result), weights)
    state = (result.rotation, result.translation, result.weights)
    lin = linearise_fit(problem.model, state, lm, terms, problem.topology)
    lam = problem.options.prior_weight
    M = problem.model.n_modes
    H = lin.jacobian.T @ lin.jacobian
    H[6:, 6:] += lam * np.eye(M)
    C = np.linalg.pinv(H)
    out = []
    for b in blocks:
        x = result.weights[b]
        k = slice(6 + b.start, 6 + b.stop)
        gamma = len(x) - lam * float(np.trace(C[k, k]))
        out.append((lam * float(x @ x), max(gamma, 0.0)))
    return out


def kernel_evidence_terms(
    problem: Problem, result, weights: np.ndarray | None, n_base: int
) -> tuple[float, float]:
    """``(lambda |u|^2, gamma)`` of the kernel weights at ``result``: the weights after the
    first ``n_base`` (:func:`evidence_terms`)."""
    return evidence_terms(problem, result, weights, [slice(n_base, problem.model.n_modes)])[0]


def _fixed_point(scale: float, x2: float, gamma: float) -> float:
    """MacKay's update of a prior's scale from ``(lambda |x|^2, gamma)`` of its weights."""
    return scale * float(np.sqrt(x2 / gamma)) if gamma > 1e-9 else 0.0


@dataclass(frozen=True)
class GpOutcome:
    """What the stage did, for ``result.json`` and the report."""

    used: bool
    width_mm: float
    amplitude_mm: float
    modes: int
    effective_modes: float
    rounds: int
    reason: str = ""
    kernel: str = "gaussian"
    ssm_scale: float | None = None  # gp_ssm = "refit": the SSM weights' change's prior scale

    def as_dict(self) -> dict:
        """Plain numbers for ``result.json`` (``RegistrationResult.gp``)."""
        return {
            "used": self.used,
            "kernel": self.kernel,
            "width_mm": self.width_mm,
            "amplitude_mm": self.amplitude_mm,
            "modes": self.modes,
            "effective_modes": self.effective_modes,
            "rounds": self.rounds,
            **({"ssm_scale": self.ssm_scale} if self.ssm_scale is not None else {}),
            **({"reason": self.reason} if self.reason else {}),
        }


def gp_stage(
    problem: Problem,
    final: Refined,
    basis: KernelBasis,
    *,
    rounds: int | None = None,
    start: np.ndarray | None = None,
) -> tuple[Problem, Refined, GpOutcome]:
    """Refine ``final`` over the SSM's and the kernel's modes (module docstring).

    Parameters
    ----------
    problem : Problem
        The problem of ``final`` (its model has the SSM's modes only).
    final : Refined
        The final refinement's output.
    basis : KernelBasis
        The kernel's modes (:func:`kernel_basis`).
    rounds : int, optional
        At most this many refinements (default ``gp_rounds``). With 1 the kernel's weights
        are refined at ``basis.start_amplitude_mm``, which is the amplitude returned (a
        re-registration from a previous fit keeps its amplitude: :mod:`.previous`).
    start : (K,) array, optional
        The kernel's weights to start from (at ``basis.start_amplitude_mm``; default 0).

    Returns
    -------
    problem, refined, outcome
        The problem with the augmented model and the refined fit (its steps recorded with
        kind ``"gp"``); or ``problem`` and ``final`` unchanged when the data do not support
        the kernel (``outcome.used`` False).
    """
    opts = problem.options
    base, w0 = problem.model, final.result.weights
    n_k = len(basis.modes)
    a, u = basis.start_amplitude_mm, np.zeros(n_k)
    records, iterates = list(final.records), list(final.iterates)
    prob, res, weights, groups = problem, final.result, final.weights, final.noise
    if start is not None and np.shape(start) == u.shape and np.all(np.isfinite(start)):
        u = np.asarray(start, float)  # the shape it gives:
        d = np.tensordot(a * u, basis.modes, axes=1)
        X = (base.instance(w0) + d) @ res.rotation.T + res.translation
        res = with_pose(res, res.rotation, res.translation, w0, X)
    # gp_ssm = "refit" (not from a previous fit's kernel weights): the SSM weights' change
    # from their fit comes first, its prior's scale b (SSM sds) chosen like the amplitude
    b = 1.0 if opts.gp_ssm == "refit" and start is None else None
    n_b = 0 if b is None else base.n_modes
    S = None if b is None else change_basis(base, seen_vertices(problem, res.vertices))
    change = None if S is None else np.tensordot(S.T, base.modes, axes=1)
    x = np.concatenate([np.zeros(n_b), u])
    outcome = GpOutcome(False, basis.width_mm, a, n_k, 0.0, 0, "no rounds", basis.kernel, b)
    for done in range(1, (opts.gp_rounds if rounds is None else rounds) + 1):
        ssm_change = None if b is None else b * change
        prob = replace(prob, model=_stage_model(base, w0, basis, a, ssm_change))
        res = with_pose(res, res.rotation, res.translation, x, res.vertices)
        rec = Recorder(prob, records, iterates, res.certificate, "gp")
        res, _ = refine_once(prob, res, prob.outlines(res), weights, rec)
        if opts.noise == "estimated":
            groups = group_noise(prob, res, weights)
            prob = with_noise(prob, groups)
        blocks = [slice(n_b, n_b + n_k)] + ([slice(0, n_b)] if n_b else [])
        terms = evidence_terms(prob, res, weights, blocks)
        a_new = _fixed_point(a, *terms[0])
        b_new = None if b is None else max(_fixed_point(b, *terms[1]), MIN_SSM_SCALE)
        prob.say(
            f"gaussian-process stage: amplitude {a:.3g} -> {a_new:.3g} mm "
            f"({terms[0][1]:.1f} effective kernel modes)"
            + ("" if b is None else f", SSM change scale {b:.3g} -> {b_new:.3g}")
        )
        outcome = GpOutcome(True, basis.width_mm, a, n_k, terms[0][1], done, "", basis.kernel, b)
        if a_new < MIN_AMPLITUDE_MM:
            reason = f"not supported by the data: amplitude {a_new:.2g} mm"
            return problem, final, replace(outcome, used=False, reason=reason)
        settled = abs(a_new / a - 1.0) < AMPLITUDE_TOL
        settled = settled and (b is None or abs(b_new / b - 1.0) < AMPLITUDE_TOL)
        x = res.weights.copy()  # the same displacement at the new scales
        x[n_b:] *= a / a_new
        if n_b:
            x[:n_b] *= b / b_new
        a, b = a_new, b_new
        if settled:
            break
    # the whole model (the SSM's modes, then the kernel's at the amplitude of the fit) for
    # what follows: the flags, the uncertainty (which includes the kernel's modes)
    prob = replace(prob, model=_augmented(base, basis, outcome.amplitude_mm))
    dw = outcome.ssm_scale * S @ res.weights[:n_b] if n_b else 0.0
    w = np.concatenate([w0 + dw, res.weights[n_b:]])
    res = with_pose(res, res.rotation, res.translation, w, res.vertices)
    refined = Refined(
        res, prob.outlines(res), records, iterates, records[-1].index, weights, prob, groups,
        final.left_out,
    )  # fmt: skip
    return prob, refined, outcome
