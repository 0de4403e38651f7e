"""Batch registration: isolation of broken cases, resume, Dask LocalCluster, SIGKILL mid-run."""

from __future__ import annotations

import csv
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from biplanar_reg.cases.batch import run_batch
from biplanar_reg.cases.outputs import is_complete
from biplanar_reg.simulate import write_synthetic_case


def _make(root: Path, n: int, broken: tuple[int, ...] = ()) -> list[Path]:
    cases = []
    for i in range(n):
        c = write_synthetic_case(root / f"c{i}", i, image_size=(192, 192), silhouettes=False)
        cases.append(c)
    for i in broken:  # one missing file, one wrong format tag
        if i % 2:
            (cases[i] / "gt/bone.ply").unlink()
        else:
            t = (cases[i] / "case.toml").read_text().replace("case@1", "case@7")
            (cases[i] / "case.toml").write_text(t)
    return cases


@pytest.fixture(scope="module")
def six_cases(tmp_path_factory) -> list[Path]:
    return _make(tmp_path_factory.mktemp("batch"), 6, broken=(1, 4))


def _check_summary(out: Path, n_done: int, n_failed: int) -> list[dict]:
    """The batch summary's counts and files; case folders complete without reports (the batch
    tests run ``report=False``: the report is not what they test, and it is most of a small
    case's time)."""
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows].count("done") == n_done
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == n_failed and all(r["reason"] for r in failed)
    assert (out / "summary.html").is_file() and (out / "summary_stats.csv").is_file()
    for r in rows:
        assert is_complete(out / r["case"], report=False) == (r["status"] == "done")
    assert not list(out.glob(".*"))  # no temporary folders
    return rows


def test_local_batch_isolates_failures_and_resumes(six_cases, tmp_path):
    out = tmp_path / "out"
    s = run_batch(six_cases, out, workers=2, report=False)
    assert s.counts["done"] == 4 and s.counts["failed"] == 2 and s.counts["skipped"] == 0
    rows = _check_summary(out, 4, 2)
    reasons = {r["case"]: r["reason"] for r in rows if r["status"] == "failed"}
    assert "gt/bone.ply: file not found" in reasons["c1"]
    assert "format: expected" in reasons["c4"]
    done_row = next(r for r in rows if r["case"] == "c0")
    assert float(done_row["vertex_rms_mm"]) < 1.0
    mtime = (out / "c0/result.json").stat().st_mtime_ns
    again = run_batch(six_cases, out, workers=2, report=False)  # resume: complete cases are skipped
    assert again.counts["skipped"] == 4 and again.counts["failed"] == 2
    assert (out / "c0/result.json").stat().st_mtime_ns == mtime
    _check_summary(out, 4, 2)


def test_dask_local_cluster(six_cases, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        s = run_batch(
            six_cases, tmp_path / "out", scheduler=cluster.scheduler_address, report=False
        )
    assert s.counts["done"] == 4 and s.counts["failed"] == 2
    _check_summary(tmp_path / "out", 4, 2)


def test_sigkill_mid_run_then_resume(tmp_path):
    cases = _make(tmp_path / "cases", 4)
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "biplanar_reg.cli",
        "batch",
        *map(str, cases),
        "--out",
        str(out),
        "--workers",
        "1",
        "--no-report",
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )

    def done(c: Path) -> bool:
        return is_complete(out / c.name, report=False)

    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(done(c) for c in cases):
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole run: parent and worker
        proc.wait()
    complete = {c.name for c in cases if done(c)}
    assert 1 <= len(complete) < 4, complete
    for c in cases:  # nothing half-written: a case folder is complete or absent
        assert done(c) or not (out / c.name).exists()
    mtimes = {n: (out / n / "result.json").stat().st_mtime_ns for n in complete}
    s = run_batch(cases, out, workers=2, report=False)
    assert s.counts["done"] == 4 and s.counts["failed"] == 0
    assert s.counts["skipped"] == len(complete)  # each case completed exactly once
    assert sum(r["ran"] for r in s.rows) == 4 - len(complete)
    for n, t in mtimes.items():
        assert (out / n / "result.json").stat().st_mtime_ns == t
    _check_summary(out, 4, 0)
    shutil.rmtree(tmp_path / "cases")
