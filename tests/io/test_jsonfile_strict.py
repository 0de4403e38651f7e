"""Strict JSON: a key given twice in one object is an error naming the file and the key.

Python's json module keeps the last of two equal keys silently; an edited ``landmarks.json``
or ``annotations.json`` with a landmark named twice would then register with the wrong one.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from biplanar_reg.cli import main
from biplanar_reg.io import read_json

ROOT = Path(__file__).resolve().parents[2]


def test_a_duplicate_key_is_a_one_line_error_naming_file_and_key(tmp_path):
    path = tmp_path / "landmarks.json"
    path.write_text('{"tip": 3, "base": 7,\n "tip": 9}')
    with pytest.raises(ValueError) as err:
        read_json(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "duplicate key 'tip'" in msg and "\n" not in msg
    nested = tmp_path / "nested.json"
    nested.write_text('{"views": {"cam1": {"uv": [1, 2], "uv": [3, 4]}}, "x": 1}')
    with pytest.raises(ValueError, match=r"nested\.json: duplicate key 'uv'"):
        read_json(nested)
    # with constants=True (the annotation reader) too; equal keys in different objects are fine
    with pytest.raises(ValueError, match="duplicate key 'a'"):
        read_json(_write(tmp_path / "c.json", '{"a": NaN, "a": 1}'), constants=True)
    ok = read_json(_write(tmp_path / "ok.json", '{"a": {"k": 1}, "b": {"k": 2}, "c": [{"k": 3}]}'))
    assert ok == {"a": {"k": 1}, "b": {"k": 2}, "c": [{"k": 3}]}


def test_a_key_that_needs_quoting_stays_on_one_line(tmp_path):
    path = _write(tmp_path / "q.json", '{"a\\nb": 1, "a\\nb": 2}')
    with pytest.raises(ValueError) as err:
        read_json(path)
    assert "\n" not in str(err.value) and "duplicate key 'a\\nb'" in str(err.value)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("which", ["landmarks", "annotations"])
def test_register_refuses_a_case_file_with_a_duplicate_key(tmp_path, capsys, which):
    case = tmp_path / "case"
    shutil.copytree(ROOT / "sample_cases" / "synthetic_demo", case)
    if which == "landmarks":
        path = case / "model" / "landmarks.json"
        text = path.read_text().replace(
            '"distal_tip": 481,', '"distal_tip": 481,\n  "distal_tip": 7,'
        )
        key = "distal_tip"
    else:
        path = case / "annotations.json"
        text = path.read_text().replace('"sigma_px": 1.0', '"sigma_px": 1.0, "sigma_px": 9.0', 1)
        key = "sigma_px"
    assert text != path.read_text()
    path.write_text(text)
    capsys.readouterr()
    assert main(["register", str(case), "--out", str(tmp_path / "out"), "--no-report"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert path.name in err[0] and f"duplicate key '{key}'" in err[0], err[0]
    assert not (tmp_path / "out").exists()


def test_the_other_json_readers_refuse_a_duplicate_key_too(tmp_path):
    from biplanar_reg.calibration.native_json import read_native_json
    from biplanar_reg.ssm.inputs import read_landmarks

    calib = tmp_path / "cam.json"
    calib.write_text(
        '{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "K": [[2, 0, 0], [0, 2, 0], [0, 0, 1]]}'
    )
    with pytest.raises(ValueError, match=r"cam\.json: duplicate key 'K'"):
        read_native_json(calib)
    marks = tmp_path / "marks.json"
    marks.write_text('{"tip": 1, "tip": 2}')
    with pytest.raises(ValueError, match=r"marks\.json: duplicate key 'tip'"):
        read_landmarks(marks)
