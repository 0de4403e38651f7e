"""Fixtures of the registration tests (``model``: ``tests/conftest.py``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from registration_problems import clean_views

from biplanar_reg.registration import ViewObservations
from biplanar_reg.simulate.realistic import wrist_scene

WRIST_DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"


@pytest.fixture(scope="module")
def views(model) -> list[ViewObservations]:
    """The clean two-view problem of seed 0 (``registration_problems.clean_views``)."""
    return clean_views(model, 0)[0]


@pytest.fixture(scope="session")
def scene():
    """A small realistic wrist scene (``simulate.realistic.wrist_scene``: 500 vertices, a 4-mode
    model from 5 shapes, so that the truths are out of its span), built once per process."""
    return wrist_scene(
        str(WRIST_DATA), n_vertices=500, n_population=8, n_train=5, n_modes=4, resolution=20
    )
