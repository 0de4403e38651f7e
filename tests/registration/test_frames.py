"""register_frames: one shape over several frames (landmarks only: fast and exact)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from biplanar_reg.registration.frames import register_frames
from biplanar_reg.registration.rotations import rotation_angle
from biplanar_reg.simulate import biplanar_views, synthetic_bone_model, vertex_landmarks


def _frames(model, w, poses, ids, with_landmarks, noise_px=0.0, seed=0):
    rng = np.random.default_rng(seed)
    views = biplanar_views(75.0)
    Q = model.instance(w)
    frames = []
    for (R, t), has in zip(poses, with_landmarks, strict=True):
        X = Q @ R.T + t
        obs = []
        for v in views:
            sel = ids if has else ids[:0]
            uv = v.project(X[sel]) + noise_px * rng.normal(size=(len(sel), 2))
            obs.append(vertex_landmarks(v.name, v, sel, uv))
        frames.append(obs)
    return frames


def _path(n):
    out = []
    for f in range(n):
        R = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(10.0 * f)]).as_matrix()
        out.append((R, np.array([2.0 * f, -1.0, 0.5 * f])))
    return out


def test_noise_free_landmarks_recover_shape_and_every_pose():
    model = synthetic_bone_model(4, seed=0)
    w = np.array([0.8, -0.5, 0.3, 0.1])
    ids = np.array([0, 40, 120, 200, 300, 400])
    poses = _path(3)
    frames = _frames(model, w, poses, ids, [True, True, True])
    res = register_frames(model, frames, silhouettes=False)
    truth = model.instance(w)
    # the shape prior pulls a little: a few hundredths of a mm on a 60 mm bone
    assert np.sqrt(np.mean(np.sum((res.vertices - truth) ** 2, 1))) < 0.1
    for f, (R, t) in enumerate(poses):
        assert np.degrees(rotation_angle(res.rotations[f], R)) < 0.2
        assert np.allclose(res.frame_vertices(f), truth @ R.T + t, atol=0.3)
    assert res.started_from == ["landmarks"] * 3
    assert res.poses().shape == (3, 4, 4)
    assert np.all(res.landmark_rms_px < 0.5)


def test_more_frames_determine_the_shape_better_under_noise():
    model = synthetic_bone_model(4, seed=0)
    w = np.array([1.0, -1.0, 0.5, 0.5])
    ids = np.array([0, 40, 120, 200, 300, 400])
    poses = _path(6)
    frames = _frames(model, w, poses, ids, [True] * 6, noise_px=2.0, seed=3)
    truth = model.instance(w)

    def err(fr):
        res = register_frames(model, fr, silhouettes=False)
        return np.sqrt(np.mean(np.sum((res.vertices - truth) ** 2, 1)))

    assert err(frames) < err(frames[:1])


def test_frame_without_landmarks_or_outlines_is_interpolated_and_flagged():
    model = synthetic_bone_model(4, seed=0)
    ids = np.array([0, 40, 120, 200, 300, 400])
    poses = _path(3)
    frames = _frames(model, np.zeros(4), poses, ids, [True, False, True])
    res = register_frames(model, frames, silhouettes=False, names=["a", "b", "c"])
    assert res.started_from == ["landmarks", "neighbours", "landmarks"]
    assert any(f.startswith("b: no landmarks") for f in res.flags)
    # halfway between the neighbours' poses: the bone's centroid and rotation
    c = [res.frame_vertices(f).mean(axis=0) for f in range(3)]
    assert np.allclose(c[1], (c[0] + c[2]) / 2)
    half = np.degrees(rotation_angle(res.rotations[0], res.rotations[2])) / 2
    assert abs(np.degrees(rotation_angle(res.rotations[0], res.rotations[1])) - half) < 1e-6
    assert np.isnan(res.landmark_rms_px[1])
    # no data of its own: its pose (and so its posed vertices) has no posterior sd
    assert np.isnan(res.vertex_sd_mm[1]).all() and np.isfinite(res.vertex_sd_mm[[0, 2]]).all()


def test_bad_input_names_the_problem():
    model = synthetic_bone_model(4, seed=0)
    ids = np.array([0, 40, 120])
    frames = _frames(model, np.zeros(4), _path(2), ids, [False, False])
    with pytest.raises(ValueError, match="no frame has 4 landmark observations"):
        register_frames(model, frames)
    with pytest.raises(ValueError, match="names: expected 2 distinct"):
        register_frames(model, frames, names=["x", "x"])
    with pytest.raises(ValueError, match="frames: expected a non-empty"):
        register_frames(model, [])


def _outline_frames(model, w, poses, ids, with_landmarks, fraction=0.7):
    """Like :func:`_frames`, with the first ``fraction`` of each view's exact outline."""
    from biplanar_reg.annotation import Contour
    from biplanar_reg.outline import outline_polylines

    frames = _frames(model, w, poses, ids, with_landmarks)
    Q = model.instance(w)
    out = []
    for obs, (R, t) in zip(frames, poses, strict=True):
        X = Q @ R.T + t
        views = []
        for o in obs:
            line = outline_polylines(X, o.view, model.faces)[0][0]
            contour = Contour(uv=line[: int(fraction * len(line))], closed=False)
            views.append(vertex_landmarks(o.name, o.view, o.landmark_ids, o.landmark_uv, [contour]))
        out.append(views)
    return out


def test_middle_frames_without_landmarks_register_on_outlines_from_their_neighbours():
    model = synthetic_bone_model(4, seed=0)
    w = np.array([0.8, -0.5, 0.3, 0.1])
    ids = np.array([0, 40, 120, 200, 300, 400])
    poses = _path(4)
    frames = _outline_frames(model, w, poses, ids, [True, False, False, True])
    res = register_frames(model, frames)
    assert res.started_from == ["landmarks", "neighbours", "neighbours", "landmarks"]
    truth = model.instance(w)
    for f in (1, 2):  # outlines only: their pose from the neighbours, then fitted
        R, t = poses[f]
        assert np.degrees(rotation_angle(res.rotations[f], R)) < 0.5
        assert np.sqrt(np.mean(np.sum((res.frame_vertices(f) - (truth @ R.T + t)) ** 2, 1))) < 0.3
    # the uncertainty: every frame's pose is determined, and the shape's sd shrinks as frames
    # (each a new view of the shape) are added
    assert res.vertex_sd_mm.shape == (4, model.n_vertices) and np.isfinite(res.vertex_sd_mm).all()
    shape_sd = [b["shape_sd_median_mm"] for b in res.uncertainty_by_frames]
    assert [b["n_frames"] for b in res.uncertainty_by_frames] == [1, 2, 3, 4]
    assert all(b < a for a, b in zip(shape_sd, shape_sd[1:], strict=False))


def test_long_sequences_bound_the_uncertainty_passes():
    from biplanar_reg.registration.frames import (
        MAX_UNCERTAINTY_COUNTS,
        _frame_counts,
        _sd_frames,
    )

    assert _frame_counts(5) == [1, 2, 3, 4, 5] and _sd_frames(5) == [0, 1, 2, 3, 4]
    counts, frames = _frame_counts(300), _sd_frames(300)
    assert counts[0] == 1 and counts[-1] == 300 and len(counts) <= MAX_UNCERTAINTY_COUNTS + 1
    assert frames[0] == 0 and frames[-1] == 299 and len(frames) == MAX_UNCERTAINTY_COUNTS
