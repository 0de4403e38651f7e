"""Synthetic scenes and case folders with a known ground truth (public).

For testing a registration pipeline on data whose answer is known: a bone-like shape model,
X-ray views, random poses, the rays and outlines a registration sees, and complete case folders
in the case format. Everything is seeded and deterministic; lengths are mm, pixels ``(u, v)``.
See ``docs/sample_cases.md``.

* :mod:`.scenes`: :func:`synthetic_bone_model`, :func:`look_at_view`, :func:`biplanar_views`,
  :func:`random_pose`, :func:`noisy_pixels` and :func:`observe` (landmark pixels and their
  :class:`~biplanar_reg.registration.rays.RayObservations`), :func:`outline_stretch`,
  :func:`vertex_landmarks` (a view's observations of model vertices), :func:`boosting_case`
  (a two-view landmarks-plus-outline problem);
* :mod:`.case_folder`: :func:`write_synthetic_case` (a case folder with ``gt/``) and
  :func:`synthetic_landmarks`.
"""

from .case_folder import synthetic_landmarks, write_synthetic_case
from .scenes import (
    biplanar_views,
    boosting_case,
    look_at_view,
    noisy_pixels,
    observe,
    outline_stretch,
    random_pose,
    synthetic_bone_model,
    vertex_landmarks,
)

__all__ = [
    "biplanar_views",
    "boosting_case",
    "look_at_view",
    "noisy_pixels",
    "observe",
    "outline_stretch",
    "random_pose",
    "synthetic_bone_model",
    "synthetic_landmarks",
    "vertex_landmarks",
    "write_synthetic_case",
]
