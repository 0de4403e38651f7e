"""Model-quality measures of a PCA shape model (as in ShapeWorks and scalismo).

All functions take training shapes already in correspondence **and aligned** (S, N, 3) mm (see
:func:`model_quality`, which aligns them like :func:`.build.build_ssm`), and return one value per
number of modes ``k``:

* **compactness** ``C(k)``: the fraction of the training set's total variance that the first
  ``k`` modes explain, over *all* modes (``C(rank) = 1``);
* **generalisation** ``G(k)`` mm: leave-one-out; the PCA of the other ``S - 1`` shapes, the
  held-out shape orthogonally projected onto its mean + first ``k`` modes, and the mean
  vertex-to-vertex distance of the projection to the held-out shape; averaged over the folds.
  Projections onto nested subspaces, so ``G`` never increases with ``k``; ``k = 0 .. S - 2``;
* **specificity** ``Sp(k)`` mm: random shapes of the model (all ``S`` shapes) with ``k`` modes,
  weights ``N(0, 1)`` (seeded), each compared with its nearest training shape by the mean
  vertex-to-vertex distance; averaged over the samples. ``k = 0 .. S - 1``.

Recommended number of modes (:func:`recommended_modes`): the smallest ``k`` that both reaches
95 % compactness and has realised 95 % of the generalisation gain available,
``G(k) <= G_min + 0.05 (G(0) - G_min)``; from compactness alone when no training set is at hand.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .._validate import as_array
from .build import ALIGNMENTS, procrustes_align

__all__ = [
    "ModelQuality",
    "compactness",
    "generalisation",
    "model_quality",
    "plot_quality",
    "recommended_modes",
    "specificity",
]

#: Compactness a recommended model reaches, and the share of the generalisation gain it realises.
COMPACTNESS_TARGET = 0.95
GENERALISATION_GAIN = 0.95


def _pca(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``mean (D,)``, ``variances (R,)`` (divisor S - 1) and unit eigenvectors ``(R, D)`` of the
    rows of ``data`` (S, D); only the numerically non-zero modes (rank R)."""
    mean = data.mean(axis=0)
    _, sig, vt = np.linalg.svd(data - mean, full_matrices=False)
    var = sig**2 / max(len(data) - 1, 1)
    rank = int(np.sum(var > 1e-12 * max(var.max(initial=0.0), 1e-300)))
    return mean, var[:rank], vt[:rank]


def _flat(shapes: object) -> np.ndarray:
    x = as_array("shapes", shapes, (None, None, 3))
    if len(x) < 3:
        raise ValueError(f"shapes: need at least 3 shapes for the quality measures, got {len(x)}")
    return x.reshape(len(x), -1)


def compactness(variances: object, total: float | None = None) -> np.ndarray:
    """Cumulative explained-variance fractions ``C(k)``, k = 1..len(variances).

    Parameters
    ----------
    variances : (R,) array
        Mode variances, mm^2, in decreasing order.
    total : float, optional
        Total variance of the training set, mm^2 (all modes). Default: ``sum(variances)``,
        i.e. ``variances`` are all the modes.
    """
    v = as_array("variances", variances, (None,))
    tot = float(v.sum()) if total is None else float(total)
    if tot <= 0:
        raise ValueError(f"total variance must be positive, got {tot}")
    return np.cumsum(v) / tot


