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


#: The longest test modules, longest first (seconds of test time on the two-core machine,
#: ``python -m pytest -q -n 2 --durations=0`` summed per module): they are handed out first.
LONGEST_MODULES = (
    "test_e2e.py",  # 34.5
    "test_e2e_security.py",  # 27.3
    "test_e2e_view_aids.py",  # 20.1
    "test_sample_cases.py",  # 19.5
    "test_boosting.py",  # 18.5
    "test_warm_register.py",  # 18.4
    "test_e2e_undo.py",  # 17.3
    "test_e2e_keys.py",  # 17.1
    "test_real_radiographs.py",  # 16.5
    "test_robust_realistic.py",  # 15.1
    "test_view_starts.py",  # 14.7
    "test_e2e_sample_cases.py",  # 14.3
    "test_warm_start.py",  # 14.2
    "test_registration_stages.py",  # 13.2
    "test_fuzz_parsers.py",  # 13.1
    "test_e2e_pose.py",  # 12.9
    "test_e2e_warm.py",  # 12.2
    "test_batch_faults.py",  # 12.1
    "test_batch_run.py",  # 10.7
    "test_gp_stage.py",  # 10.7
    "test_report_pages_browser.py",  # 10.1
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest test modules first, longest first (:data:`LONGEST_MODULES`), then the
    others: the two workers take whole modules from the front of the list (``--dist
    loadfile``), so the long ones start early and the short ones fill in at the end (the
    longest-first rule keeps the two workers' finishing times close). Each module keeps its
    order."""
    rank = {name: i for i, name in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
