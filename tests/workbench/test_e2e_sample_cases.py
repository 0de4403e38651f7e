"""Every shipped sample case opens in the workbench with no console error and no failed request;
a case of several bones or frames is refused with one line naming the key (the workbench edits
one bone in one frame)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from _browser import needs_chromium
from test_e2e import _settle, running_workbench

from biplanar_reg.cases import read_case_setup
from biplanar_reg.errors import CaseError

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = sorted(p.parent.name for p in (ROOT / "sample_cases").glob("*/case.toml"))
SEVERAL = {"wrist_radius_ulna": "bones", "wrist_radius_frames": "frames"}
SINGLE = [name for name in SAMPLES if name not in SEVERAL]


@pytest.mark.parametrize("name", sorted(SEVERAL))
def test_a_case_of_several_bones_or_frames_is_refused_with_its_key(name, tmp_path):
    case = Path(shutil.copytree(ROOT / "sample_cases" / name, tmp_path / name))
    with pytest.raises(CaseError, match=rf"case\.toml: \[\[{SEVERAL[name]}\]\]: the workbench"):
        read_case_setup(case)


@needs_chromium
@pytest.mark.parametrize("name", SINGLE)
def test_each_sample_case_opens_without_a_console_error(name, page, tmp_path):
    case = Path(shutil.copytree(ROOT / "sample_cases" / name, tmp_path / name))
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    failed: list[str] = []
    page.on("response", lambda r: failed.append(f"{r.status} {r.url}") if r.status >= 400 else None)
    with running_workbench(case) as url:
        page.goto(url)
        page.wait_for_selector("body[data-ready='true']")
        _settle(page)
        page.keyboard.press("?")  # the shortcut list opens and closes
        page.wait_for_selector("[data-testid=shortcut-list]:not([hidden])")
        page.keyboard.press("Escape")
        _settle(page)
    assert errors == [] and page.errors == [] and failed == [], (errors, page.errors, failed)
