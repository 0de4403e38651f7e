"""``[registration]`` and ``[registration.expert]``: every option in one section, the documented
table in docs/cases.md listing exactly the options, and a one-line error for each misplaced or
removed key naming the file, the key and its place."""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import pytest

from biplanar_reg.cases import CaseError, load_case, registration_options
from biplanar_reg.cases.registration_table import (
    EXPERT_KEYS,
    MODE_KEYS,
    REMOVED_KEYS,
    USER_KEYS,
    USER_OPTIONS,
)
from biplanar_reg.cli import main
from biplanar_reg.registration import RegistrationOptions

ROOT = Path(__file__).resolve().parents[2]
FIELDS = {f.name: f for f in dataclasses.fields(RegistrationOptions)}
#: The defaults of the keys that are not RegistrationOptions fields, as docs/cases.md states them.
MODE_DEFAULTS = {"poses": '"known"', "silhouettes": "true", "start": "none"}
ROW = re.compile(r"^\| `(\w+)` \| `(\[registration(?:\.expert)?\])` \| (\w+) \| (.+?) \| (.+) \|$")


def _doc_rows() -> dict[str, tuple[str, str, str, str]]:
    """``{key: (section, type, default, meaning)}`` of the options table of docs/cases.md."""
    text = (ROOT / "docs" / "cases.md").read_text(encoding="utf-8")
    table = text[text.index("### Registration options") :]
    table = table[: table.index("\n### ")]
    rows: dict[str, tuple[str, str, str, str]] = {}
    for line in table.splitlines():
        m = ROW.match(line)
        if m:
            assert m.group(1) not in rows, f"{m.group(1)} listed twice"
            rows[m.group(1)] = m.group(2, 3, 4, 5)
    return rows


def _doc_default(value: object) -> str:
    """A field default as the table writes it (TOML spelling in backticks)."""
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    return f"`{value}`" if isinstance(value, int) else f"`{value!r}`"


def test_the_docs_table_lists_exactly_the_options_with_section_type_and_default():
    rows = _doc_rows()
    assert set(rows) == {*FIELDS, *MODE_KEYS}
    for key, (section, kind, default, meaning) in rows.items():
        assert section == ("[registration]" if key in USER_KEYS else "[registration.expert]"), key
        assert meaning.strip(), key
        if key in MODE_KEYS:
            assert default.strip("`") == MODE_DEFAULTS[key], key
            continue
        value = FIELDS[key].default
        assert kind == {"str": "string"}.get(type(value).__name__, type(value).__name__), key
        if isinstance(value, float):  # written with a decimal point, so TOML reads a float
            assert "." in default and float(default.strip("`")) == value, key
        else:
            assert default == _doc_default(value), key


def test_the_sections_split_the_options():
    assert set(USER_OPTIONS) | set(EXPERT_KEYS) == set(FIELDS)
    assert not set(USER_OPTIONS) & set(EXPERT_KEYS)
    assert len(USER_KEYS) <= 10  # the keys a user holds in mind
    assert not set(REMOVED_KEYS) & set(FIELDS)


# -- case files ----------------------------------------------------------------------------------


@pytest.fixture()
def case(tmp_path) -> Path:
    dst = tmp_path / "case"
    shutil.copytree(ROOT / "sample_cases" / "synthetic_demo", dst)
    return dst


def _set(case: Path, registration: str = "", expert: str = "") -> None:
    """Add keys to ``[registration]`` and a ``[registration.expert]`` table to case.toml."""
    p = case / "case.toml"
    text = p.read_text(encoding="utf-8")
    assert "[registration]\n" in text
    text = text.replace("[registration]\n", "[registration]\n" + registration, 1)
    if expert:
        text += "\n[registration.expert]\n" + expert
    p.write_text(text, encoding="utf-8")


def _error(case: Path) -> str:
    with pytest.raises(CaseError) as info:
        load_case(case)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1, msg
    return msg


def test_both_sections_set_their_options(case):
    _set(case, 'noise = "stated"\ncontour_sigma_px = 2\n', "gate_px = 20.0\nmutual = true\n")
    c = load_case(case)
    assert c.warnings == []
    assert (c.options.noise, c.options.contour_sigma_px) == ("stated", 2.0)
    assert (c.options.gate_px, c.options.mutual) == (20.0, True)


