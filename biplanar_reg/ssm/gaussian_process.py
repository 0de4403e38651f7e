"""A Gaussian-process shape model: the SSM's covariance plus a smooth deformation kernel.

A shape model of a few subjects spans few shapes: a patient's bone lies outside its span by
the model's floor, whatever the radiographs show. A Gaussian-process morphable model (Luthi et
al. 2017, "Gaussian Process Morphable Models", IEEE TPAMI) adds a smooth deformation prior to
the model's own covariance,

    k(x, y) = Sigma_SSM(x, y) + A^2 exp(-|x - y|^2 / (2 W^2)) I_3,

with ``x``, ``y`` points of the mean shape (object frame, mm), ``W`` the kernel width and ``A``
the amplitude (the prior standard deviation of each coordinate's displacement), both mm. The
kernel part is approximated with few modes by the Nystrom method: the kernel's eigenvectors on
``m`` inducing points (the mean's vertices picked by farthest-point sampling, about ``W / 2``
apart) extended to every vertex, keeping the leading eigenvalues that hold ``1 - rel_tol`` of
its trace. Each scalar eigenfunction gives three modes (one per axis). The result is a plain
:class:`ShapeModel` whose first modes are the SSM's and the rest the kernel's, scaled to unit
prior weights like the SSM's, so every solver and :func:`.statismo.write_statismo` (statismo
stores exactly such a low-rank model) take it as it is. Its provenance records which modes are
which (``"gaussian_process"``), so the registration can start on the SSM's modes alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import ShapeModel
from .surface import vertex_normals

__all__ = [
    "KERNELS",
    "GaussianProcessInfo",
    "augment_model",
    "gaussian_kernel_modes",
    "orthogonal_kernel_modes",
    "split_modes",
    "ssm_part",
]

#: Provenance key of an augmented model.
PROVENANCE_KEY = "gaussian_process"
#: Default share of the kernel's trace the modes leave out.
DEFAULT_REL_TOL = 0.01
#: Most inducing points (the eigenproblem is m x m).
MAX_INDUCING = 600


@dataclass(frozen=True)
class GaussianProcessInfo:
    """How a model was augmented (:func:`augment_model`).

    Attributes
    ----------
    ssm_modes : int
        The first ``ssm_modes`` modes are the original model's; the rest are the kernel's.
    width_mm, amplitude_mm : float
        Kernel width ``W`` and amplitude ``A`` (mm).
    kernel : str
        One of :data:`KERNELS`.
    captured : float
        Share of the kernel's variance (trace over the mean's vertices) the modes hold.
    """

    ssm_modes: int
    width_mm: float
    amplitude_mm: float
    kernel: str = "gaussian"
    captured: float = 1.0

    def as_dict(self) -> dict:
        """Plain JSON-serialisable dict (the model's provenance entry)."""
        return {
            "ssm_modes": self.ssm_modes,
            "width_mm": self.width_mm,
            "amplitude_mm": self.amplitude_mm,
            "kernel": self.kernel,
            "captured": self.captured,
        }


def _check_positive(name: str, value: float) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: expected a positive number of mm, got {value!r}")
    return v


def farthest_points(points: np.ndarray, spacing: float, max_points: int) -> np.ndarray:
    """Indices of a farthest-point sample of ``points`` (N, 3): points are added until every
    point is within ``spacing`` of one (mm), at most ``max_points``; starts at the point
    farthest from the centroid (deterministic)."""
    d = np.linalg.norm(points - points.mean(axis=0), axis=1)
    chosen = [int(np.argmax(d))]
    dist = np.linalg.norm(points - points[chosen[0]], axis=1)
    while len(chosen) < min(max_points, len(points)):
        i = int(np.argmax(dist))
        if dist[i] <= spacing:
            break
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(points - points[i], axis=1))
    return np.array(chosen, dtype=np.int64)


