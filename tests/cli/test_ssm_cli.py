"""The template / population / ssm commands, end to end on the shipped wrist radius CT."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from biplanar_reg.cli import main
from biplanar_reg.io.meshes import read_mesh, write_mesh
from biplanar_reg.ssm.model import ShapeModel

DATA = Path(__file__).resolve().parents[2] / "sample_cases" / "wrist_radius" / "data"


def test_ct_to_population_to_model(tmp_path, capsys):
    bone = tmp_path / "radius.ply"
    rc = main(
        [
            "template",
            "from-ct",
            str(DATA / "radius_ct.tif"),
            "-o",
            str(bone),
            "--voxel-size",
            "0.39625",
            "0.39625",
            "0.625",
            "--target-vertices",
            "2000",
        ]
    )
    assert rc == 0
    assert "closed, 1 component" in capsys.readouterr().out
    v, f = read_mesh(bone)
    assert abs(len(v) - 2000) < 100 and f is not None

    pop = tmp_path / "pop"
    assert (
        main(["population", "synth", str(bone), "-o", str(pop), "--size", "5", "--seed", "0"]) == 0
    )
    capsys.readouterr()
    files = sorted(pop.glob("shape_*.ply"))
    assert len(files) == 5
    manifest = json.loads((pop / "population.json").read_text())
    assert manifest["seed"] == 0 and len(manifest["shapes"]) == 5
    for p in files:
        v2, f2 = read_mesh(p)
        np.testing.assert_array_equal(f2, f)

    (tmp_path / "lm.json").write_text(json.dumps({"distal_tip": 5, "proximal": 17}))
    model_path = tmp_path / "model.npz"
    rc = main(
        [
            "--json",
            "ssm",
            "build",
            str(pop),
            "-o",
            str(model_path),
            "--variance",
            "0.95",
            "--landmarks",
            str(tmp_path / "lm.json"),
        ]
    )
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    model = ShapeModel.load(model_path)
    assert model.landmarks == {"distal_tip": 5, "proximal": 17}
    assert len(report["modes"]) == model.n_modes >= 1
    assert all(0.0 <= m["affine_fraction"] <= 1.0 for m in report["modes"])

    assert main(["ssm", "info", str(model_path)]) == 0
    assert "affine_fraction" in capsys.readouterr().out
    dense = tmp_path / "dense.npz"
    assert main(["ssm", "densify", str(model_path), "-o", str(dense), "--points", "500"]) == 0
    assert ShapeModel.load(dense).n_vertices == model.n_vertices + 500


def _sphere(tmp_path: Path, name: str, subdivisions: int = 1) -> tuple[Path, np.ndarray]:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=10.0)
    path = tmp_path / name
    write_mesh(path, s.vertices, s.faces)
    return path, s.faces


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("one", "need at least 2 shapes"),
        ("count", r"b\.ply: 162 vertices, but a\.ply has 42"),
        ("faces", r"b\.ply: faces differ from a\.ply"),
        ("nonmanifold", r"a\.ply: non-manifold mesh"),
        ("landmarks", r"lm\.json: landmarks\['x'\]: index 999 out of range"),
        ("mixed", r"b\.csv: is a point set, unlike a\.ply"),
    ],
)
def test_ssm_build_bad_inputs(tmp_path, capsys, case, message):
    a, faces = _sphere(tmp_path, "a.ply")
    v, _ = read_mesh(a)
    inputs = [str(a)]
    extra: list[str] = []
    if case == "count":
        inputs.append(str(_sphere(tmp_path, "b.ply", subdivisions=2)[0]))
    elif case == "faces":
        write_mesh(tmp_path / "b.ply", v, np.roll(faces, 1, axis=0))
        inputs.append(str(tmp_path / "b.ply"))
    elif case == "nonmanifold":
        write_mesh(a, v, np.vstack([faces, [faces[0, 0], faces[0, 1], 41]]))
        inputs.append(str(a))
    elif case == "landmarks":
        write_mesh(tmp_path / "b.ply", v * 1.1, faces)
        inputs.append(str(tmp_path / "b.ply"))
        (tmp_path / "lm.json").write_text('{"x": 999}')
        extra = ["--landmarks", str(tmp_path / "lm.json")]
    elif case == "mixed":
        write_mesh(tmp_path / "b.csv", v)
        inputs.append(str(tmp_path / "b.csv"))
    rc = main(["ssm", "build", *inputs, "-o", str(tmp_path / "m.npz"), *extra])
    assert rc == 2
    assert __import__("re").search(message, capsys.readouterr().err)
    assert not (tmp_path / "m.npz").exists()


def test_from_ct_bad_inputs(tmp_path, capsys):
    rc = main(["template", "from-ct", str(DATA / "radius_ct.tif"), "-o", str(tmp_path / "b.ply")])
    assert rc == 2
    assert "voxel_size (x, y, z) in mm is required" in capsys.readouterr().err
    np.save(tmp_path / "zeros.npy", np.zeros((4, 4, 4)))
    rc = main(
        [
            "template",
            "from-ct",
            str(tmp_path / "zeros.npy"),
            "-o",
            str(tmp_path / "b.ply"),
            "--voxel-size",
            "1",
            "1",
            "1",
            "--threshold",
            "10",
        ]
    )
    assert rc == 2
    assert "zeros.npy: empty segmentation" in capsys.readouterr().err
    assert not (tmp_path / "b.ply").exists()
