"""The joint view refinement measures its residuals in pixels
(``outline_fit.refine_poses_on_outlines(pixels=...)``): moving the scene towards the sources
and shrinking the bone with it (the perspective scale ambiguity of free view poses) changes no
image and must not lower the objective, as a ray distance in mm would."""

from __future__ import annotations

import numpy as np

from biplanar_reg.registration.options import RegistrationOptions
from biplanar_reg.registration.outline_fit import refine_poses_on_outlines
from biplanar_reg.registration.problem import make_problem
from biplanar_reg.simulate import boosting_case
from biplanar_reg.ssm import ShapeModel


def test_shrinking_the_scene_towards_the_sources_does_not_pay(model):
    # a model whose one mode is a pure scaling about the model's centroid
    c = model.mean.mean(axis=0)
    scaled = ShapeModel(model.mean, (model.mean - c)[None] * 0.05, faces=model.faces)
    views, (w, R, t, X) = boosting_case(model, 0, noise_px=1.0, landmarks_per_view=4)
    problem = make_problem(scaled, views, RegistrationOptions(), False, lambda m: None, X.mean(0))
    lm = problem.landmark_rays(frozenset())
    depths = [v.view.to_camera((c @ R.T + t)[None])[0, 2] for v in views]

    def costs(k):
        """Data costs (pixel-scaled, and plain mm) with the bone scaled by ``k``."""
        s = (k - 1.0) / 0.05  # the mode weight that scales the bone by k
        out = []
        for v in views:
            # the pose seen through each view: the bone's centre moved k times as far from
            # that view's source (each image unchanged, the bone scaled by k)
            src = v.view.centre
            out.append(src + k * (R @ c + t - src) - R @ c)
        state = (np.array([R, R]), np.array(out), np.array([s]))
        kw = {"pose_of_view": np.arange(2), "max_iter": 0}
        px = refine_poses_on_outlines(
            scaled, state, lm, [], pixels=[v.view for v in views], depths=depths, **kw
        )
        mm = refine_poses_on_outlines(scaled, state, lm, [], **kw)
        return px.cost_before - 0.5 * s**2, mm.cost_before - 0.5 * s**2

    px1, mm1 = costs(1.0)
    px8, mm8 = costs(0.8)
    assert abs(px8 - px1) < 1e-6 * px1
    # what the mm objective would have rewarded (its residuals shrink by k, its cost by k^2)
    assert mm8 < 0.7 * mm1
