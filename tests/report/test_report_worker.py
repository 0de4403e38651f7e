"""The report written by a child process (:mod:`biplanar_reg.report.worker`): the same files
as in this process, and this process writes them itself whenever the child cannot."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from biplanar_reg.cases import load_case, run_case_dir, to_view_observations
from biplanar_reg.cases.metrics import model_outlines
from biplanar_reg.cases.pipeline import report_views
from biplanar_reg.io import read_mesh
from biplanar_reg.report import prepare, worker
from biplanar_reg.report.case_report import write_case_report
from biplanar_reg.simulate import write_synthetic_case


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The arguments of ``write_case_report`` for a registered synthetic case (no report)."""
    case_dir = write_synthetic_case(tmp_path_factory.mktemp("w") / "c", seed=1)
    outcome = run_case_dir(case_dir, report=False)
    case = load_case(case_dir)
    obs = to_view_observations(case)
    V, F = read_mesh(outcome.out_dir / "registered.ply")
    fit = SimpleNamespace(
        frame_vertices=[V],
        view_poses={},
        outlines=[{o.name: model_outlines(V, F, o.view) for o in obs}],
    )
    views = report_views(case, [obs], fit, [0])[0]
    arrays = {"vertices": V, "faces": F, "vertex_error": 0.01 * V[:, 0] % 1.0}
    return outcome.result, views, arrays


def _page(folder: Path) -> str:
    """report.html without its embedded figures (the 3D view's render is compared apart)."""
    return re.sub(r"data:image/png;base64,[^\"]+", "", (folder / "report.html").read_text())


def test_the_child_writes_the_report_this_process_would(inputs, tmp_path):
    doc, views, arrays = inputs
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    expected = write_case_report(here, doc, views, **arrays)
    worker.start_report_process(len(views), ground_truth=True)
    got = worker.delegated_report(there, doc, views, arrays)
    assert got == expected and got["renderer"] is not None
    assert sorted(p.name for p in there.iterdir()) == sorted(p.name for p in here.iterdir())
    for p in here.iterdir():  # an off-screen GL render need not be bit-identical
        if p.suffix == ".png" and p.name != "error_3d.png":
            assert (there / p.name).read_bytes() == p.read_bytes(), p.name
    assert _page(there) == _page(here)
    # it served its one report: there is no child any more
    assert worker.delegated_report(tmp_path, doc, views, arrays) is None


def test_the_report_is_written_here_when_the_child_cannot(inputs, tmp_path):
    doc, views, arrays = inputs
    # the child died before it was asked: written here
    worker.start_report_process(len(views))
    child = worker._child
    child.process.kill()
    child.process.join(10)
    written = prepare.write_prepared_report(tmp_path, doc, views, **arrays)
    assert (tmp_path / "report.html").is_file() and written["html"] == "report.html"
    # the child raised on what it was given: None, for the caller to write it here
    worker.start_report_process(len(views))
    child = worker._child
    broken = [SimpleNamespace(name="cam1")]  # no annotations, outlines, ...
    assert worker.delegated_report(tmp_path / "x", doc, broken, arrays) is None
    child.process.join(30)
    assert child.process.exitcode == 0


def test_a_child_that_does_not_answer_in_time_is_ended(inputs, tmp_path, monkeypatch):
    doc, views, arrays = inputs
    monkeypatch.setattr(worker, "REPORT_TIMEOUT_S", 0.01)  # it needs about a second
    worker.start_report_process(len(views))
    child = worker._child
    assert worker.delegated_report(tmp_path, doc, views, arrays) is None
    child.process.join(10)
    assert not child.process.is_alive() and child.process.exitcode != 0


def test_report_in_child_starts_a_child_and_ends_an_unused_one():
    prepare.prepare_report(2)  # outside the block: no child
    assert worker._child is None
    with prepare.report_in_child():
        prepare.prepare_report(2)
        child = worker._child
        assert child is not None and child.process.is_alive()
    assert worker._child is None and not child.process.is_alive()
