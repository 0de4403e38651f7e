"""Edge features of display images shared by livewire and landmark snapping."""

from __future__ import annotations

import functools

import numpy as np

from .._validate import check_positive

# scipy.ndimage (and scipy.special, which it loads: ~0.1 CPU s together) is imported inside
# the functions that use it: the package imports this module, and a case's registration
# calls none of them (tests/test_lazy_imports.py).

__all__ = ["edge_cost"]

# onset powers of the outline models, in this order: 0 = step (a face along the rays),
# 0.5 = square-root onset (the occluding contour of a smooth surface)
ONSET_POWERS = (0.0, 0.5)


def gradient_magnitude(display: np.ndarray, sigma_px: float = 1.5) -> np.ndarray:
    """Gaussian-derivative gradient magnitude of a (H, W) image (units: display / pixel)."""
    from scipy import ndimage

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


def _onset_templates(
    x: np.ndarray, offsets: np.ndarray, widths: np.ndarray, powers: np.ndarray
) -> np.ndarray:
    """Blurred power-law onsets ``E[max(x - x0 - z, 0) ** p]``, ``z ~ N(0, w^2)``.

    Returns an array (len(powers) * len(widths) * len(offsets), len(x)): one template per
    (power, width, offset), offsets varying fastest. ``p = 0`` is a blurred step.
    """
    z = np.linspace(-4.0, 4.0, 161)
    pz = np.exp(-0.5 * z**2)
    pz /= pz.sum()
    out = []
    for p in powers:
        for w in widths:
            d = x[None, :, None] - offsets[:, None, None] - w * z[None, None, :]
            out.append(np.where(d > 0, np.maximum(d, 0.0) ** p, 0.0) @ pz)
    return np.concatenate(out, axis=0)


@functools.lru_cache(maxsize=8)
def _unit_templates(
    half_width_px: float,
    max_shift_px: float,
    widths_px: tuple[float, ...],
    powers: tuple[float, ...],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample positions ``s``, offsets ``s0`` and the centred unit-norm onset templates of
    :func:`edge_onset_offsets` (read-only; cached: they depend on the parameters only and
    cost ~40 ms, most of a livewire call on a short stretch)."""
    s = np.arange(-half_width_px, half_width_px + 1e-9, 0.5)
    s0 = np.arange(-max_shift_px, max_shift_px + 1e-9, 0.05)
    tmpl = _onset_templates(s, s0, np.asarray(widths_px, float), np.asarray(powers, float))
    tmpl -= tmpl.mean(axis=1, keepdims=True)
    tmpl /= np.sqrt(np.sum(tmpl**2, axis=1, keepdims=True))
    for a in (s, s0, tmpl):
        a.flags.writeable = False
    return s, s0, tmpl


def edge_onset_offsets(
    display: np.ndarray,
    uv: np.ndarray,
    directions: np.ndarray,
    *,
    half_width_px: float = 6.0,
    max_shift_px: float = 4.0,
    widths_px: tuple[float, ...] = (0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0),
    powers: tuple[float, ...] = ONSET_POWERS,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel position of a bone's outline along given directions, by profile fitting.

    A radiograph's intensity across a bone's outline follows the X-ray path length through the
    bone. Near the occluding contour of a smooth surface that length grows like
    ``sqrt(depth)`` (power 0.5); where the surface runs parallel to the rays (a flat face seen
    edge-on) it jumps (power 0, a step). Both are blurred by the imaging system, and the
    gradient-magnitude peak of a blurred square-root onset lies *inside* the outline (about
    one blur width). So each point's profile along ``directions`` is fitted with
    ``a + b * onset(s - s0)``, ``onset = E[max(s - s0 - z, 0) ** p]``, ``z ~ N(0, w^2)``,
    ``b > 0`` (the bone attenuates), by linear least squares for ``a, b`` over a grid of
    outline offsets ``s0`` (0.05 px steps) and blur widths ``w``, for each power ``p``.

    Parameters
    ----------
    display : (H, W) array
        Display image with the bone darker than its surroundings.
    uv : (K, 2) array
        Points near the outline, pixels (u, v).
    directions : (K, 2) array
        Unit vectors (du, dv) across the outline, pointing into the bone.
    half_width_px : float
        The profile spans ``[-half_width_px, half_width_px]`` around each point (0.5 px
        samples, each the mean of three lines 1 px apart along the outline), pixels.
    max_shift_px : float
        Largest outline offset searched, pixels.
    widths_px : tuple of float
        Gaussian blur widths (sigma, pixels) tried.
    powers : tuple of float
        Onset powers tried (0: step, 0.5: smooth surface).

    Returns
    -------
    offsets : (K, P) array
        For each power, the best-fitting signed offset of the outline from each point along
        ``directions``, pixels.
    r2 : (K, P) array
        Fraction of the profile's variance explained by that fit (0 when no onset with the
        bone attenuating fits).
    """
    from scipy import ndimage

    s, s0, tmpl = _unit_templates(
        float(half_width_px),
        float(max_shift_px),
        tuple(float(w) for w in widths_px),
        tuple(float(p) for p in powers),
    )
    tang = np.column_stack([-directions[:, 1], directions[:, 0]])
    prof = np.zeros((len(uv), len(s)))
    for t in (-1.0, 0.0, 1.0):
        pu = uv[:, 0:1] + s[None] * directions[:, 0:1] + t * tang[:, 0:1]
        pv = uv[:, 1:2] + s[None] * directions[:, 1:2] + t * tang[:, 1:2]
        prof += ndimage.map_coordinates(display, [pv, pu], order=1, mode="nearest")
    y = -prof  # attenuation, growing into the bone
    y -= y.mean(axis=1, keepdims=True)
    yy = np.sum(y**2, axis=1)
    # projection on each centred unit template = the fit's b * |template|; keep b > 0 only
    c = np.maximum(y @ tmpl.T, 0.0).reshape(len(uv), len(powers), -1)
    best = np.argmax(c, axis=2)
    cbest = np.take_along_axis(c, best[:, :, None], axis=2)[:, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.where(yy[:, None] > 0, cbest**2 / yy[:, None], 0.0)
    return s0[best % len(s0)], r2
