"""``register --no-report`` / ``batch --no-report``: the numbers without the report; batch
workers' BLAS threads."""

from __future__ import annotations

import io
import json
import os

from biplanar_reg._threads import THREAD_VARIABLES, available_cores, worker_threads
from biplanar_reg.cases.batch import run_batch
from biplanar_reg.cases.outputs import is_complete
from biplanar_reg.cli import main
from biplanar_reg.simulate import write_synthetic_case


def test_register_and_batch_without_report(tmp_path, capsys):
    case = write_synthetic_case(tmp_path / "c0", 0, image_size=(192, 192), silhouettes=False)
    out = tmp_path / "out"
    assert main(["--json", "register", str(case), "--out", str(out), "--no-report"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["report"] is None
    doc = json.loads((out / "result.json").read_text())
    exported = {e.split("/")[0] for e in doc["exports"]}  # docs/exports.md
    assert sorted(p.name for p in out.iterdir() if p.name not in exported) == [
        "inputs.json",  # the record of the case's input files (docs/cases.md)
        "registered.ply",
        "result.json",
    ]
    assert doc["report"] is None and doc["metrics"]["vertex_rms_mm"] < 1.0
    assert "report" not in doc["timings"]
    assert is_complete(out, report=False) and not is_complete(out)

    batch_out = tmp_path / "batch"
    s = run_batch([case], batch_out, workers=1, report=False, progress_stream=io.StringIO())
    assert s.counts["done"] == 1 and not (batch_out / "c0" / "report.html").exists()
    assert s.rows[0]["report"] == ""
    again = run_batch([case], batch_out, workers=1, report=False, progress_stream=io.StringIO())
    assert again.counts["skipped"] == 1  # complete without a report (a run with reports
    # redoes it: is_complete(out) is False above)


def test_worker_threads_share_the_cores(monkeypatch):
    for k in THREAD_VARIABLES:
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")  # the user's choice is kept
    with worker_threads(2):
        assert os.environ["OPENBLAS_NUM_THREADS"] == str(max(1, available_cores() // 2))
        assert os.environ["OMP_NUM_THREADS"] == os.environ["OPENBLAS_NUM_THREADS"]
        assert os.environ["MKL_NUM_THREADS"] == "3"
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["MKL_NUM_THREADS"] == "3"
