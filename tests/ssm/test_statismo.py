"""statismo HDF5 interchange: round trips, a hand-built statismo file, bad input."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from biplanar_reg.ssm import ShapeModel, build_ssm
from biplanar_reg.ssm.statismo import read_statismo, write_statismo

FACES = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])


def _model() -> ShapeModel:
    rng = np.random.default_rng(0)
    base = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    shapes = base + rng.normal(scale=1.0, size=(6, 4, 3))
    return build_ssm(shapes, FACES, n_modes=3, landmarks={"apex": 3})


def test_round_trip_float64_is_exact(tmp_path) -> None:
    model = _model()
    path = tmp_path / "m.h5"
    model.save(path)  # dispatches on the suffix (float32 by default) ...
    write_statismo(model, path, dtype="float64")  # ... and in full precision here
    back = ShapeModel.load(path)
    np.testing.assert_allclose(back.mean, model.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.modes, model.modes, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.variances, model.variances, rtol=1e-9)
    np.testing.assert_array_equal(back.faces, model.faces)
    np.testing.assert_allclose(back.truncation_modes, model.truncation_modes, atol=1e-12)
    np.testing.assert_allclose(back.population_variances, model.population_variances)
    assert back.landmarks == {"apex": 3}
    with h5py.File(path) as f:  # the statismo layout: orthonormal basis, (3, N) points
        u = f["model/pcaBasis"][()]
        np.testing.assert_allclose(u.T @ u, np.eye(3), atol=1e-12)
        assert f["representer/points"].shape == (3, 4)
        assert f["representer/cells"].shape == (3, 4)
        assert f["representer"].attrs["datasetType"] == b"POLYGON_MESH"  # fixed-length
        assert int(f["version/minorVersion"][()]) == 9


def test_round_trip_float32(tmp_path) -> None:
    model = _model()
    model.save(tmp_path / "m.h5")
    back = ShapeModel.load(tmp_path / "m.h5")
    np.testing.assert_allclose(back.modes, model.modes, atol=1e-5 * np.abs(model.modes).max())


@pytest.mark.parametrize("version", [(0, 9), (0, 8), None])
def test_hand_built_statismo_file(tmp_path, version) -> None:
    """A file written the way statismo does (float32; 0.8 stores U*sqrt(var); no version ->
    0.8), with a reference differing from the mean, and no biplanar_reg group."""
    rng = np.random.default_rng(1)
    n, m = 5, 2
    mean = rng.normal(size=3 * n)
    u, _ = np.linalg.qr(rng.normal(size=(3 * n, m)))
    var = np.array([4.0, 1.0])
    stored = u if version == (0, 9) else u * np.sqrt(var)
    path = tmp_path / "statismo.h5"
    with h5py.File(path, "w") as f:
        if version is not None:
            f["version/majorVersion"], f["version/minorVersion"] = (
                np.int32(version[0]),
                np.int32(version[1]),
            )
        f["model/mean"] = mean.astype(np.float32)
        f["model/pcaBasis"] = stored.astype(np.float32)
        f["model/pcaVariance"] = var.astype(np.float32)
        f["model/noiseVariance"] = np.float32(0.0)
        rep = f.create_group("representer")
        rep.attrs["name"] = "vtkStandardMeshRepresenter"
        rep.attrs["datasetType"] = "POLYGON_MESH"
        rep["points"] = (mean.reshape(n, 3).T + 1.0).astype(np.float32)
        rep["cells"] = np.array([[0, 1, 2], [2, 3, 4]], dtype=np.uint32).T
    model = read_statismo(path)
    assert model.n_vertices == n and model.n_modes == m
    np.testing.assert_allclose(model.mean, mean.reshape(n, 3), atol=1e-6)
    np.testing.assert_array_equal(model.faces, [[0, 1, 2], [2, 3, 4]])
    w = np.array([0.5, -1.0])  # statismo's sample: mean + U diag(sqrt(var)) w
    expected = mean + u @ (np.sqrt(var) * w)
    np.testing.assert_allclose(model.instance(w).reshape(-1), expected, atol=1e-5)


def test_bad_input(tmp_path) -> None:
    path = tmp_path / "empty.h5"
    with h5py.File(path, "w") as f:
        f.create_group("representer")["points"] = np.zeros((3, 2))
    with pytest.raises(ValueError, match=r"empty\.h5: missing key 'model/mean'"):
        ShapeModel.load(path)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(ValueError, match=r"junk\.h5: not a readable HDF5 file"):
        ShapeModel.load(tmp_path / "junk.h5")
    nonortho = ShapeModel(np.zeros((2, 3)), np.ones((2, 2, 3)) * [[[1.0]], [[2.0]]])
    with pytest.raises(ValueError, match="not mutually orthogonal"):
        write_statismo(nonortho, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()
