"""Mesh and point-cloud I/O (biplanar_reg.io.meshes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from biplanar_reg.io import meshes
from biplanar_reg.io.meshes import check_manifold, read_mesh, write_mesh


def _mesh(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An icosphere with shuffled vertex order (so order preservation is actually tested)."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(sphere.vertices))
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm))
    vertices = sphere.vertices[perm] + rng.normal(0, 0.01, sphere.vertices.shape)
    return vertices, inv[sphere.faces]


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".vtk", ".vtp"])
def test_mesh_round_trip_keeps_vertex_order(tmp_path, suffix):
    v, f = _mesh()
    path = tmp_path / f"m{suffix}"
    write_mesh(path, v, f)
    v2, f2 = read_mesh(path)
    np.testing.assert_allclose(v2, v, rtol=0, atol=1e-5 if suffix == ".vtk" else 1e-12)
    np.testing.assert_array_equal(f2, f)
    assert not list(tmp_path.glob(".*part*"))  # no temporary left behind


def test_stl_numbers_vertices_in_first_use_order(tmp_path):
    v, f = _mesh()
    write_mesh(tmp_path / "m.stl", v, f)
    v2, f2 = read_mesh(tmp_path / "m.stl")
    order = np.unique(f.ravel(), return_index=True)[1]
    first_use = f.ravel()[np.sort(order)]
    np.testing.assert_allclose(v2, v[first_use], atol=1e-4)  # STL stores float32
    # Same faces -> same numbering for another shape of the same topology.
    write_mesh(tmp_path / "b.stl", v * 1.1, f)
    _, f3 = read_mesh(tmp_path / "b.stl")
    np.testing.assert_array_equal(f3, f2)


@pytest.mark.parametrize("suffix", [".ply", ".csv", ".npy", ".vtp", ".obj"])
def test_point_cloud_round_trip(tmp_path, suffix):
    v = np.random.default_rng(1).normal(size=(50, 3)) * 7.0
    write_mesh(tmp_path / f"p{suffix}", v)
    v2, f2 = read_mesh(tmp_path / f"p{suffix}")
    assert f2 is None
    np.testing.assert_allclose(v2, v, atol=1e-12)


def test_bad_inputs_are_clear(tmp_path):
    v, f = _mesh()
    with pytest.raises(ValueError, match=r"nope\.ply: file not found"):
        read_mesh(tmp_path / "nope.ply")
    with pytest.raises(ValueError, match=r"m\.xyz: unsupported mesh/point-cloud format"):
        write_mesh(tmp_path / "m.xyz", v, f)
    with pytest.raises(ValueError, match="STL needs faces"):
        write_mesh(tmp_path / "p.stl", v)
    with pytest.raises(ValueError, match="stores points only"):
        write_mesh(tmp_path / "p.csv", v, f)
    with pytest.raises(ValueError, match=r"face vertex index out of range"):
        write_mesh(tmp_path / "m.ply", v, f + len(v))
    with pytest.raises(ValueError, match="folder .* does not exist"):
        write_mesh(tmp_path / "missing" / "m.ply", v, f)
    assert not (tmp_path / "m.ply").exists()
    (tmp_path / "bad.csv").write_text("x,y,z\n1,2,3\n4,5\n")
    with pytest.raises(ValueError, match=r"bad\.csv: line 3: expected 3 values"):
        read_mesh(tmp_path / "bad.csv")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat garbage\n")
    with pytest.raises(ValueError, match=r"bad\.ply: cannot read as PLY"):
        read_mesh(tmp_path / "bad.ply")
    np.save(tmp_path / "obj.npy", np.array([None, 1], dtype=object))
    with pytest.raises(ValueError, match=r"obj\.npy: Object arrays cannot be loaded"):
        read_mesh(tmp_path / "obj.npy")


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    v, f = _mesh()
    path = tmp_path / "m.ply"
    write_mesh(path, v, f)
    before = path.read_bytes()

    def half_write(tmp, *args):
        tmp.write_bytes(b"ply\npartial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(meshes, "_write_ply", half_write)
    with pytest.raises(RuntimeError):
        write_mesh(path, v * 2, f)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


def test_check_manifold():
    _, f = _mesh()
    check_manifold(f)
    with pytest.raises(ValueError, match="non-manifold mesh, edge"):
        check_manifold(np.vstack([f, [f[0, 0], f[0, 1], 1000]]), name="x.ply")
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="inconsistently oriented"):
        check_manifold(flipped)
