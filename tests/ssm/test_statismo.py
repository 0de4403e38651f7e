"""statismo HDF5 interchange: round trips, a hand-built statismo file, bad input."""

from __future__ import annotations

import logging

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


# -- what statismo's and scalismo's readers need -------------------------------------------------
# Encoded from their reading code (neither can be installed here, so the file layout is checked
# against these requirements instead of by running them):
#
# statismo (C++, github.com/statismo/statismo):
#   modules/core/include/StatismoIO.h, IO<T>::LoadStatisticalModel: opens group /representer
#     and calls the representer's Load; /version/{majorVersion,minorVersion} via
#     HDF5Utils::readInt, only (0, 8) and (0, 9) accepted; /model/mean and /model/pcaVariance via
#     readVector (1-D), /model/pcaBasis via readMatrix (2-D, hyperslab of the columns),
#     /model/noiseVariance via readFloat (one value); then ModelInfo::Load(/).
#   modules/core/src/ModelInfo.cxx, ModelInfo::Load: opens group /modelinfo; ./scores optional
#     (an H5 exception is caught); every member whose name contains "modelBuilder" is a group
#     read by BuilderInfo::Load: readString ./builderName and ./buildTime (required), groups
#     ./dataInfo and ./parameters whose members are all read with readString; a member whose
#     name contains "dataInfo" or "builderInfo" switches to the pre-0.9 layout (needs
#     ./builderInfo and ./build-time), so none may sit directly in /modelinfo.
#   modules/core/include/HDF5Utils.hxx: readString = DataSet::read(std::string, getStrType())
#     and writeString = fixed-length C_S1 of length + 1, scalar dataspace (likewise the string
#     attributes); readMatrix/readVector convert to float (NATIVE_FLOAT); writeMatrix refuses
#     empty matrices.
#   modules/ITK/include/itkStandardMeshRepresenter.hxx and modules/VTK/src/
#     vtkStandardMeshRepresenter.cxx, Load/LoadRef: readStringAttribute "name" (legacy names
#     vtkPolyDataRepresenter / itkMeshRepresenter take another path), readMatrix ./points
#     (3, N), readMatrixOfType<unsigned int> ./cells (cellDim rows, one column per cell),
#     converted to NATIVE_UINT.
# scalismo (Scala, github.com/unibas-gravis/scalismo), reading with jhdf (pure Java):
#   src/main/scala/scalismo/io/statisticalmodel/StatismoIO.scala, readStatismoPDM (and the older
#     src/main/scala/scalismo/io/StatismoIO.scala, readStatismoPointModel): string attribute
#     /representer@datasetType in {POINT_SET, POLYGON_MESH, ...} and @name;
#     readNDArrayFloat representer/points with dims(0) == 3; cells (required for POLYGON_MESH)
#     via readNDArrayInt, (3, F) (StatismoDomainIO.scala: "Representer cells are not
#     triangles" otherwise); readArrayFloat model/mean and model/pcaVariance, readNDArrayFloat
#     model/pcaBasis; readInt /version/{majorVersion,minorVersion}, (0, 9) or (1, _) accepted.
#   src/main/scala/scalismo/io/statisticalmodel/HDF5Reader.scala: these cast jhdf's getData()
#     with asInstanceOf[Array[Array[Float]]], [Array[Array[Int]]], [Array[Float]], [Int]; jhdf
#     (io/jhdf/object/datatype/FixedPoint.java, getJavaType) returns int for signed 32-bit,
#     long for unsigned 32-bit, and (FloatingPoint) double for 64-bit floats: so the arrays must
#     be float32, the cells and the version numbers signed int32, or the cast fails.


def _is_fixed_string(obj_type: h5py.h5t.TypeID) -> bool:
    return obj_type.get_class() == h5py.h5t.STRING and not obj_type.is_variable_str()


def _string_dataset(f: h5py.File, key: str) -> str:
    assert isinstance(f.get(key), h5py.Dataset), f"missing string dataset {key}"
    ds = f[key]
    assert ds.shape == () and _is_fixed_string(ds.id.get_type()), key
    return ds[()].decode("ascii")


