"""Harmonic coordinates and harmonic-deformation populations."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from biplanar_reg.ssm.harmonic import box_cage, harmonic_coordinates
from biplanar_reg.ssm.population import synthesise_population


@pytest.fixture(scope="module")
def template() -> np.ndarray:
    """An elongated, rotated, off-centre ellipsoid surface (mm), like a long bone."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return (sphere.vertices * [30.0, 10.0, 8.0]) @ q.T + [100.0, -20.0, 40.0]


@pytest.fixture(scope="module")
def cage_and_coords(template):
    cage = box_cage(template, max_divisions=5)
    return cage, harmonic_coordinates(cage, template, resolution=30)


def test_cage_is_aligned_with_the_long_axis(template, cage_and_coords):
    cage, _ = cage_and_coords
    assert np.argmax(cage.half_lengths) == 0
    np.testing.assert_allclose(cage.axes @ cage.axes.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cage.axes) > 0
    local = cage.to_local(template)
    assert np.all(np.abs(local) < cage.half_lengths)  # strictly inside


def test_partition_of_unity_and_non_negative(cage_and_coords):
    _, g = cage_and_coords
    np.testing.assert_allclose(g.sum(axis=1), 1.0, atol=1e-10)
    assert g.min() > -1e-12  # discrete maximum principle


def test_interpolates_the_cage_vertices(cage_and_coords):
    cage, _ = cage_and_coords
    g_cage = harmonic_coordinates(cage, cage.vertices, resolution=30)
    np.testing.assert_allclose(g_cage, np.eye(len(cage.lattice)), atol=1e-10)


def test_reproduces_affine_cage_deformations_exactly(template, cage_and_coords):
    cage, g = cage_and_coords
    rng = np.random.default_rng(7)
    for _ in range(3):
        a = np.eye(3) + rng.normal(0, 0.3, (3, 3))
        b = rng.normal(0, 20.0, 3)
        deformed = g @ (cage.vertices @ a.T + b)
        np.testing.assert_allclose(deformed, template @ a.T + b, rtol=0, atol=1e-8)


def test_non_affine_cage_move_is_smooth_and_local(template, cage_and_coords):
    cage, g = cage_and_coords
    moved = cage.vertices.copy()
    c = 0  # lattice (0, 0, 0): a corner
    moved[c] += 5.0 * cage.axes[1]
    disp = np.linalg.norm(g @ moved - template, axis=1)
    near = np.linalg.norm(template - cage.vertices[c], axis=1)
    assert disp.max() < 5.0  # a bounded, attenuated bump
    assert disp[np.argmin(near)] > disp[np.argmax(near)]  # larger near the moved handle


def test_points_outside_the_cage_are_rejected(cage_and_coords):
    cage, _ = cage_and_coords
    with pytest.raises(ValueError, match="point 0 lies outside the cage"):
        harmonic_coordinates(cage, cage.centre + 10 * cage.half_lengths.max() * cage.axes[0:1])


def test_population_is_seeded_in_correspondence_and_varied(template):
    pop = synthesise_population(template, size=4, seed=11, resolution=24)
    again = synthesise_population(template, size=4, seed=11, resolution=24)
    other = synthesise_population(template, size=4, seed=12, resolution=24)
    assert pop.shapes.shape == (4, len(template), 3)
    np.testing.assert_array_equal(pop.shapes, again.shapes)
    assert not np.allclose(pop.shapes, other.shapes)
    rms = np.sqrt(np.mean(np.sum((pop.shapes - template) ** 2, axis=2), axis=1))
    assert np.all(rms > 0.1) and np.all(rms < 10.0)  # mm: visible but bone-like variations
    assert set(pop.parameters[0]) == {"scale", "shear", "torsion_deg", "local"}


def test_scale_only_population_is_exactly_affine(template):
    pop = synthesise_population(template, size=3, seed=0, families=["scale"], resolution=24)
    for shape, params in zip(pop.shapes, pop.parameters, strict=True):
        cage = pop.cage
        expect = cage.to_world(cage.to_local(template) * np.array(params["scale"]))
        np.testing.assert_allclose(shape, expect, atol=1e-8)


def test_population_bad_arguments(template):
    with pytest.raises(ValueError, match="families: unknown"):
        synthesise_population(template, 2, families=["twist"])
    with pytest.raises(ValueError, match="size: must be >= 1"):
        synthesise_population(template, 0)
    with pytest.raises(ValueError, match="strength"):
        synthesise_population(template, 2, strength=-1.0, resolution=16)
