"""Batch faults (issue 18): worker deaths charged to the right case, workers that die with a
killed batch, and the output-folder lock (a live run is refused, a stale lock is taken over).

The accounting tests replace ``process_case`` with the fake of ``_batch_helpers`` (each case
sleeps, may SIGKILL its own worker); the kill and lock tests run the real ``biplanar-reg batch``
on small synthetic cases.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from _batch_helpers import fake_case, make_fake_cases, probe_outcome_case, runs

from biplanar_reg.cases import batch
from biplanar_reg.cases._lock import LockedError, OutputLock
from biplanar_reg.cases.batch import run_batch
from biplanar_reg.cases.outputs import is_complete
from biplanar_reg.cli import main
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]


def _cases(root: Path, n: int) -> list[Path]:
    return [
        write_synthetic_case(root / f"c{i}", i, image_size=(192, 192), silhouettes=False)
        for i in range(n)
    ]


def _start_batch(cases: list[Path], out: Path, *extra: str) -> subprocess.Popen:
    """``biplanar-reg batch CASES --out OUT --workers 1 [EXTRA]`` in its own session."""
    cmd = [sys.executable, "-m", "biplanar_reg.cli", "batch", *map(str, cases), "--out", str(out)]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    return subprocess.Popen(
        [*cmd, "--workers", "1", *extra],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=env,
    )


def _wait(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _dead_pid() -> int:
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    return int(done.stdout)


# --------------------------------------------------------------------- worker deaths


def test_worker_deaths_are_charged_only_to_the_case_they_ran(tmp_path, monkeypatch):
    # a: its worker dies at once, twice; g: later, twice; d: once, then it succeeds. Before the
    # fix every death broke the whole pool and charged every pending case: healthy cases that
    # never ran ended "the worker process died twice".
    monkeypatch.setattr(batch, "process_case", fake_case)
    specs = {
        "a": {"die": "always"},
        "b": {"sleep": 0.2},
        "c": {"sleep": 0.2},
        "d": {"sleep": 0.4, "die": "once"},
        "e": {"sleep": 0.2},
        "f": {"sleep": 0.2},
        "g": {"sleep": 0.6, "die": "always"},
        "h": {"sleep": 0.2},
    }
    cases = make_fake_cases(tmp_path / "cases", specs)
    s = run_batch(cases, tmp_path / "out", workers=2, progress_stream=io.StringIO())
    rows = {r["case"]: r for r in s.rows}
    assert {n for n, r in rows.items() if r["status"] == "failed"} == {"a", "g"}
    for n in "ag":
        assert "the worker process died twice" in rows[n]["reason"]
        assert "SIGKILL" in rows[n]["reason"]
    assert all(rows[n]["status"] == "done" for n in "bcdefh")
    # healthy cases ran exactly once: none was stopped or re-run because another worker died
    started = Counter(runs(tmp_path / "cases"))
    assert started == {"a": 2, "g": 2, "d": 2, **{n: 1 for n in "bcefh"}}
    assert s.counts == {"total": 8, "done": 6, "failed": 2, "skipped": 0, "missing": 0}


def test_workers_take_the_batchs_off_screen_check(tmp_path, monkeypatch):
    # With reports, the batch checks off-screen rendering once and its workers take the outcome
    # (same environment) instead of each starting the check's child process; without reports
    # nobody checks.
    from biplanar_reg.report import gl_probe

    checks = []

    def checked():
        checks.append(1)
        return gl_probe._key(gl_probe.offscreen_env()), (False, "checked by the batch")

    monkeypatch.setattr(gl_probe, "checked_outcome", checked)
    monkeypatch.setattr(batch, "process_case", probe_outcome_case)
    cases = make_fake_cases(tmp_path / "cases", {n: {} for n in "abcd"})
    run_batch(cases, tmp_path / "out", workers=2, progress_stream=io.StringIO())
    lines = (tmp_path / "cases" / "probe.log").read_text().splitlines()
    assert len(lines) == 4 and len({ln.split()[0] for ln in lines}) == 2  # two workers
    assert all(ln.split(maxsplit=1)[1] == "checked by the batch" for ln in lines), lines
    assert checks == [1]
    (tmp_path / "cases" / "probe.log").unlink()
    run_batch(cases, tmp_path / "out2", workers=2, progress_stream=io.StringIO(), report=False)
    lines = (tmp_path / "cases" / "probe.log").read_text().splitlines()
    assert len(lines) == 4 and all(ln.endswith(" none") for ln in lines), lines
    assert checks == [1]


def test_workers_that_cannot_start_charge_no_case(tmp_path, monkeypatch):
    # The task's module exists in this process only: every worker dies while starting. That is
    # an error of the run, not "died twice" for every case, and the pool does not respawn forever.
    mod = tmp_path / "vanishing_task.py"
    mod.write_text("def task(c, o, a=False):\n    return {}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import vanishing_task

    mod.unlink()
    monkeypatch.setattr(batch, "process_case", vanishing_task.task)
    cases = make_fake_cases(tmp_path / "cases", {"a": {}, "b": {}, "c": {}})
    with pytest.raises(RuntimeError, match="3 worker processes exited while starting"):
        run_batch(cases, tmp_path / "out", workers=3, progress_stream=io.StringIO())
    assert runs(tmp_path / "cases") == []
    assert not list((tmp_path / "out").glob(".batch*.lock"))


# ------------------------------------------------------------- workers die with the batch


def test_workers_die_with_a_killed_batch(tmp_path, caplog):
    # Before the fix the orphaned worker went on with its case and took the next queued one,
    # racing a rerun on the same output folders.
    psutil = pytest.importorskip("psutil")
    cases = _cases(tmp_path / "cases", 2)
    out = tmp_path / "out"
    proc = _start_batch(cases, out, "--no-report")  # the worker's fate is tested, not reports

    def complete_cases() -> set[str]:
        return {c.name for c in cases if is_complete(out / c.name, report=False)}

    try:
        _wait(lambda: bool(complete_cases()))
        workers = psutil.Process(proc.pid).children(recursive=True)
        assert workers
        proc.send_signal(signal.SIGKILL)  # the batch process only, not its process group
        proc.wait()
        _, alive = psutil.wait_procs(workers, timeout=5)
        assert not alive, f"workers outlived the batch: {alive}"
        complete = complete_cases()
        time.sleep(1.0)
        assert complete_cases() == complete
        assert len(complete) == 1
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    # the SIGKILL left its lock behind: stale, taken over by the next run (which the SIGKILL
    # test of test_batch_run.py completes)
    assert json.loads((out / ".batch.lock").read_text())["pid"] == proc.pid
    with caplog.at_level(logging.WARNING, logger="biplanar_reg.cases._lock"):
        with OutputLock(out):
            pass
    assert "taking over the stale lock" in caplog.text and f"pid {proc.pid}" in caplog.text
    assert not (out / ".batch.lock").exists()


# ------------------------------------------------------------------ output-folder lock


def test_a_second_batch_on_a_live_output_folder_is_refused(tmp_path, capsys):
    cases = _cases(tmp_path / "cases", 2)
    out = tmp_path / "out"
    lock = out / ".batch.lock"
    proc = _start_batch(cases, out)
    try:
        _wait(lambda: lock.is_file() and lock.read_text().strip().endswith("}"))
        for extra in ([], ["--shard", "1/2"], ["--force"]):
            capsys.readouterr()
            assert main(["batch", *map(str, cases), "--out", str(out), *extra]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1, err
            assert str(lock) in err[0] and f"pid {proc.pid} on {socket.gethostname()}" in err[0]
            assert "already running" in err[0]
        assert json.loads(lock.read_text())["pid"] == proc.pid  # the live run keeps its lock
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def test_shard_locks_exclude_only_overlapping_runs(tmp_path):
    with OutputLock(tmp_path, (1, 2)):
        with OutputLock(tmp_path, (2, 2)):  # disjoint cases: both run
            pass
        with OutputLock(tmp_path, (2, 4)):  # positions 1, 5, ...: none of shard 1/2's
            pass
        for other in (None, (1, 2), (1, 4), (3, 4), (1, 3)):
            with pytest.raises(LockedError, match=r"\.batch\.shard-1-of-2\.lock"):
                OutputLock(tmp_path, other).acquire()
    assert not list(tmp_path.glob(".batch*"))


def test_stale_and_live_lock_files(tmp_path, caplog):
    lock = tmp_path / ".batch.lock"
    host = socket.gethostname()
    dead = _dead_pid()
    for text in (json.dumps({"pid": dead, "host": host}), f"{dead}@{host}\n", "pid=99999999\n"):
        lock.write_text(text)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="biplanar_reg.cases._lock"):
            with OutputLock(tmp_path):
                assert json.loads(lock.read_text())["pid"] == os.getpid()
        assert "taking over the stale lock" in caplog.text
        assert not lock.exists()
    # a holder that is alive on this host but holds no flock (e.g. another tool): refused
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock.write_text(f"{sleeper.pid}@{host}")
        with pytest.raises(LockedError, match=f"pid {sleeper.pid} on {host}"):
            OutputLock(tmp_path).acquire()
        assert lock.read_text() == f"{sleeper.pid}@{host}"
    finally:
        sleeper.kill()
        sleeper.wait()