def _gaussian(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    d2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2.0 * a @ b.T
    return np.exp(-np.maximum(d2, 0.0) / (2.0 * width * width))


def gaussian_kernel_modes(
    points: object,
    width_mm: float,
    amplitude_mm: float,
    *,
    rel_tol: float = DEFAULT_REL_TOL,
    max_inducing: int = MAX_INDUCING,
    normals: object | None = None,
) -> tuple[np.ndarray, float]:
    """Low-rank modes of the Gaussian deformation kernel on ``points`` (module docstring).

    Parameters
    ----------
    points : (N, 3) array
        Where the kernel is evaluated (the mean shape, object frame, mm).
    width_mm, amplitude_mm : float
        Kernel width ``W`` and amplitude ``A``, mm.
    rel_tol : float
        Share of the (Nystrom-approximated) kernel trace left out by the truncation, in (0, 1).
    max_inducing : int
        Most inducing points.
    normals : (N, 3) array, optional
        Unit surface normals at ``points``: the displacement is then along them only,
        ``k(x, y) n(x) n(y)^T`` (kernel ``"gaussian-normal"``: it changes the surface, it
        does not slide points along it).

    Returns
    -------
    modes : (3 K, N, 3) array, or (K, N, 3) with ``normals``
        mm per unit weight; ``sum_k modes[k] modes[k]^T`` approximates ``A^2 exp(...) I_3``.
    captured : float
        Share of the kernel's exact trace ``N A^2`` per axis that the modes hold.
    """
    P = np.asarray(points, dtype=float)
    width = _check_positive("width", width_mm)
    amp = _check_positive("amplitude", amplitude_mm)
    if not 0 < rel_tol < 1:
        raise ValueError(f"rel_tol: expected a number in (0, 1), got {rel_tol!r}")
    ind = farthest_points(P, width / 2.0, max_inducing)
    Kmm = _gaussian(P[ind], P[ind], width)
    lam, U = np.linalg.eigh(Kmm)
    lam, U = lam[::-1], U[:, ::-1]
    keep = lam > 1e-10 * lam[0]
    lam, U = lam[keep], U[:, keep]
    k = int(np.searchsorted(np.cumsum(lam) / lam.sum(), 1.0 - rel_tol) + 1)
    lam, U = lam[:k], U[:, :k]
    # Nystrom: K ~ Knm Kmm^-1 Kmn = sum_k f_k f_k^T with f_k = Knm u_k / sqrt(lam_k)
    F = amp * (_gaussian(P, P[ind], width) @ U) / np.sqrt(lam)  # (N, K)
    captured = float(np.sum(F * F) / (len(P) * amp * amp))
    if normals is not None:  # one mode per eigenfunction, along the surface normal
        return F.T[:, :, None] * np.asarray(normals, float)[None], captured
    modes = np.zeros((3 * k, len(P), 3))
    for axis in range(3):
        modes[axis::3, :, axis] = F.T
    return modes, captured


#: The kernels :func:`augment_model` knows.
KERNELS = ("gaussian", "gaussian-normal")


def kernel_modes(
    model: ShapeModel, kernel: str, width_mm: float, amplitude_mm: float, rel_tol: float
) -> tuple[np.ndarray, float]:
    """The modes of ``kernel`` (one of :data:`KERNELS`) on ``model``'s mean shape."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel: expected one of {list(KERNELS)}, got {kernel!r}")
    normals = None
    if kernel == "gaussian-normal":
        if model.faces is None:
            raise ValueError("kernel 'gaussian-normal' needs a mesh model (faces): none given")
        normals = vertex_normals(model.mean, model.faces)
    return gaussian_kernel_modes(
        model.mean, width_mm, amplitude_mm, rel_tol=rel_tol, normals=normals
    )


def orthogonal_kernel_modes(
    model: ShapeModel, kernel: str, width_mm: float, amplitude_mm: float, rel_tol: float
) -> tuple[np.ndarray, float]:
    """:func:`kernel_modes` of ``model``'s mean, with what lies in the span of the model's own
    modes taken out and the rest made mutually orthogonal (an SVD: the covariance outside the
    model's span is kept exactly). The model's modes and these together are then one
    orthogonal basis, as statismo stores it, and no direction is both an SSM and a kernel
    direction."""
    modes, captured = kernel_modes(model, kernel, width_mm, amplitude_mm, rel_tol)
    G = modes.reshape(len(modes), -1)
    if model.n_modes:
        P = model.modes.reshape(model.n_modes, -1)
        G = G - np.linalg.lstsq(P.T, G.T, rcond=None)[0].T @ P
    U, S, _ = np.linalg.svd(G.T, full_matrices=False)
    keep = S > 1e-9 * max(float(S[0]) if len(S) else 0.0, 1e-300)
    out = (U[:, keep] * S[keep]).T
    return out.reshape(len(out), -1, 3), captured


def augment_model(
    model: ShapeModel,
    width_mm: float,
    amplitude_mm: float,
    *,
    kernel: str = "gaussian",
    rel_tol: float = DEFAULT_REL_TOL,
) -> ShapeModel:
    """``model`` with a Gaussian deformation kernel's modes appended (module docstring).

    ``kernel`` ``"gaussian"`` moves every point in 3-D (the standard Gaussian-process
    morphable model); ``"gaussian-normal"`` along the mean's surface normals only. The kernel's
    modes are made orthogonal to the model's and to each other
    (:func:`orthogonal_kernel_modes`), so the result can be written to statismo.

    The kernel is evaluated on the model's mean shape; landmarks, faces, truncation modes and
    provenance are kept, and the provenance gains ``"gaussian_process"``
    (:meth:`GaussianProcessInfo.as_dict`). An already augmented model is augmented from its
    SSM modes (its kernel modes are replaced).
    """
    base = ssm_part(model)
    modes, captured = orthogonal_kernel_modes(base, kernel, width_mm, amplitude_mm, rel_tol)
    info = GaussianProcessInfo(
        base.n_modes, float(width_mm), float(amplitude_mm), kernel, round(captured, 6)
    )
    variances = None
    if base.variances is not None:
        variances = np.concatenate([base.variances, np.sum(modes**2, axis=(1, 2))])
    return ShapeModel(
        base.mean,
        np.concatenate([base.modes, modes]),
        faces=base.faces,
        variances=variances,
        landmarks=base.landmarks,
        truncation_modes=base.truncation_modes,
        provenance={**base.provenance, PROVENANCE_KEY: info.as_dict()},
        population_variances=base.population_variances,
    )


def split_modes(model: ShapeModel) -> GaussianProcessInfo | None:
    """The augmentation recorded in ``model``'s provenance, or None for a plain model (or a
    record that does not fit the model: then every mode counts as the SSM's)."""
    rec = model.provenance.get(PROVENANCE_KEY)
    if not isinstance(rec, dict):
        return None
    try:
        info = GaussianProcessInfo(
            int(rec["ssm_modes"]),
            float(rec["width_mm"]),
            float(rec["amplitude_mm"]),
            str(rec.get("kernel", "gaussian")),
            float(rec.get("captured", 1.0)),
        )
    except (KeyError, TypeError, ValueError):
        return None
    return info if 0 <= info.ssm_modes < model.n_modes else None


def ssm_part(model: ShapeModel) -> ShapeModel:
    """``model`` without its kernel modes (itself when it has none)."""
    info = split_modes(model)
    if info is None:
        return model
    provenance = {k: v for k, v in model.provenance.items() if k != PROVENANCE_KEY}
    variances = None if model.variances is None else model.variances[: info.ssm_modes]
    return ShapeModel(
        model.mean,
        model.modes[: info.ssm_modes],
        faces=model.faces,
        variances=variances,
        landmarks=model.landmarks,
        truncation_modes=model.truncation_modes,
        provenance=provenance,
        population_variances=model.population_variances,
    )
