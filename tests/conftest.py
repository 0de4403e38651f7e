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
#: machine, ``python -m pytest -q -n 2 --durations=0`` summed per module): handed out first,
#: so that the modules left for the end are short and the two workers finish together.
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
    "test_few_landmarks.py",  # 9.1
    "test_correspond.py",  # 8.9
    "test_api.py",  # 8.5
    "test_security.py",  # 7.4
    "test_own_data_walkthrough.py",  # 7.2
    "test_cases_register.py",  # 7.2
    "test_e2e_model.py",  # 6.6
    "test_reused_figures.py",  # 6.1
    "test_figure_drawing.py",  # 5.9
    "test_unknown_realistic.py",  # 5.6
    "test_outline_fit.py",  # 5.5
    "test_registration_options.py",  # 5.4
    "test_multi_start.py",  # 5.4
    "test_cases_load.py",  # 5.2
    "test_pipeline.py",  # 4.7
    "test_robust_weights.py",  # 4.3
    "test_frames_case.py",  # 4.0
    "test_template_checks.py",  # 4.0
    "test_unknown_poses.py",  # 3.8
    "test_batch_safety.py",  # 3.7
    "test_pose_modes.py",  # 3.6
    "test_batch_shards.py",  # 3.6
    "test_case_report.py",  # 3.5
    "test_extras.py",  # 3.5
    "test_traced_past_the_cut.py",  # 3.2
    "test_bones.py",  # 3.1
    "test_registration_gsft.py",  # 2.8
    "test_ipm.py",  # 2.6
    "test_layering.py",  # 2.4
    "test_annotation_contours.py",  # 2.4
    "test_pose_aid.py",  # 2.3
    "test_render3d_probe.py",  # 2.3
    "test_lazy_imports.py",  # 2.2
    "test_view_aids.py",  # 2.1
    "test_register_poses.py",  # 2.1
    "test_realistic.py",  # 2.0
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest test modules first, longest first (:data:`LONGEST_MODULES`), then the
    others: the two workers take whole modules from the front of the list (``--dist
    loadfile``), so the long ones start early and the short ones fill in at the end (the
    longest-first rule keeps the two workers' finishing times close). Each module keeps its
    order."""
    rank = {name: i for i, name in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