@pytest.mark.parametrize("key", ["gate_px", "max_iterations", "eps", "gp_kernel"])
def test_an_old_flat_key_names_its_place_in_expert(case, key):
    value = '"gaussian"' if key == "gp_kernel" else "1"
    _set(case, f"{key} = {value}\n")
    msg = _error(case)
    assert msg.endswith(f"case.toml: [registration] {key}: moved to [registration.expert] {key}")
    assert msg.startswith(str(case.resolve()))


@pytest.mark.parametrize("key", ["robust", "noise", "poses", "start"])
def test_a_user_key_in_expert_names_its_place(case, key):
    _set(case, expert=f"{key} = true\n")
    msg = _error(case)
    assert msg.endswith(f"case.toml: [registration.expert] {key}: moved to [registration] {key}")


@pytest.mark.parametrize("section", ["registration", "expert"])
@pytest.mark.parametrize("key", sorted(REMOVED_KEYS))
def test_a_removed_spelling_names_its_replacement(case, key, section):
    where = {"registration": "[registration]", "expert": "[registration.expert]"}[section]
    if section == "registration":
        _set(case, f"{key} = 0.5\n")
    else:
        _set(case, expert=f"{key} = 0.5\n")
    msg = _error(case)
    new = REMOVED_KEYS[key][1]
    assert msg.endswith(
        f"case.toml: {where} {key}: {REMOVED_KEYS[key][0]}: use [registration.expert] {new}"
    ), msg
    assert new in FIELDS


def test_certificate_flag_was_renamed(case):
    _set(case, "certificate_flag = 0.5\n")
    assert _error(case).endswith(
        "case.toml: [registration] certificate_flag: was renamed in 0.2.0: use "
        "[registration.expert] start_certificate"
    )


def test_expert_must_be_a_table(case):
    _set(case, "expert = 3\n")
    assert _error(case).endswith("case.toml: [registration.expert]: expected a table, got int")


def test_a_bad_expert_value_names_its_section(case):
    _set(case, expert="silhouette_points = 2\n")
    assert "case.toml: [registration.expert]: silhouette_points: too small" in _error(case)


def test_register_exits_2_with_the_one_line_error(case, tmp_path, capsys):
    _set(case, "gate_px = 20.0\n")
    assert main(["register", str(case), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("moved to [registration.expert] gate_px"), err
    assert not (tmp_path / "out").exists()


def test_a_bone_override_in_the_wrong_section_names_the_bone(tmp_path):
    case = tmp_path / "bones"
    shutil.copytree(ROOT / "sample_cases" / "wrist_radius_ulna", case)
    p = case / "case.toml"
    text = p.read_text(encoding="utf-8")
    assert 'name = "ulna"\n' in text
    p.write_text(text.replace('name = "ulna"\n', 'name = "ulna"\nregistration = {tol = 1e-3}\n'))
    msg = _error(case)
    assert msg.endswith("(ulna) [registration] tol: moved to [registration.expert] tol"), msg
    p.write_text(
        text.replace('name = "ulna"\n', 'name = "ulna"\nregistration = {expert = {tol = 1e-3}}\n')
    )
    c = load_case(case)
    assert [b.options.tol for b in c.bones] == [1e-4, 1e-3]


def test_registration_options_reads_both_sections():
    opts = registration_options({"robust": False, "expert": {"gate_px": 9.0}})
    assert opts == RegistrationOptions(robust=False, gate_px=9.0)
    with pytest.raises(CaseError, match=r"\[registration\] gate_px: moved to"):
        registration_options({"gate_px": 9.0})


def test_a_result_json_of_0_1_with_the_removed_options_still_reads(case, tmp_path):
    """0.1 recorded the removed options (``null``) in ``result.json``: the batch summary and
    the workbench's result view read such a file as before."""
    import json

    from biplanar_reg.cases import run_case_dir
    from biplanar_reg.cases.batch import read_record
    from biplanar_reg.workbench.jobs import review

    out = tmp_path / "out"
    run_case_dir(case, out, report=False)
    doc = json.loads((out / "result.json").read_text(encoding="utf-8"))
    options = doc["registration"]["options"]
    assert not set(REMOVED_KEYS) & set(options)
    options.update(dict.fromkeys(REMOVED_KEYS))
    (out / "result.json").write_text(json.dumps(doc), encoding="utf-8")
    row = read_record("demo", out, "done", None)
    assert row["certificate"] == doc["certificate"] and row["flags"] == "; ".join(doc["flags"])
    c = load_case(case)
    page = review(c.views, c.landmarks, out)
    assert set(page["views"]) == {v.name for v in c.views} and page["flags"] == doc["flags"]
