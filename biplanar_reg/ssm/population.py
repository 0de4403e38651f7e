"""Synthetic shape populations by harmonic-coordinate cage deformations of one template.

Following the seed paper's biplanar experiment (a population of 9 bones from one CT template by
harmonic-spline deformations), every member is the template moved by a random deformation of a
box cage (:mod:`biplanar_reg.ssm.harmonic`), composed from these families, in this order:

``scale``
    anisotropic scaling along the three principal axes, factors ``exp(N(0, 0.08 s))``;
``shear``
    ``x_a += k_ab x_b`` for a < b (three coefficients, ``N(0, 0.06 s)``);
``torsion``
    rotation about the long axis by an angle growing linearly along it, ``N(0, 8 s)`` degrees
    between the centre and either end;
``local``
    one protrusion or depression (random sign): the cage vertices near a random template
    vertex (Gaussian weight, width 0.3 x the longest half-length) move along the radial
    direction from the long axis to that vertex by ``U(0.5, 1) x 0.25 s x`` the smallest cage
    half-length.

``s`` is the ``strength`` argument (default 1). All members share the template's vertex order
(and faces), so they are in correspondence by construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, check_positive
from .harmonic import BoxCage, box_cage, harmonic_coordinates

__all__ = ["FAMILIES", "Population", "synthesise_population"]

#: Deformation families, applied in this order.
FAMILIES: tuple[str, ...] = ("scale", "shear", "torsion", "local")


@dataclass(frozen=True)
class Population:
    """A synthetic population in correspondence with its template.

    Attributes
    ----------
    shapes : (S, N, 3) array
        Member vertices, mm, in the template's frame.
    parameters : list of dict
        The random parameters of each member (JSON-serialisable).
    cage : BoxCage
        The cage used.
    coordinates : (N, C) array
        Harmonic coordinates of the template vertices.
    """

    shapes: np.ndarray
    parameters: list[dict[str, object]]
    cage: BoxCage
    coordinates: np.ndarray


def _check_families(families: Sequence[str]) -> tuple[str, ...]:
    chosen = tuple(families)
    unknown = [f for f in chosen if f not in FAMILIES]
    if unknown or not chosen:
        raise ValueError(
            f"families: unknown or empty {unknown or list(chosen)} (choose from {list(FAMILIES)})"
        )
    return tuple(f for f in FAMILIES if f in chosen)


def _deform_cage(
    cage: BoxCage,
    template_local: np.ndarray,
    rng: np.random.Generator,
    families: Sequence[str] = FAMILIES,
    strength: float = 1.0,
) -> tuple[np.ndarray, dict[str, object]]:
    """One random cage deformation.

    Parameters
    ----------
    cage : BoxCage
        The cage.
    template_local : (N, 3) array
        Template vertices in the cage's box frame (mm), to pick local-handle sites.
    rng : numpy.random.Generator
        Source of randomness.
    families : sequence of str
        Subset of :data:`FAMILIES`.
    strength : float
        Multiplier of all magnitudes.

    Returns
    -------
    cage_local : (C, 3) array
        Deformed cage vertices, box frame, mm.
    params : dict
        The drawn parameters.
    """
    fams = _check_families(families)
    s = check_positive("strength", strength)
    c = cage.local_vertices.copy()
    half = cage.half_lengths
    params: dict[str, object] = {}
    if "scale" in fams:
        factors = np.exp(rng.normal(0.0, 0.08 * s, 3))
        c *= factors
        params["scale"] = factors.tolist()
    if "shear" in fams:
        k = rng.normal(0.0, 0.06 * s, 3)
        shear = np.eye(3)
        shear[0, 1], shear[0, 2], shear[1, 2] = k
        c = c @ shear.T
        params["shear"] = k.tolist()
    if "torsion" in fams:
        tau = np.deg2rad(rng.normal(0.0, 8.0 * s))
        angle = tau * c[:, 0] / half[0]
        cos, sin = np.cos(angle), np.sin(angle)
        c[:, 1], c[:, 2] = cos * c[:, 1] - sin * c[:, 2], sin * c[:, 1] + cos * c[:, 2]
        params["torsion_deg"] = float(np.rad2deg(tau))
    if "local" in fams:
        site = int(rng.integers(len(template_local)))
        p = template_local[site]
        radial = np.array([0.0, p[1], p[2]])
        norm = np.linalg.norm(radial)
        direction = radial / norm if norm > 1e-9 else np.array([np.sign(p[0]) or 1.0, 0, 0])
        sign = 1.0 if rng.random() < 0.5 else -1.0
        amplitude = sign * rng.uniform(0.5, 1.0) * 0.25 * s * half.min()
        width = 0.3 * half.max()
        weight = np.exp(-np.sum((cage.local_vertices - p) ** 2, axis=1) / (2 * width**2))
        c += amplitude * weight[:, None] * direction
        params["local"] = {"vertex": site, "amplitude_mm": float(amplitude)}
    return c, params


def synthesise_population(
    template_vertices: object,
    size: int,
    seed: int = 0,
    families: Sequence[str] = FAMILIES,
    strength: float = 1.0,
    max_divisions: int = 6,
    resolution: int = 40,
) -> Population:
    """Random harmonic-deformation population of a template.

    Parameters
    ----------
    template_vertices : (N, 3) array
        Template vertices, mm (faces are not needed: members keep the template's topology).
    size : int
        Number of members (>= 1).
    seed : int
        Seed of ``numpy.random.default_rng``; the same seed gives the same population.
    families : sequence of str
        Deformation families (see the module docstring).
    strength : float
        Multiplier of all deformation magnitudes.
    max_divisions, resolution : int
        Cage lattice cells along the longest axis; Laplace grid intervals along it.

    Returns
    -------
    Population
    """
    verts = as_array("template_vertices", template_vertices, (None, 3))
    if int(size) < 1:
        raise ValueError(f"size: must be >= 1, got {size}")
    fams = _check_families(families)
    cage = box_cage(verts, max_divisions=max_divisions)
    coords = harmonic_coordinates(cage, verts, resolution=resolution)
    local = cage.to_local(verts)
    rng = np.random.default_rng(seed)
    shapes, params = [], []
    for _ in range(int(size)):
        c_local, p = _deform_cage(cage, local, rng, fams, strength)
        shapes.append(coords @ cage.to_world(c_local))
        params.append(p)
    return Population(np.stack(shapes), params, cage, coords)
