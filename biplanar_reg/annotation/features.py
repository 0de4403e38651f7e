"""Edge features of display images shared by livewire and landmark snapping."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .._validate import check_positive

__all__ = ["gradient_magnitude", "edge_cost"]


def gradient_magnitude(display: np.ndarray, sigma_px: float = 1.5) -> np.ndarray:
    """Gaussian-derivative gradient magnitude of a (H, W) image (units: display / pixel)."""
    sigma = check_positive("sigma_px", sigma_px)
    return ndimage.gaussian_gradient_magnitude(np.asarray(display, float), sigma, mode="nearest")


def edge_cost(
    display: np.ndarray,
    sigma_px: float = 1.5,
    *,
    floor: float = 0.01,
    power: float = 2.0,
    reference_percentile: float = 99.5,
) -> np.ndarray:
    """Per-pixel cost (H, W) that is low on strong edges, for shortest-path tracing.

    ``cost = floor + (1 - g / g_ref) ** power`` with ``g`` the gradient magnitude and ``g_ref``
    its ``reference_percentile`` (so a few very strong edges, e.g. metal beads, do not flatten
    the rest); ``g / g_ref`` is clipped to [0, 1].
    """
    g = gradient_magnitude(display, sigma_px)
    ref = float(np.percentile(g, reference_percentile))
    if ref <= 0:
        return np.ones_like(g)
    gn = np.clip(g / ref, 0.0, 1.0)
    return floor + (1.0 - gn) ** power
