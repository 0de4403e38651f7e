"""Fixtures of the registration tests (``model``: ``tests/conftest.py``)."""

from __future__ import annotations

import pytest
from registration_problems import clean_views

from biplanar_reg.registration import ViewObservations


@pytest.fixture(scope="module")
def views(model) -> list[ViewObservations]:
    """The clean two-view problem of seed 0 (``registration_problems.clean_views``)."""
    return clean_views(model, 0)[0]
