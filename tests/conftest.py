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


#: The test modules of 2 s or more, longest first (seconds of test time on the two-core
#: machine, ``python -m pytest -q -n 2 --durations=0 -p no:randomly`` summed per module): handed
#: out first, so that the modules left for the end are short and the two workers finish
#: together.
LONGEST_MODULES = (
    "test_e2e.py",  # 26.9
    "test_sample_cases.py",  # 22.7
    "test_e2e_security.py",  # 21.3
    "test_boosting.py",  # 19.9
    "test_e2e_view_aids.py",  # 18.9
    "test_registration_stages.py",  # 17.5
    "test_e2e_warm.py",  # 16.7
    "test_fuzz_parsers.py",  # 16.7
    "test_e2e_sample_cases.py",  # 16.5
    "test_e2e_undo.py",  # 16.1
    "test_view_starts.py",  # 16.1
    "test_robust_realistic.py",  # 14.7
    "test_real_radiographs.py",  # 14.6
    "test_warm_register.py",  # 14.3
    "test_own_data_walkthrough.py",  # 11.3
    "test_e2e_pose.py",  # 10.9
    "test_batch_faults.py",  # 10.6
    "test_e2e_keys.py",  # 10.4
    "test_warm_start.py",  # 9.6
    "test_correspond.py",  # 9.5
    "test_few_landmarks.py",  # 9.3
    "test_api.py",  # 8.6
    "test_batch_run.py",  # 8.2
    "test_security.py",  # 7.3
    "test_e2e_model.py",  # 6.8
    "test_gp_stage.py",  # 6.6
    "test_cases_register.py",  # 6.5
    "test_pose_modes.py",  # 6.3
    "test_reused_figures.py",  # 6.3
    "test_unknown_realistic.py",  # 5.6
    "test_figure_drawing.py",  # 4.9
    "test_outline_fit.py",  # 4.6
    "test_multi_start.py",  # 4.6
    "test_robust_weights.py",  # 4.4
    "test_registration_options.py",  # 4.3
    "test_frames_case.py",  # 4.2
    "test_template_checks.py",  # 4.0
    "test_pipeline.py",  # 3.9
    "test_cases_load.py",  # 3.7
    "test_extras.py",  # 3.6
    "test_traced_past_the_cut.py",  # 3.4
    "test_unknown_poses.py",  # 3.3
    "test_batch_shards.py",  # 3.3
    "test_bones.py",  # 3.1
    "test_case_report.py",  # 3.1
    "test_batch_safety.py",  # 3.0
    "test_annotation_contours.py",  # 2.5
    "test_ipm.py",  # 2.4
    "test_registration_gsft.py",  # 2.4
    "test_lazy_imports.py",  # 2.3
    "test_view_aids.py",  # 2.3
    "test_register_poses.py",  # 2.2
    "test_render3d_probe.py",  # 2.2
    "test_layering.py",  # 2.1
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest test modules first, longest first (:data:`LONGEST_MODULES`), then the
    others: the two workers take whole modules from the front of the list (``--dist
    loadfile``), so the long ones start early and the short ones fill in at the end (the
    longest-first rule keeps the two workers' finishing times close). Each module keeps its
    order."""
    rank = {name: i for i, name in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
