"""``register`` on a shared case: one registration per output folder at a time, an output swap
that survives a crash at any instant, no orphaned temporary files, and a full or read-only
disk reported on one line (exit 2) with the previous output kept.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from biplanar_reg.cases import bone_fit, pipeline
from biplanar_reg.cli import main
from biplanar_reg.errors import SolverFailure
from biplanar_reg.io import atomic as atomic_module
from biplanar_reg.io.atomic import atomic_path
from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> Path:
    """A small synthetic case (no silhouettes: fast) with one complete output ``out``."""
    folder = write_synthetic_case(
        tmp_path_factory.mktemp("safety") / "k1", 1, image_size=(192, 192), silhouettes=False
    )
    assert main(["register", str(folder), "--no-report"]) == 0
    return folder


@pytest.fixture()
def fresh(case, tmp_path) -> Path:
    """A copy of the case (with its output ``out``) that a test may damage."""
    dst = tmp_path / "k1"
    shutil.copytree(case, dst)
    return dst


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _fail_registration(monkeypatch) -> None:
    def fail(*args, **kwargs):
        raise SolverFailure("stopped by the test")

    monkeypatch.setattr(bone_fit, "register_views", fail)


def test_a_second_registration_of_a_busy_output_is_refused(fresh, monkeypatch, capsys):
    """The second run (a terminal, while the workbench's Register is writing) gets one line and
    exit 2, and leaves the first run's temporary folder alone; the first run completes."""
    second: list[int] = []
    real = pipeline.write_pose_exports

    def exports_then_a_second_run(tmp, out, case, poses, vertices):
        # the first run is writing its outputs into its temporary folder: start another one
        second.append(main(["register", str(fresh), "--no-report"]))
        second.append(_err_line(capsys))
        return real(tmp, out, case, poses, vertices)

    monkeypatch.setattr(pipeline, "write_pose_exports", exports_then_a_second_run)
    before = (fresh / "out" / "result.json").read_bytes()
    assert main(["register", str(fresh), "--no-report"]) == 0
    rc, line = second
    assert rc == 2
    assert "another registration is writing this output folder" in line, line
    assert f"pid {os.getpid()}" in line and str(fresh / "out") in line
    assert (fresh / "out" / "result.json").read_bytes() != before  # the first run's output
    assert _hidden(fresh) == []  # its lock file and temporary folder are gone


# a run killed between the two renames of the output swap (a file system without an atomic
# exchange of two folders): the previous output is renamed away, the new one not yet in place
KILLED_SWAP = """
import os, sys
from pathlib import Path
from biplanar_reg.cases import outputs
outputs.exchange_paths = lambda a, b: False  # no atomic exchange: the two-rename swap
real, renames = os.replace, []
def replace(src, dst):
    real(src, dst)
    renames.append(dst)
    if len(renames) == 1:
        os._exit(9)  # killed right after the first rename
os.replace = replace
with outputs.atomic_output_dir(Path(sys.argv[1])) as tmp:
    (tmp / "result.json").write_text("{}")
    (tmp / "registered.ply").write_text("new")
"""


def test_a_kill_between_the_renames_never_loses_the_previous_output(fresh, monkeypatch, capsys):
    out = fresh / "out"
    previous = (out / "result.json").read_bytes()
    proc = subprocess.run([sys.executable, "-c", KILLED_SWAP, str(out)], env=ENV, timeout=60)
    assert proc.returncode == 9
    assert not out.exists()  # the instant the kill left: the previous output renamed away
    # the next run fails (so it writes nothing): the previous output is back, not deleted
    _fail_registration(monkeypatch)
    assert main(["register", str(fresh), "--no-report"]) == 1
    assert (out / "result.json").read_bytes() == previous
    assert _hidden(fresh) == []


def test_the_swap_exchanges_the_folders_where_the_system_can(fresh, monkeypatch):
    if not sys.platform.startswith("linux"):
        pytest.skip("renameat2(RENAME_EXCHANGE) is Linux's")
    from biplanar_reg.cases import outputs

    out = fresh / "out"
    real = os.replace

    def no_rename_of_the_target(src, dst, **kw):
        assert Path(src) != out and Path(dst) != out, "the target was renamed, not exchanged"
        return real(src, dst, **kw)

    monkeypatch.setattr(os, "replace", no_rename_of_the_target)
    with outputs.atomic_output_dir(out) as tmp:
        (tmp / "result.json").write_text('{"new": 1}')
    assert json.loads((out / "result.json").read_text()) == {"new": 1}
    assert not (out / "registered.ply").exists()  # the whole folder was replaced
    assert _hidden(fresh) == []


# an atomic write killed mid-way (SIGKILL): its temporary file stays beside the target
KILLED_WRITE = """
import os, signal, sys
from pathlib import Path
from biplanar_reg.io.atomic import atomic_path
with atomic_path(Path(sys.argv[1])) as tmp:
    tmp.write_text('{"partial')
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_orphaned_temporary_files_are_removed_and_live_ones_kept(fresh):
    for target in (fresh / "annotations.json", fresh / "model" / "landmarks.json"):
        proc = subprocess.run([sys.executable, "-c", KILLED_WRITE, str(target)], env=ENV)
        assert proc.returncode == -signal.SIGKILL
    orphans = sorted(fresh.glob(".annotations.json.*.part.json"))
    orphans += sorted((fresh / "model").glob(".landmarks.json.*.part.json"))
    assert len(orphans) == 2
    landmarks = fresh / "model" / "landmarks.json"
    text = landmarks.read_text()
    with atomic_path(landmarks) as live:  # a save in progress (the workbench) during the run
        live.write_text(text)
        assert main(["register", str(fresh), "--no-report"]) == 0
        assert live.is_file()
    assert not any(p.exists() for p in orphans)
    assert landmarks.read_text() == text
    assert _hidden(fresh) == [] and _hidden(fresh / "model") == []


def _read_only(monkeypatch, folder: Path) -> list[Path]:
    """Make ``folder`` behave as a read-only file system for this process (the tests run as
    root, whom permissions do not stop): creating anything under it fails with EROFS."""
    tried: list[Path] = []
    real_open, real_mkdir = os.open, os.mkdir

    def refuse(path) -> None:
        p = Path(os.fsdecode(path)).absolute()
        if p.is_relative_to(folder):
            tried.append(p)
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(p))

    def ro_open(path, flags, *args, **kwargs):
        if flags & (os.O_CREAT | os.O_WRONLY | os.O_RDWR):
            refuse(path)
        return real_open(path, flags, *args, **kwargs)

    def ro_mkdir(path, *args, **kwargs):
        refuse(path)
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", ro_open)
    monkeypatch.setattr(os, "mkdir", ro_mkdir)
    return tried


def test_a_read_only_output_is_refused_before_the_registration(
    fresh, tmp_path, monkeypatch, capsys
):
    ran: list[int] = []
    real = bone_fit.register_views
    monkeypatch.setattr(bone_fit, "register_views", lambda *a, **k: ran.append(1) or real(*a, **k))
    ro = tmp_path / "ro"
    ro.mkdir()
    tried = _read_only(monkeypatch, ro)
    capsys.readouterr()
    assert main(["register", str(fresh), "--out", str(ro / "out"), "--no-report"]) == 2
    line = _err_line(capsys)
    assert line.startswith(f"error: {ro / 'out'}: ") and "Read-only file system" in line, line
    assert tried and not ran  # refused before the registration ran
    assert not list(ro.iterdir())


def test_a_full_disk_is_one_line_and_keeps_the_previous_output(fresh, monkeypatch, capsys):
    out = fresh / "out"
    previous = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}

    def full(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as fsync reports it

    monkeypatch.setattr(atomic_module, "_fsync_path", full)
    capsys.readouterr()
    assert main(["register", str(fresh), "--no-report"]) == 2
    line = _err_line(capsys)
    assert line.startswith(f"error: {out}: No space left on device"), line
    assert "previous output" in line and "internal error" not in line
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == previous
    assert _hidden(fresh) == []
    # a batch case records the same line as its reason
    from biplanar_reg.cases.batch import process_case

    row = process_case(str(fresh), str(out), False, False)
    assert row["status"] == "failed"
    assert row["reason"].startswith(f"{out}: No space left on device (the output was not"), row
