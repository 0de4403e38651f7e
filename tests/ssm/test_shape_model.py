"""ShapeModel: evaluation, landmarks, .npz round trip without pickles, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.ssm import ShapeModel


@pytest.fixture()
def model() -> ShapeModel:
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(10, 3))
    modes = rng.normal(size=(2, 10, 3))
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    return ShapeModel(mean, modes, faces=faces, variances=[2.0, 1.0], landmarks={"tip": 3})


def test_instance_is_mean_plus_weighted_modes(model):
    w = np.array([0.5, -2.0])
    assert np.allclose(model.instance(w), model.mean + 0.5 * model.modes[0] - 2.0 * model.modes[1])
    assert np.allclose(model.instance(), model.mean)
    assert model.n_vertices == 10 and model.n_modes == 2
    assert model.landmark_ids(["tip"]).tolist() == [3]


def test_save_load_round_trip(model, tmp_path):
    path = tmp_path / "m.npz"
    model.save(path)
    back = ShapeModel.load(path)
    assert np.array_equal(back.mean, model.mean) and np.array_equal(back.modes, model.modes)
    assert np.array_equal(back.faces, model.faces)
    assert np.array_equal(back.variances, model.variances)
    assert back.landmarks == {"tip": 3}
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]  # no temporary file left


def test_point_model_without_modes(tmp_path):
    m = ShapeModel(np.zeros((4, 3)), np.zeros((0, 4, 3)))
    m.save(tmp_path / "p.npz")
    back = ShapeModel.load(tmp_path / "p.npz")
    assert back.n_modes == 0 and back.faces is None


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mean": np.zeros((5, 2))}, "mean: expected shape"),
        ({"modes": np.zeros((2, 6, 3))}, r"modes: expected shape \(M, 5, 3\)"),
        ({"mean": np.full((5, 3), np.nan)}, "mean: contains NaN"),
        ({"faces": [[0, 1, 7]]}, "faces: vertex index out of range"),
        ({"variances": [1.0]}, "variances: expected shape"),
        ({"landmarks": {"x": 9}}, "landmarks\\['x'\\]: index 9 out of range"),
    ],
)
def test_bad_model_input_is_named(kwargs, match):
    args = {"mean": np.zeros((5, 3)), "modes": np.zeros((2, 5, 3))}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ShapeModel(**args)


def test_unknown_landmark_and_bad_weights(model):
    with pytest.raises(ValueError, match="not in the model"):
        model.landmark_ids(["styloid"])
    with pytest.raises(ValueError, match="weights: expected shape"):
        model.instance([1.0, 2.0, 3.0])


def test_load_rejects_pickles_and_bad_files(tmp_path):
    obj = tmp_path / "obj.npz"
    np.savez(obj, mean=np.array([{"a": 1}], dtype=object), modes=np.zeros((0, 1, 3)))
    with pytest.raises(ValueError, match="obj.npz"):
        ShapeModel.load(obj)
    missing = tmp_path / "missing.npz"
    np.savez(missing, mean=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="missing key 'modes'"):
        ShapeModel.load(missing)
    with pytest.raises(ValueError, match="file not found"):
        ShapeModel.load(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk.npz: not a readable"):
        ShapeModel.load(junk)


def _damaged(model: ShapeModel, path, damage: str) -> bytes:
    """The bytes of ``model`` saved as .npz, damaged as named (a truncated download, a flipped
    byte in a member's compressed data, a zip that is only its first bytes)."""
    import zipfile

    model.save(path)
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        return bytes(data[: len(data) // 2])
    if damage == "header only":
        return bytes(data[:10])
    if damage == "bad offset":  # the end record's central-directory offset 100 bytes too far:
        end = data.rindex(b"PK\x05\x06") + 16  # the first member then starts at byte -100
        data[end : end + 4] = (int.from_bytes(data[end : end + 4], "little") + 100).to_bytes(
            4, "little"
        )
        return bytes(data)
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("mean.npy")
    at = info.header_offset  # the local header's own name and extra field lengths
    start = at + 30 + int.from_bytes(data[at + 26 : at + 28], "little")
    start += int.from_bytes(data[at + 28 : at + 30], "little")
    if damage == "flipped byte":  # inside the compressed stream of 'mean.npy'
        data[start + info.compress_size // 2] ^= 0xFF
    else:  # "bad deflate": the compressed stream itself is garbage
        data[start : start + 8] = b"\xff" * 8
    return bytes(data)


@pytest.mark.parametrize("damage", ["truncated", "header only", "flipped byte", "bad deflate"])
def test_a_truncated_or_corrupt_npz_is_a_named_error(model, tmp_path, damage):
    """Reproducer (issue 18): ``zipfile.BadZipFile`` and ``zlib.error`` escaped
    ``ShapeModel.load`` (it caught only OSError/ValueError): a traceback at the command line."""
    path = tmp_path / "m.npz"
    path.write_bytes(_damaged(model, path, damage))
    with pytest.raises(ValueError, match=r"m\.npz: not a readable \.npz shape model") as info:
        ShapeModel.load(path)
    assert "\n" not in str(info.value)


def test_an_npz_member_at_a_negative_offset_is_a_named_error(model, tmp_path):
    """Reproducer (issue 18): the ``OSError [Errno 22] Invalid argument`` variant, a seek to
    a negative offset while reading a member, escaped ``ShapeModel.load``."""
    path = tmp_path / "m.npz"
    path.write_bytes(_damaged(model, path, "bad offset"))
    with pytest.raises(ValueError, match=r"m\.npz: not a readable \.npz shape model"):
        ShapeModel.load(path)