def _string_attr(obj: h5py.HLObject, name: str) -> str:
    assert name in obj.attrs, f"missing attribute {name}"
    aid = h5py.h5a.open(obj.id, name.encode())
    assert aid.shape == () and _is_fixed_string(aid.get_type()), name
    return obj.attrs[name].decode("ascii")


def _require_float32(f: h5py.File, key: str, ndim: int) -> np.ndarray:
    ds = f[key]
    assert ds.dtype == np.float32 and ds.ndim == ndim, (key, ds.dtype, ds.shape)
    return ds[()]


def check_statismo_scalismo_layout(path) -> None:
    """The requirements above, for a shape model file (float32 export)."""
    with h5py.File(path, "r") as f:
        for key in ("version/majorVersion", "version/minorVersion"):  # readInt / jhdf Integer
            assert f[key].shape == () and f[key].dtype == np.int32, key
        assert (int(f["version/majorVersion"][()]), int(f["version/minorVersion"][()])) == (0, 9)
        mean = _require_float32(f, "model/mean", 1)
        var = _require_float32(f, "model/pcaVariance", 1)
        basis = _require_float32(f, "model/pcaBasis", 2)
        assert basis.shape == (mean.size, var.size) and var.size >= 1  # no empty matrices
        assert f["model/noiseVariance"].size == 1 and f["model/noiseVariance"].dtype.kind == "f"
        rep = f["representer"]
        name, kind = _string_attr(rep, "name"), _string_attr(rep, "datasetType")
        assert name not in ("vtkPolyDataRepresenter", "itkMeshRepresenter")  # legacy path
        points = _require_float32(f, "representer/points", 2)
        assert points.shape == (3, mean.size // 3)
        if kind == "POLYGON_MESH":
            cells = rep["cells"]
            assert cells.dtype == np.int32 and cells.ndim == 2 and cells.shape[0] == 3
            assert cells[()].min() >= 0 and cells[()].max() < points.shape[1]
        else:
            assert kind == "POINT_SET"
        info = f["modelinfo"]
        assert not [k for k in info if "dataInfo" in k or "builderInfo" in k]
        builders = [k for k in info if "modelBuilder" in k]
        assert builders, "no modelinfo/modelBuilder-* group"
        for b in builders:
            _string_dataset(f, f"modelinfo/{b}/builderName")
            _string_dataset(f, f"modelinfo/{b}/buildTime")
            for sub in ("dataInfo", "parameters"):
                assert isinstance(info[b].get(sub), h5py.Group), f"{b}/{sub}"
                for k in info[b][sub]:
                    _string_dataset(f, f"modelinfo/{b}/{sub}/{k}")
        if "scores" in info:
            assert info["scores"].ndim == 2


def test_export_layout_meets_statismo_and_scalismo_readers(tmp_path) -> None:
    model = _model()
    model.save(tmp_path / "m.h5")
    check_statismo_scalismo_layout(tmp_path / "m.h5")
    back = ShapeModel.load(tmp_path / "m.h5")  # and this package still reads it
    np.testing.assert_array_equal(back.faces, model.faces)


def test_point_model_export_is_a_scalismo_point_set(tmp_path) -> None:
    model = _model()
    points = ShapeModel(model.mean, model.modes, variances=model.variances)
    write_statismo(points, tmp_path / "p.h5")
    check_statismo_scalismo_layout(tmp_path / "p.h5")
    with h5py.File(tmp_path / "p.h5") as f:
        assert f["representer"].attrs["datasetType"] == b"POINT_SET"
        assert "cells" not in f["representer"]  # what scalismo writes for a point set


def test_float64_export_says_it_is_for_this_tool_only(tmp_path, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        write_statismo(_model(), tmp_path / "m.h5", dtype="float64")
    assert any("only" in r.message and "scalismo" in r.message for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        write_statismo(_model(), tmp_path / "m32.h5")
    assert not caplog.records


def test_model_without_modes_is_refused(tmp_path) -> None:
    model = _model()
    empty = ShapeModel(model.mean, np.zeros((0, model.n_vertices, 3)), faces=model.faces)
    with pytest.raises(ValueError, match="no modes"):
        write_statismo(empty, tmp_path / "e.h5")
    assert not (tmp_path / "e.h5").exists()