def _mean_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean vertex-to-vertex distance, mm, of flattened shapes (..., 3N) broadcasting."""
    d = (a - b).reshape(*np.broadcast_shapes(a.shape, b.shape)[:-1], -1, 3)
    return np.sqrt(np.sum(d * d, axis=-1)).mean(axis=-1)


def generalisation(shapes: object, max_modes: int | None = None) -> np.ndarray:
    """Leave-one-out generalisation ``G(k)``, mm, for k = 0 .. K (module docstring).

    Parameters
    ----------
    shapes : (S, N, 3) array
        Aligned training shapes in correspondence, mm; S >= 3.
    max_modes : int, optional
        Largest ``k`` (default and at most ``S - 2``).

    Returns
    -------
    (K + 1,) array
        ``G(0)`` is the mean distance of each held-out shape to the others' mean.
    """
    data = _flat(shapes)
    s_count = len(data)
    kmax = s_count - 2 if max_modes is None else min(int(max_modes), s_count - 2)
    out = np.zeros(kmax + 1)
    for i in range(s_count):
        mean, _, vecs = _pca(np.delete(data, i, axis=0))
        d = data[i] - mean
        coeff = vecs[:kmax] @ d
        recon = np.zeros_like(d)
        out[0] += _mean_distance(d, recon)
        for k in range(1, kmax + 1):
            if k <= len(coeff):
                recon = recon + coeff[k - 1] * vecs[k - 1]
            out[k] += _mean_distance(d, recon)
    return out / s_count


def specificity(
    shapes: object, max_modes: int | None = None, n_samples: int = 100, seed: int = 0
) -> np.ndarray:
    """Specificity ``Sp(k)``, mm, for k = 0 .. K (module docstring).

    Parameters
    ----------
    shapes : (S, N, 3) array
        Aligned training shapes in correspondence, mm; S >= 3.
    max_modes : int, optional
        Largest ``k`` (default and at most the rank, <= S - 1).
    n_samples : int
        Random model shapes per ``k`` (the same standard-normal draws for every ``k``).
    seed : int
        Seed of the draws.
    """
    data = _flat(shapes)
    mean, var, vecs = _pca(data)
    kmax = len(var) if max_modes is None else min(int(max_modes), len(var))
    if n_samples < 1:
        raise ValueError(f"n_samples: must be >= 1, got {n_samples}")
    z = np.random.default_rng(seed).standard_normal((int(n_samples), max(kmax, 1)))
    modes = np.sqrt(var[:kmax])[:, None] * vecs[:kmax]
    out = np.zeros(kmax + 1)
    batch = max(1, int(2e7 // max(data.size, 1)))  # bound the (batch, S, N) distance array
    for k in range(kmax + 1):
        total = 0.0
        for start in range(0, len(z), batch):
            samples = mean + z[start : start + batch, :k] @ modes[:k]
            dist = _mean_distance(samples[:, None, :], data[None, :, :])
            total += float(dist.min(axis=1).sum())
        out[k] = total / len(z)
    return out


def recommended_modes(
    compact: object,
    general: object | None = None,
    target: float = COMPACTNESS_TARGET,
    gain: float = GENERALISATION_GAIN,
) -> int:
    """The recommended number of modes (module docstring), >= 1.

    Parameters
    ----------
    compact : (R,) array
        ``C(k)`` for k = 1..R (:func:`compactness`).
    general : (K + 1,) array, optional
        ``G(k)`` for k = 0..K (:func:`generalisation`); ignored when ``None``.
    target, gain : float
        The compactness to reach and the share of the generalisation gain to realise.
    """
    c = as_array("compactness", compact, (None,))
    k_c = int(min(len(c), np.searchsorted(c, target - 1e-12) + 1))
    if general is None:
        return k_c
    return max(k_c, _k_generalisation(general, gain), 1)


def _k_generalisation(general: object, gain: float = GENERALISATION_GAIN) -> int:
    """Smallest k with ``G(k) <= G_min + (1 - gain) (G(0) - G_min)``."""
    g = as_array("generalisation", general, (None,))
    g_min = g.min()
    return int(np.argmax(g <= g_min + (1.0 - gain) * (g[0] - g_min) + 1e-12))


@dataclass
class ModelQuality:
    """The three measures of a training set (see the module docstring).

    ``variances`` (R,) mm^2 all PCA variances; ``compactness`` (R,) ``C(1..R)``;
    ``generalisation_mm`` ``G(0..S-2)``; ``specificity_mm`` ``Sp(0..R)``; ``recommended``
    the recommended number of modes; ``n_shapes``, ``n_samples``, ``seed``, ``align``.
    """

    variances: np.ndarray
    compactness: np.ndarray
    generalisation_mm: np.ndarray
    specificity_mm: np.ndarray
    recommended: int
    n_shapes: int
    n_samples: int
    seed: int
    align: str

    def to_dict(self) -> dict:
        """JSON-ready dictionary (lists of floats; index ``k`` of each list as stated)."""
        return {
            "n_shapes": self.n_shapes,
            "align": self.align,
            "variances_mm2": self.variances.tolist(),
            "compactness": {"k_from": 1, "values": self.compactness.tolist()},
            "generalisation_mm": {"k_from": 0, "values": self.generalisation_mm.tolist()},
            "specificity_mm": {
                "k_from": 0,
                "values": self.specificity_mm.tolist(),
                "n_samples": self.n_samples,
                "seed": self.seed,
            },
            "recommended_modes": self.recommended,
            "recommended_by_compactness": recommended_modes(self.compactness),
            "recommended_by_generalisation": _k_generalisation(self.generalisation_mm),
            "rule": (
                f"smallest k with compactness >= {COMPACTNESS_TARGET} and generalisation "
                f"within {1 - GENERALISATION_GAIN:.0%} of its attainable gain"
            ),
        }


def model_quality(
    shapes: object, align: str = "rigid", n_samples: int = 100, seed: int = 0
) -> ModelQuality:
    """All three measures of a training set in correspondence (S, N, 3) mm, S >= 3.

    ``align`` as in :func:`.build.build_ssm` (generalised Procrustes before PCA), so the
    figures describe the model that ``build_ssm`` learns from the same shapes.
    """
    x = as_array("shapes", shapes, (None, None, 3))
    if align not in ALIGNMENTS:
        raise ValueError(f"align: expected one of {list(ALIGNMENTS)}, got {align!r}")
    if align != "none":
        x = procrustes_align(x, scaling=(align == "similarity"))
    data = _flat(x)
    _, var, _ = _pca(data)
    comp = compactness(var)
    gen = generalisation(x)
    spec = specificity(x, n_samples=n_samples, seed=seed)
    return ModelQuality(
        variances=var,
        compactness=comp,
        generalisation_mm=gen,
        specificity_mm=spec,
        recommended=recommended_modes(comp, gen),
        n_shapes=len(x),
        n_samples=int(n_samples),
        seed=int(seed),
        align=align,
    )


def plot_quality(quality: ModelQuality, path: str | os.PathLike, title: str = "") -> None:
    """Write the three curves side by side as a PNG (fixed 12 x 3.6 in layout, 100 dpi)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from ..io.atomic import atomic_path

    fig = Figure(figsize=(12, 3.6), dpi=100)
    axes = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.05, right=0.985, bottom=0.14, top=0.82, wspace=0.22)
    k_c = np.arange(1, len(quality.compactness) + 1)
    curves = (
        (axes[0], k_c, 100 * quality.compactness, "compactness (% of total variance)"),
        (
            axes[1],
            np.arange(len(quality.generalisation_mm)),
            quality.generalisation_mm,
            "generalisation (leave-one-out, mm)",
        ),
        (
            axes[2],
            np.arange(len(quality.specificity_mm)),
            quality.specificity_mm,
            f"specificity ({quality.n_samples} samples, mm)",
        ),
    )
    for ax, k, y, label in curves:
        ax.plot(k, y, "o-", ms=3)
        ax.axvline(quality.recommended, color="tab:red", ls="--", lw=1)
        ax.set_xlabel("number of modes k")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].axhline(100 * COMPACTNESS_TARGET, color="grey", ls=":", lw=1)
    axes[0].set_ylim(0, 101)
    axes[1].set_ylim(bottom=0)
    axes[2].set_ylim(bottom=0)
    fig.suptitle(
        f"{title + ': ' if title else ''}{quality.n_shapes} shapes, "
        f"recommended k = {quality.recommended} (red)",
        fontsize=11,
    )
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fig.savefig(fh, format="png")
