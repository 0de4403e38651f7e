"""``biplanar-reg workbench --new``: ``case.toml`` scaffolded from the model, calibrations and
images (options or the page's form), paths kept inside the case folder, nothing left behind
when refused."""

from __future__ import annotations

import argparse
import re
import shutil
import tomllib
from pathlib import Path

import pytest
from _http import BASE, page_client
from starlette.testclient import TestClient

from biplanar_reg.cases import read_case_setup
from biplanar_reg.cli.workbench import _new_case
from biplanar_reg.workbench.scaffold import (
    NewView,
    candidate_files,
    create_new_case_app,
    parse_view_option,
    scaffold_case,
    view_names,
)

TOKEN = "test-token-0123456789"


@pytest.fixture
def loose(synthetic_case: Path) -> Path:
    """The synthetic case's files without its case.toml (nor annotations, nor landmarks)."""
    (synthetic_case / "case.toml").unlink()
    (synthetic_case / "annotations.json").unlink()
    shutil.move(synthetic_case / "model" / "landmarks.json", synthetic_case / "lm.json")
    return synthetic_case


VIEWS = [NewView("cam1", "calib/cam1.txt", "xray/cam1.png"), NewView("cam2", "calib/cam2.json")]


def test_scaffold_writes_a_case_the_loader_reads(loose):
    setup = scaffold_case(loose, model="model/bone_ssm.npz", views=VIEWS)
    doc = tomllib.loads((loose / "case.toml").read_text())
    assert doc["model"] == {"ssm": "model/bone_ssm.npz", "landmarks": "model/landmarks.json"}
    assert [v["name"] for v in doc["views"]] == ["cam1", "cam2"]
    assert doc["views"][0]["image"] == "xray/cam1.png" and "image" not in doc["views"][1]
    assert doc["registration"]["poses"] == "known"
    assert [v.name for v in setup.views] == ["cam1", "cam2"]
    assert setup.views[0].image is not None and setup.landmarks == {}
    assert setup.annotations_path == loose / "annotations.json"


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"model": "../elsewhere.npz"}, "model"),
        ({"model": "model/missing.npz"}, "model"),
        ({"model": "calib/cam1.txt"}, "model"),
        ({"views": VIEWS[:1]}, "views"),
        ({"views": [VIEWS[0], NewView("cam1", "calib/cam2.json")]}, "views[1].name"),
        ({"views": [VIEWS[0], NewView("cam2", "/etc/passwd")]}, "views[1].calibration"),
        ({"views": [VIEWS[0], NewView("cam 2", "calib/cam2.json")]}, "views[1].name"),
        ({"landmarks": "../lm.json"}, "landmarks"),
        ({"poses": "guess"}, "poses"),
    ],
)
def test_bad_scaffolds_name_the_field_and_write_nothing(loose, kwargs, field):
    args = {"model": "model/bone_ssm.npz", "views": VIEWS, **kwargs}
    with pytest.raises(ValueError, match=rf"^{field.replace('[', '.').replace(']', '.')}"):
        scaffold_case(loose, **args)
    assert not (loose / "case.toml").exists()


def test_a_link_out_of_the_folder_is_refused(loose, tmp_path):
    outside = tmp_path / "outside.txt"
    shutil.copy(loose / "calib" / "cam1.txt", outside)
    (loose / "calib" / "link.txt").symlink_to(outside)
    views = [VIEWS[0], NewView("cam2", "calib/link.txt")]
    with pytest.raises(ValueError, match="outside the case folder"):
        scaffold_case(loose, model="model/bone_ssm.npz", views=views)
    assert not (loose / "case.toml").exists()


def test_an_invalid_file_is_refused_by_the_loader_and_the_toml_removed(loose):
    (loose / "calib" / "bad.txt").write_text("not a calibration\n")
    views = [VIEWS[0], NewView("cam2", "calib/bad.txt")]
    with pytest.raises(ValueError, match="bad.txt"):
        scaffold_case(loose, model="model/bone_ssm.npz", views=views)
    assert not (loose / "case.toml").exists()


