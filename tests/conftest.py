"""Fixtures shared by the test modules (a module that defines a fixture of the same name uses its
own).

``model`` and ``posed`` are the set-up of the outline and silhouette-boosting tests
(``tests/test_outline.py``, ``tests/registration/``): the synthetic bone with 8 modes
(1,282 vertices) and one seeded random instance of it in a random pose.
"""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.simulate import random_pose, synthetic_bone_model
from biplanar_reg.ssm import ShapeModel


@pytest.fixture(scope="module")
def model() -> ShapeModel:
    """The synthetic bone of the outline and boosting tests (8 modes, 1,282 vertices, mm)."""
    return synthetic_bone_model(8, seed=0, resolution=(40, 32))


@pytest.fixture(scope="module")
def posed(model: ShapeModel) -> tuple[np.random.Generator, np.ndarray, np.ndarray]:
    """``(rng, w, X)``: weights ``w ~ N(0, 1)`` and the instance posed by :func:`random_pose`
    (world frame, mm), drawn from ``default_rng(0)``; ``rng`` is left for the module's draws."""
    rng = np.random.default_rng(0)
    w = rng.normal(size=8)
    R, t = random_pose(rng).rt
    return rng, w, model.instance(w) @ R.T + t


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The browser test modules (``test_e2e*.py``, the longest of the suite) first: the two
    workers take whole modules from the front of the list (``--dist loadfile``), so the long
    ones start early and the short ones fill in at the end. Each module keeps its order."""
    items.sort(key=lambda item: not item.path.name.startswith("test_e2e"))
