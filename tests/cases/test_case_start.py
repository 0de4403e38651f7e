"""``[registration] start`` (issue 16 item 6): the start pose file of a case."""

from __future__ import annotations

import json

import numpy as np
import pytest

from biplanar_reg.cases import load_case
from biplanar_reg.errors import CaseError
from biplanar_reg.simulate.case_folder import write_synthetic_case


def _with_start(folder, start: dict | None, key: str = "start.json"):
    toml = folder / "case.toml"
    text = toml.read_text()
    line = f'start = "{key}"\n'
    if "[registration]" in text:
        text = text.replace("[registration]\n", "[registration]\n" + line, 1)
    else:
        text += "\n[registration]\n" + line
    toml.write_text(text)
    if start is not None:
        (folder / key).write_text(json.dumps(start))


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory):
    return write_synthetic_case(tmp_path_factory.mktemp("c") / "case", 0)


def _copy(case_dir, tmp_path):
    import shutil

    dst = tmp_path / "case"
    dst.parent.mkdir(exist_ok=True)
    shutil.copytree(case_dir, dst)
    return dst


def test_start_pose_is_read_in_mm(case_dir, tmp_path):
    folder = _copy(case_dir, tmp_path)
    _with_start(folder, {"R": np.eye(3).tolist(), "t": [1.0, 2.0, 3.0]})
    case = load_case(folder)
    np.testing.assert_allclose(case.start.R, np.eye(3))
    np.testing.assert_allclose(case.start.t, [1.0, 2.0, 3.0])
    assert case.start_path.name == "start.json"


def test_a_start_that_is_not_a_rotation_names_file_and_key(case_dir, tmp_path):
    folder = _copy(case_dir, tmp_path)
    _with_start(folder, {"R": (2 * np.eye(3)).tolist(), "t": [0, 0, 0]})
    with pytest.raises(CaseError, match=r"case.toml: \[registration\] start: start.json: R: not"):
        load_case(folder)
    folder = _copy(case_dir, tmp_path / "b")
    _with_start(folder, {"R": np.eye(3).tolist()}, "other.json")
    with pytest.raises(CaseError, match=r"\[registration\] start: other.json: expected an object"):
        load_case(folder)


def test_a_start_outside_the_case_folder_is_refused(case_dir, tmp_path):
    folder = _copy(case_dir, tmp_path)
    (tmp_path / "start.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0, 0, 0]}))
    _with_start(folder, None, "../start.json")
    with pytest.raises(CaseError, match="points outside the case folder"):
        load_case(folder)
