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
#: machine, ``python -m pytest -q -n 2 --durations=0 -p no:randomly`` summed per module, measured
#: with the machine shared by other jobs, a load of 4-5: the order is what counts): handed out
#: first, so that the modules left for the end are short and the two workers finish together.
LONGEST_MODULES = (
    "test_sample_cases.py",  # 55.2
    "test_boosting.py",  # 52.6
    "test_e2e.py",  # 47.4
    "test_fuzz_parsers.py",  # 43.4
    "test_e2e_security.py",  # 36.3
    "test_registration_stages.py",  # 34.3
    "test_view_starts.py",  # 30.7
    "test_e2e_view_aids.py",  # 29.3
    "test_e2e_undo.py",  # 27.1
    "test_warm_register.py",  # 26.8
    "test_e2e_warm.py",  # 25.6
    "test_own_data_walkthrough.py",  # 24.9
    "test_warm_start.py",  # 24.0
    "test_e2e_sample_cases.py",  # 22.1
    "test_batch_run.py",  # 19.6
    "test_few_landmarks.py",  # 18.8
    "test_real_radiographs.py",  # 18.2
    "test_security.py",  # 18.1
    "test_robust_realistic.py",  # 17.2
    "test_batch_faults.py",  # 17.1
    "test_gp_stage.py",  # 16.6
    "test_api.py",  # 15.9
    "test_e2e_keys.py",  # 15.9
    "test_reused_figures.py",  # 15.5
    "test_outline_fit.py",  # 15.4
    "test_correspond.py",  # 15.1
    "test_e2e_pose.py",  # 15.1
    "test_unknown_realistic.py",  # 14.2
    "test_cases_register.py",  # 14.2
    "test_cases_load.py",  # 13.5
    "test_frames_case.py",  # 12.3
    "test_figure_drawing.py",  # 12.2
    "test_registration_options.py",  # 12.0
    "test_multi_start.py",  # 12.0
    "test_template_checks.py",  # 11.5
    "test_robust_weights.py",  # 11.3
    "test_pipeline.py",  # 9.6
    "test_e2e_model.py",  # 8.5
    "test_unknown_poses.py",  # 7.3
    "test_pose_modes.py",  # 6.8
    "test_batch_safety.py",  # 4.9
    "test_lazy_imports.py",  # 4.3
    "test_render3d_probe.py",  # 4.0
    "test_extras.py",  # 3.6
    "test_case_report.py",  # 3.2
    "test_view_aids.py",  # 3.2
    "test_batch_shards.py",  # 3.2
    "test_pose_aid.py",  # 3.2
    "test_bones.py",  # 3.2
    "test_layering.py",  # 3.0
    "test_register_poses.py",  # 3.0
    "test_annotation_cli.py",  # 3.0
    "test_traced_past_the_cut.py",  # 2.9
    "test_annotation_contours.py",  # 2.7
    "test_metrics.py",  # 2.7
    "test_output_safety.py",  # 2.6
    "test_registration_gsft.py",  # 2.5
    "test_roi_metrics.py",  # 2.4
    "test_ipm.py",  # 2.2
    "test_batch_cluster.py",  # 2.1
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest test modules first, longest first (:data:`LONGEST_MODULES`), then the
    others: the two workers take whole modules from the front of the list (``--dist
    loadfile``), so the long ones start early and the short ones fill in at the end (the
    longest-first rule keeps the two workers' finishing times close). Each module keeps its
    order."""
    rank = {name: i for i, name in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