def test_an_existing_case_is_not_overwritten(synthetic_case):
    before = (synthetic_case / "case.toml").read_bytes()
    with pytest.raises(ValueError, match="exists already"):
        scaffold_case(synthetic_case, model="model/bone_ssm.npz", views=VIEWS)
    args = argparse.Namespace(case_dir=str(synthetic_case), model=None, view=None,
                              landmarks=None, poses="known")  # fmt: skip
    with pytest.raises(ValueError, match="^--new: .*exists already"):
        _new_case(args)
    assert (synthetic_case / "case.toml").read_bytes() == before


def test_the_cli_options_scaffold_or_leave_it_to_the_form(loose):
    ns = dict(case_dir=str(loose), landmarks="lm.json", poses="unknown")
    assert _new_case(argparse.Namespace(**ns, model="model/bone_ssm.npz", view=None)) is False
    assert not (loose / "case.toml").exists()
    views = ["cam1=calib/cam1.txt,xray/cam1.png", "cam2=calib/cam2.json"]
    assert _new_case(argparse.Namespace(**ns, model="model/bone_ssm.npz", view=views)) is True
    setup = read_case_setup(loose)
    assert setup.poses == "unknown" and len(setup.landmarks) == 8  # lm.json used
    with pytest.raises(ValueError, match="^--view"):
        parse_view_option("cam1")


def test_the_form_lists_the_files_and_creates_the_case(loose):
    (loose / "calib" / "LICENSE.txt").write_text("not a calibration\n")
    found = candidate_files(loose)
    assert "calib/LICENSE.txt" not in found["calibrations"]
    assert "model/bone_ssm.npz" in found["models"] and "gt/bone.ply" in found["models"]
    assert {"calib/cam1.txt", "calib/cam2.json"} <= set(found["calibrations"])
    assert found["images"] == ["xray/cam1.png", "xray/cam2.png"]
    assert found["landmarks"] == ["lm.json"]
    opened = []
    app = create_new_case_app(loose.resolve(), TOKEN, opened.append)
    client = page_client(app, TOKEN)
    assert TestClient(app, base_url=BASE).get("/api/new").status_code == 403
    assert client.get("/").status_code == 200 and TOKEN in client.get("/").text
    assert client.get("/api/new").json()["files"] == found
    # the form names each view after its image (calibration when it has none)
    names = client.get("/api/new").json()["view_names"]
    assert names["xray/cam1.png"] == "cam1" and names["calib/cam2.json"] == "cam2"
    body = {"model": "model/bone_ssm.npz", "views": [{"name": "cam1", "calibration": "x.txt"}]}
    r = client.post("/api/new", json=body)
    assert r.status_code == 400 and r.json()["error"].startswith("views"), r.text
    assert not (loose / "case.toml").exists() and not opened
    body["views"] = [
        {"name": "cam1", "calibration": "calib/cam1.txt", "image": "xray/cam1.png"},
        {"name": "cam2", "calibration": "calib/cam2.json", "image": None},
    ]
    r = client.post("/api/new", json={**body, "landmarks": "lm.json"})
    assert r.status_code == 200 and r.json()["url"] == "/"  # the browser is signed in already
    assert len(opened) == 1 and opened[0].case_dir == loose.resolve()
    assert tomllib.loads((loose / "case.toml").read_text())["model"]["landmarks"] == "lm.json"


def test_view_names_are_the_file_names_sanitised_and_unique():
    names = view_names(["data/cam01 frame#0099.tif", "b/cam01 frame#0099.png", "c/#.tif", "x" * 80])
    assert list(names.values()) == ["cam01_frame_0099", "cam01_frame_0099_2", "view", "x" * 64]
    for name in names.values():
        NewView(name, "calib/cam1.txt")  # each a valid view name
        assert re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", name)
