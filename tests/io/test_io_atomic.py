"""The one atomic writer: modes honour the umask, nothing is half-written, all writers use it."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.io import atomic as atomic_module
from biplanar_reg.io.atomic import (
    atomic_path,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    current_umask,
    new_file_mode,
)


@pytest.fixture
def umask022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_current_umask_reads_without_changing(umask022):
    assert current_umask() == 0o022
    os.umask(0o027)
    assert current_umask() == 0o027
    assert os.umask(0o022) == 0o027  # still set: reading it did not change it


def test_helpers_write_content_and_mode(tmp_path, umask022):
    a = atomic_write_bytes(tmp_path / "a.bin", b"\x00\x01")
    b = atomic_write_text(tmp_path / "sub" / "b.txt", "x\ny\n")  # parents are created
    c = atomic_write_json(tmp_path / "c.json", {"k": [1, 2.5]})
    with atomic_path(tmp_path / "d.npy") as tmp:
        assert tmp.parent == tmp_path and tmp.name.endswith(".npy")  # libraries see the suffix
        np.save(tmp, np.arange(3))
    assert a.read_bytes() == b"\x00\x01" and b.read_text() == "x\ny\n"
    assert json.loads(c.read_text()) == {"k": [1, 2.5]} and c.read_text().endswith("\n")
    assert np.load(tmp_path / "d.npy").tolist() == [0, 1, 2]
    for p in (a, b, c, tmp_path / "d.npy"):
        assert _mode(p) == 0o644, p
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "c.json", "d.npy", "sub"]


def test_mode_follows_umask_and_existing_file(tmp_path):
    old = os.umask(0o077)
    try:
        p = atomic_write_text(tmp_path / "private.txt", "1")
        assert _mode(p) == 0o600
        os.umask(0o022)
        os.chmod(p, 0o640)
        atomic_write_text(p, "2")  # rewriting keeps the file's mode, as open() would
        assert _mode(p) == 0o640 and p.read_text() == "2"
        assert new_file_mode(tmp_path / "new") == 0o644
    finally:
        os.umask(old)


def test_failure_leaves_target_and_no_temporary(tmp_path):
    target = atomic_write_text(tmp_path / "t.txt", "old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    with pytest.raises(ValueError, match="NaN|Out of range"):
        atomic_write_json(target, {"x": float("nan")})
    assert target.read_text() == "old"
    with pytest.raises(ValueError, match="does not exist"):
        atomic_write_text(tmp_path / "missing" / "x.txt", "1", make_parents=False)
    assert [p.name for p in tmp_path.iterdir()] == ["t.txt"]


def test_compressed_suffix_kept(tmp_path):
    with atomic_path(tmp_path / "table.csv.gz") as tmp:
        assert tmp.name.endswith(".csv.gz")
        tmp.write_bytes(b"")


def test_replace_is_the_last_step(tmp_path, monkeypatch):
    """The rename happens after the data are flushed; a failing rename leaves the old file."""
    target = atomic_write_text(tmp_path / "t.txt", "old")
    calls = []
    real_fsync = os.fsync
    monkeypatch.setattr(atomic_module.os, "fsync", lambda fd: (calls.append(fd), real_fsync(fd)))

    def failing_replace(src, dst):
        assert calls, "fsync before replace"
        raise OSError("rename refused")

    monkeypatch.setattr(atomic_module.os, "replace", failing_replace)
    with pytest.raises(OSError, match="rename refused"):
        atomic_write_text(target, "new")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["t.txt"]


def _view(fmt: str):
    from biplanar_reg.calibration import PerspectiveView

    f = -6000.0 if fmt == "dicom" else 6000.0  # DICOM's C-arm convention mirrors u
    return PerspectiveView(
        K=np.array([[f, 0, 511.5], [0, 6000.0, 383.5], [0, 0, 1]]),
        R=np.array([[-1.0, 0, 0], [0, 0, -1], [0, -1, 0]]),
        t=np.array([0.0, 0.0, 800.0]),
        image_size=(1024, 768),
        name="cam1",
    )


def test_every_writer_gives_0644_under_umask_022(tmp_path, umask022):
    """The package's file writers all honour the umask (``save_calibration`` used to give 0600)."""
    from biplanar_reg.annotation import (
        Annotations,
        Contour,
        Landmark,
        ViewAnnotations,
        save_annotations,
    )
    from biplanar_reg.annotation.recipe import parse_recipe, save_recipe
    from biplanar_reg.calibration import WRITABLE_FORMATS, save_calibration
    from biplanar_reg.io import write_mesh
    from biplanar_reg.report import write_page
    from biplanar_reg.ssm import ShapeModel

    written = []
    for fmt in WRITABLE_FORMATS:
        path = tmp_path / f"cam1_{fmt}.{'dcm' if fmt == 'dicom' else 'txt'}"
        save_calibration(_view(fmt), path, fmt)
        written.append(path)
    ann = Annotations(
        {
            "cam1": ViewAnnotations(
                landmarks={"tip": Landmark(np.array([10.0, 20.0]))},
                contours=[Contour(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 7.0]]))],
            )
        }
    )
    written.append(save_annotations(ann, tmp_path / "annotations.json"))
    recipe = parse_recipe(
        {
            "format": "biplanar-reg/contour-recipe@1",
            "image": "cam1.png",
            "view": "cam1",
            "method": "livewire",
            "anchors": [[1, 2], [30, 40]],
        }
    )
    written.append(save_recipe(recipe, tmp_path / "c.recipe.json"))
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    for suffix in (".ply", ".stl", ".obj", ".vtp"):
        write_mesh(tmp_path / f"m{suffix}", v, f)
        written.append(tmp_path / f"m{suffix}")
    for suffix in (".csv", ".npy"):
        write_mesh(tmp_path / f"p{suffix}", v)
        written.append(tmp_path / f"p{suffix}")
    model = ShapeModel(v, np.zeros((1, 4, 3)), faces=f)
    model.save(tmp_path / "model.npz")
    written.append(tmp_path / "model.npz")
    written.append(write_page(tmp_path / "page.html", "summary.html", **_summary_context()))
    for p in written:
        assert p.is_file() and _mode(p) == 0o644, (p.name, oct(_mode(p)))
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries


def _summary_context() -> dict:
    """The smallest context the batch summary template renders with."""
    return {
        "counts": {"total": 0, "done": 0, "skipped": 0, "failed": 0},
        "wall_seconds": 0.0,
        "stat_names": (),
        "stats": {},
        "columns": (),
        "rows": [],
    }
