"""The Gaussian-process stage: it fits beyond the shape model's span where the data support
it, an augmented model's own kernel is used, and ``gp = "off"`` switches it off."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.simulate.scenes import boosting_case, synthetic_bone_model
from biplanar_reg.ssm import ShapeModel
from biplanar_reg.ssm.gaussian_process import augment_model


@pytest.fixture(scope="module")
def out_of_span():
    """A truth of the 8-mode synthetic bone seen through a 2-mode model of it (the truth is
    ~1.8 mm outside its span), 80 % outlines and 3 landmarks per view with 0.5 px noise."""
    full = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    small = ShapeModel(full.mean, full.modes[:2], faces=full.faces, landmarks=full.landmarks)
    views, truth = boosting_case(full, 3, fraction=0.8, noise_px=0.5, landmarks_per_view=3)
    return small, views, truth[3]


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.fixture(scope="module")
def both(out_of_span):
    model, views, _ = out_of_span
    off = register_views(model, views, options=RegistrationOptions(gp="off"))
    auto = register_views(model, views)
    return off, auto


def test_the_stage_fits_an_out_of_span_truth_better(out_of_span, both):
    _, _, truth = out_of_span
    off, auto = both
    assert off.gp == {} and off.shape_displacement_mm is None
    assert auto.gp["used"] and 0.05 < auto.gp["amplitude_mm"] < 10
    assert 0 < auto.gp["effective_modes"] < auto.gp["modes"]
    # measured 1.83 -> 1.24 mm vertex RMS
    assert _rms(auto.vertices, truth) < 0.8 * _rms(off.vertices, truth)
    assert any(r.kind == "gp" for r in auto.iterations)


def test_the_result_states_the_kernels_displacement(out_of_span, both):
    model, _, _ = out_of_span
    _, auto = both
    assert auto.weights.shape == (model.n_modes,)
    shape = model.instance(auto.weights) + auto.shape_displacement_mm
    np.testing.assert_allclose(shape @ auto.rotation.T + auto.translation, auto.vertices, atol=1e-9)


def test_an_augmented_model_brings_its_own_kernel(out_of_span, both):
    model, views, truth = out_of_span
    aug = augment_model(model, 25.0, 1.0)
    res = register_views(aug, views)
    assert res.weights.shape == (aug.n_modes,) and res.shape_displacement_mm is None
    np.testing.assert_allclose(
        aug.instance(res.weights) @ res.rotation.T + res.translation, res.vertices, atol=1e-9
    )
    # the same kernel as the stage's own (gaussian, 25 mm): the same result
    assert _rms(res.vertices, both[1].vertices) < 0.05
    # off: the convex stages and the refinement on the SSM's modes; the kernel's weights 0
    off = register_views(aug, views, options=RegistrationOptions(gp="off"))
    np.testing.assert_array_equal(off.weights[model.n_modes :], 0.0)
    np.testing.assert_allclose(off.vertices, both[0].vertices, atol=1e-9)
    assert _rms(off.vertices, truth) > _rms(res.vertices, truth)


def _with_augmented_model(case_dir, tmp_path):
    """A copy of a sample case whose ``[model] ssm`` is its model augmented with a kernel."""
    import shutil

    from biplanar_reg.cases import load_case

    dst = tmp_path / case_dir.name
    shutil.copytree(case_dir, dst, ignore=shutil.ignore_patterns("out*"))
    model = load_case(dst).model
    toml = (dst / "case.toml").read_text()
    ssm = toml.split('ssm = "', 1)[1].split('"', 1)[0]
    augment_model(ShapeModel.load(dst / ssm), 25.0, 1.0).save(dst / "model" / "gp.npz")
    (dst / "case.toml").write_text(toml.replace(f'ssm = "{ssm}"', 'ssm = "model/gp.npz"'))
    return dst, model.n_modes


def test_a_case_with_an_augmented_model_keeps_its_kernel(tmp_path):
    import json
    from pathlib import Path

    from biplanar_reg.cases import run_case_dir

    sample = Path(__file__).resolve().parents[2] / "sample_cases"
    case, n_ssm = _with_augmented_model(sample / "synthetic_radius_known", tmp_path)
    doc = json.loads((run_case_dir(case, report=False).out_dir / "result.json").read_text())
    assert doc["gaussian_process"]["used"] and len(doc["weights"]) > n_ssm
    # several frames: registered on the shape model's modes, the kernel's weights 0
    frames, n_ssm = _with_augmented_model(sample / "wrist_radius_frames", tmp_path)
    doc = json.loads((run_case_dir(frames, report=False).out_dir / "result.json").read_text())
    expected = json.loads((sample / "wrist_radius_frames" / "expected.json").read_text())
    assert len(doc["weights"]) > n_ssm and not any(doc["weights"][n_ssm:])
    got, want = doc["metrics"]["vertex_rms_mm"], expected["metrics"]["vertex_rms_mm"]["value"]
    assert got == pytest.approx(want, abs=1e-6)


def test_refitting_the_ssm_weights_fits_an_out_of_span_case_better(scene):
    """``gp_ssm = "refit"`` on seed 6 of the small realistic scene (traced partial outlines,
    3 landmarks per view, the truth out of the 4-mode model's span): measured 1.38 -> 1.12 mm
    vertex RMS against the stage that holds the SSM's weights; the result's weights and
    displacement still give its vertices."""
    from biplanar_reg.simulate.realistic import make_realistic_case

    case = make_realistic_case(6, n_landmarks_per_view=3, scene=scene)
    held = register_views(scene.model, case.views)
    refit = register_views(scene.model, case.views, options=RegistrationOptions(gp_ssm="refit"))
    assert "ssm_scale" not in held.gp
    assert refit.gp["used"] and 0.1 < refit.gp["ssm_scale"] < 10
    assert not np.allclose(refit.weights, held.weights)
    shape = scene.model.instance(refit.weights) + refit.shape_displacement_mm
    np.testing.assert_allclose(
        shape @ refit.rotation.T + refit.translation, refit.vertices, atol=1e-9
    )
    assert _rms(refit.vertices, case.truth_vertices) < 0.9 * _rms(
        held.vertices, case.truth_vertices
    )


def test_the_refit_charges_the_change_for_moving_what_no_outline_sees():
    """``change_basis``: ``dw = S z`` with ``z`` under the SSM's prior makes the change's prior
    ``dw^T (I + mu A) dw``; a mode that moves only unseen vertices is shrunk, one that moves
    only seen ones is not, and with every vertex seen nothing changes."""
    from biplanar_reg.registration.gp_stage import UNSEEN_FIRMNESS, change_basis

    modes = np.zeros((2, 4, 3))
    modes[0, 0] = [1.0, 0.0, 0.0]  # moves a seen vertex
    modes[1, 3] = [0.0, 2.0, 0.0]  # moves the unseen one
    model = ShapeModel(np.zeros((4, 3)), modes)
    seen = np.array([True, True, True, False])
    S = change_basis(model, seen)
    P = modes.reshape(2, -1)
    A = (modes[:, ~seen].reshape(2, -1) @ modes[:, ~seen].reshape(2, -1).T) / (
        np.trace(P @ P.T) / 4 / 2
    )
    np.testing.assert_allclose(S.T @ (np.eye(2) + UNSEEN_FIRMNESS * A) @ S, np.eye(2), atol=1e-12)
    assert S[0, 0] == pytest.approx(1.0) and S[1, 1] < 0.2 and abs(S[0, 1]) < 1e-12
    np.testing.assert_allclose(change_basis(model, np.ones(4, bool)), np.eye(2), atol=1e-12)


def test_gp_ssm_takes_held_or_refit():
    with pytest.raises(ValueError, match="gp_ssm"):
        RegistrationOptions(gp_ssm="free")
