"""The one lock file (``biplanar_reg.io.lock``): what its users share. The users' own messages
and files are tested with them (tests/cases/test_batch_faults.py, tests/workbench/test_session.py).
"""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import time

import pytest

from biplanar_reg.io.lock import LockedError, LockFile, holder_record, probe, try_flock


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_held_lock_refuses_a_second_holder_naming_the_first(tmp_path):
    path = tmp_path / ".x.lock"
    with LockFile(path) as first:
        assert first.held
        record = json.loads(path.read_text())
        assert record["pid"] == os.getpid() and record["host"] == socket.gethostname()
        assert set(record) == set(holder_record())
        with pytest.raises(LockedError, match=f"{path}: locked by pid {os.getpid()} on ") as info:
            LockFile(path).acquire()  # its own flock: refused even in the same process
        assert "\n" not in str(info.value)
        assert probe(path) == (True, record)
    assert not path.exists() and not first.held
    assert probe(path) == (False, {})


def test_update_rewrites_the_record_in_place_and_keeps_the_lock(tmp_path):
    path = tmp_path / ".x.lock"
    lock = LockFile(path, {"pid": os.getpid(), "port": 0})
    lock.update(port=1)  # before acquire: only the record
    assert not path.exists()
    with lock:
        inode = path.stat().st_ino
        lock.update(port=8123)
        assert json.loads(path.read_text()) == {"pid": os.getpid(), "port": 8123}
        assert path.stat().st_ino == inode
        with pytest.raises(LockedError):
            LockFile(path).acquire()


class _Graced(LockFile):
    flock_decides = True
    grace_s = 5.0


def test_a_found_lock_naming_no_holder_is_held_only_within_the_grace(tmp_path):
    path = tmp_path / ".x.lock"
    with _Graced(path):  # a lock file it creates itself is empty for an instant: no refusal
        pass
    path.write_text("")  # someone else's, being written
    with pytest.raises(LockedError, match="locked by pid \\? on \\?"):
        _Graced(path).acquire()
    old = time.time() - 60
    os.utime(path, (old, old))
    with _Graced(path):
        assert json.loads(path.read_text())["pid"] == os.getpid()
    path.write_text("")  # without a grace an empty lock is debris at once
    with LockFile(path):
        pass


def test_a_stale_lock_is_taken_over_with_a_warning_of_the_users_module(tmp_path, caplog):
    path = tmp_path / ".x.lock"
    path.write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname()}))
    with caplog.at_level(logging.WARNING):
        with _Graced(path):
            pass
    (rec,) = [r for r in caplog.records if "taking over the stale lock" in r.getMessage()]
    assert rec.name == __name__ and str(path) in rec.getMessage()


def test_try_flock_shared_and_exclusive(tmp_path):
    path = tmp_path / "f"
    path.write_text("")
    fds = [os.open(path, os.O_RDWR) for _ in range(3)]
    try:
        assert try_flock(fds[0], shared=True) == "held"
        assert try_flock(fds[1], shared=True) == "held"
        assert try_flock(fds[2]) == "busy"
        os.close(fds.pop(0))
        os.close(fds.pop(0))
        assert try_flock(fds[0], wait=True) == "held"
    finally:
        for fd in fds:
            os.close(fd)
