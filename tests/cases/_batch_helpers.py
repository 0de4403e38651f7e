"""A stand-in for ``batch.process_case`` in the batch fault tests (importable by spawn workers).

A fake case is a folder with ``behaviour.json``: ``{"sleep": seconds, "die": "always" | "once"}``.
Every start of a case is appended to ``<parent>/runs.log`` (one line: the case name); a case
that dies kills its own worker process with SIGKILL after sleeping.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path


def fake_case(case_dir: str, out_dir: str, allow_outside: bool = False) -> dict:
    """Behave as ``behaviour.json`` says; return a ``done`` row like ``process_case``."""
    folder = Path(case_dir)
    spec = json.loads((folder / "behaviour.json").read_text())
    with open(folder.parent / "runs.log", "a", encoding="utf-8") as fh:
        fh.write(folder.name + "\n")
    time.sleep(spec.get("sleep", 0.0))
    die = spec.get("die")
    if die == "always" or (die == "once" and not (folder / "died").exists()):
        (folder / "died").touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return {"case": folder.name, "status": "done", "reason": "", "seconds": spec.get("sleep", 0)}


def make_fake_cases(root: Path, specs: dict[str, dict]) -> list[Path]:
    """One fake case folder per ``name: behaviour`` under ``root``, in the order given."""
    root.mkdir(parents=True, exist_ok=True)
    cases = []
    for name, spec in specs.items():
        (root / name).mkdir()
        (root / name / "behaviour.json").write_text(json.dumps(spec))
        cases.append(root / name)
    return cases


def runs(root: Path) -> list[str]:
    """The case starts logged under ``root``, in order."""
    log = root / "runs.log"
    return log.read_text().split() if log.exists() else []


def probe_outcome_case(
    case_dir: str, out_dir: str, allow_outside: bool = False, report: bool = True
) -> dict:
    """Record in ``<parent>/probe.log`` the off-screen check's outcome this worker knows without
    starting a check of its own (``none`` if it knows none); return a ``done`` row."""
    from biplanar_reg.report import gl_probe

    key = gl_probe._key(gl_probe.offscreen_env())
    known = gl_probe._cache.get(key)
    with open(Path(case_dir).parent / "probe.log", "a", encoding="utf-8") as fh:
        fh.write(f"{os.getpid()} {known[1] if known else 'none'}\n")
    time.sleep(0.2)  # both workers get a case
    return {"case": Path(case_dir).name, "status": "done", "reason": "", "seconds": 0.2}
