"""``biplanar-reg ssm augment``: the augmented model, and bad arguments as one-line errors."""

from __future__ import annotations

import json

from biplanar_reg.cli import main
from biplanar_reg.simulate.scenes import synthetic_bone_model
from biplanar_reg.ssm import ShapeModel
from biplanar_reg.ssm.gaussian_process import split_modes


def test_augment_writes_the_model_with_its_kernel(tmp_path, capsys):
    model = synthetic_bone_model(3, seed=0, resolution=(16, 12))
    model.save(tmp_path / "m.npz")
    out = tmp_path / "gp.npz"
    args = ["--json", "ssm", "augment", str(tmp_path / "m.npz"), "-o", str(out), "--width", "15"]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    back = ShapeModel.load(out)
    info = split_modes(back)
    assert info is not None and info.ssm_modes == 3 and info.width_mm == 15.0
    assert doc["kernel_modes"] == back.n_modes - 3 > 0


def test_bad_arguments_are_one_line_errors_and_write_nothing(tmp_path, capsys):
    model = synthetic_bone_model(3, seed=0, resolution=(16, 12))
    model.save(tmp_path / "m.npz")
    assert main(["ssm", "augment", str(tmp_path / "m.npz"), "-o", str(tmp_path / "x.txt")]) == 2
    assert "x.txt: the output must end in .npz, .h5 or .hdf5" in capsys.readouterr().err
    assert main(["ssm", "augment", str(tmp_path / "no.npz"), "-o", str(tmp_path / "y.npz")]) == 2
    assert "no.npz: file not found" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]
