"""Bad input that registered anyway or never finished: a template too large to register in
reasonable time and memory, too many views, templates with a broken surface (several pieces,
open, duplicated or inward faces) and views that see the bone from one point.

Each check is at loading: a one-line case error naming the file and key (exit 2, nothing
written), or a fix with a warning recorded in ``result.json["warnings"]``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.cases import CaseError, load_case, views_section
from biplanar_reg.cases import case as case_module
from biplanar_reg.cli import main
from biplanar_reg.io import read_mesh, write_mesh
from biplanar_reg.simulate import write_synthetic_case
from biplanar_reg.ssm.surface import signed_volume


@pytest.fixture(scope="module")
def base_case(tmp_path_factory) -> Path:
    return write_synthetic_case(
        tmp_path_factory.mktemp("base") / "case0", 0, image_size=(256, 256), silhouettes=False
    )


@pytest.fixture()
def case(base_case, tmp_path) -> Path:
    dst = tmp_path / "case"
    shutil.copytree(base_case, dst)
    return dst


def _edit_toml(case: Path, old: str, new: str) -> None:
    p = case / "case.toml"
    text = p.read_text()
    assert old in text, old
    p.write_text(text.replace(old, new, 1))


def _use_template(case: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Make ``case`` use ``gt/template.ply`` (vertices, faces) as its ``[model] template``."""
    write_mesh(case / "gt/template.ply", vertices, faces)
    _edit_toml(case, 'ssm = "model/bone_ssm.npz"', 'template = "gt/template.ply"')


def _one_line_error(case: Path, capsys) -> str:
    """Run ``register`` on ``case``; assert exit 2, one line, no output; return the line."""
    rc = main(["register", str(case)])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"error: {case.resolve() / 'case.toml'}: "), err
    assert not (case / "out").exists() and not list(case.glob(".out.*"))
    return err


def _subdivided(vertices: np.ndarray, faces: np.ndarray, times: int):
    """Midpoint subdivision (each triangle into 4; the original vertices keep their indices)."""
    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    for _ in range(times):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mid = len(v) + inv.reshape(3, -1).T  # (F, 3): midpoints of edges 01, 12, 20
        v = np.vstack([v, v[uniq].mean(axis=1)])
        a, b, c = f.T
        ab, bc, ca = mid.T
        f = np.concatenate(
            [np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]]
        )
    return v, f


# -- size ------------------------------------------------------------------------------------


def test_a_template_above_the_size_limit_is_refused_before_any_work(case, capsys, monkeypatch):
    """Reproducer: a 5M-face template (a raw CT mesh) took 6 min 46 s and 15.3 GB with no
    message. Above the documented limit the case is refused at once, with the memory and time
    it would take and what to do."""
    import biplanar_reg.ssm as ssm

    def never(*args, **kwargs):  # the population is not synthesised for a refused template
        raise AssertionError("the template was used")

    monkeypatch.setattr(ssm, "synthesise_population", never)
    V, F = read_mesh(case / "gt/bone.ply")
    V4, F4 = _subdivided(V, F, 4)  # 245,760 faces
    assert len(F4) > case_module.MAX_TEMPLATE_FACES
    _use_template(case, V4, F4)
    err = _one_line_error(case, capsys)
    assert "[model] template: template.ply: 245,760 faces (122,882 vertices)" in err, err
    assert f"at most {case_module.MAX_TEMPLATE_FACES:,} faces" in err
    assert "GB" in err and "decimate" in err and "landmark" in err


def test_the_size_limit_is_documented_with_its_measurement():
    text = (Path(__file__).resolve().parents[2] / "docs/cases.md").read_text()
    assert f"{case_module.MAX_TEMPLATE_FACES:,} faces" in text
    assert f"{case_module.MAX_VIEWS:,} views" in text


def test_too_many_views_are_refused_before_the_calibrations_are_read(case, capsys, monkeypatch):
    """Reproducer: 10,000 ``[[views]]`` never finished."""
    calls = []
    real = views_section.load_calibration
    monkeypatch.setattr(
        views_section, "load_calibration", lambda *a, **k: calls.append(a) or real(*a, **k)
    )
    n = case_module.MAX_VIEWS + 1
    extra = "".join(
        f'\n[[views]]\nname = "x{i}"\ncalibration = "calib/cam2.json"\n' for i in range(n - 2)
    )
    _edit_toml(case, "[annotations]", extra + "\n[annotations]")
    err = _one_line_error(case, capsys)
    assert f"[[views]]: {n} views; at most {case_module.MAX_VIEWS} are registered" in err, err
    assert calls == []


# -- surface defects -------------------------------------------------------------------------


def test_a_clean_template_gives_no_warning(case):
    V, F = read_mesh(case / "gt/bone.ply")
    _use_template(case, V, F)
    assert load_case(case).warnings == []


def test_a_template_in_several_pieces_is_refused(case, capsys):
    """Reproducer: a two-piece template registered with exit 0; the second piece is carried
    into registered.ply and dominates the surface metrics (measured: surface RMS 1.8-27 mm
    against 0.12-0.18 mm for the bone alone)."""
    V, F = read_mesh(case / "gt/bone.ply")
    V2 = np.vstack([V, V[:100] + [60.0, 0.0, 0.0]])
    far = F[np.all(F < 100, axis=1)] + len(V)  # the faces among the first 100 vertices, moved
    _use_template(case, V2, np.vstack([F, far]))
    err = _one_line_error(case, capsys)
    assert "[model] template: template.ply: 2 separate pieces (482 and 100 vertices" in err, err
    assert "one bone's surface" in err


def test_duplicated_faces_are_removed_with_a_warning(case):
    V, F = read_mesh(case / "gt/bone.ply")
    _use_template(case, V, np.vstack([F, F[:10, ::-1], F[5:7]]))
    c = load_case(case)
    assert len(c.model.faces) == len(F)
    np.testing.assert_array_equal(np.sort(np.sort(c.model.faces, 1), 0), np.sort(np.sort(F, 1), 0))
    (w,) = c.warnings
    assert "[model] template: template.ply: 12 duplicated faces removed" in w, w


def test_an_inward_template_is_flipped_with_a_warning(case):
    V, F = read_mesh(case / "gt/bone.ply")
    assert signed_volume(V, F) > 0
    _use_template(case, V, F[:, ::-1])
    c = load_case(case)
    assert signed_volume(c.model.mean, c.model.faces) > 0
    (w,) = c.warnings
    assert "[model] template: template.ply: the faces point inward; flipped" in w, w


def test_inconsistent_winding_is_made_consistent_and_outward(case):
    V, F = read_mesh(case / "gt/bone.ply")
    G = F.copy()
    G[::3] = G[::3, ::-1]  # every third face wound the other way
    _use_template(case, V, G)
    c = load_case(case)
    np.testing.assert_array_equal(c.model.faces, F)  # each face back to its outward winding
    (w,) = c.warnings
    assert f"{len(F[::3])} of {len(F)} faces re-wound to point outward like their neighbours" in w


def test_an_open_template_registers_with_a_warning_in_result_json(case):
    V, F = read_mesh(case / "gt/bone.ply")
    tip = V[np.argmax(V[:, 2])]
    d = np.linalg.norm(V[F].mean(axis=1) - tip, axis=1)
    kept = F[d > np.quantile(d, 0.05)]  # a hole at one end
    _use_template(case, V, kept)
    c = load_case(case)
    (w,) = c.warnings
    assert "[model] template: template.ply: the surface is open (" in w, w
    assert "boundary edges" in w
    assert main(["register", str(case), "--no-report"]) == 0
    doc = json.loads((case / "out/result.json").read_text())
    assert any("the surface is open" in x for x in doc["warnings"])


# -- views -----------------------------------------------------------------------------------


def test_identical_views_say_so_instead_of_behind_the_source(case, capsys):
    """Reproducer: two views with the same calibration failed with "X: point(s) [0] lie behind
    the source of view 'cam1'"."""
    shutil.copy(case / "calib/cam1.txt", case / "calib/cam2.txt")
    _edit_toml(case, 'calibration = "calib/cam2.json"', 'calibration = "calib/cam2.txt"')
    err = _one_line_error(case, capsys)
    assert "[[views]][1] (cam2) calibration: calib/cam2.txt: the same source position as cam1" in (
        err
    ), err
    assert "behind the source" not in err and "depth" in err


def test_a_duplicated_view_beside_distinct_ones_is_a_warning(case):
    _edit_toml(
        case,
        "[annotations]",
        '[[views]]\nname = "cam3"\ncalibration = "calib/cam2.json"\n\n[annotations]',
    )
    c = load_case(case)
    (w,) = c.warnings
    assert "[[views]][2] (cam3) calibration: calib/cam2.json: the same source position as cam2" in w


def test_a_same_source_check_raises_case_error_through_load_case(case):
    shutil.copy(case / "calib/cam1.txt", case / "calib/cam2.txt")
    _edit_toml(case, 'calibration = "calib/cam2.json"', 'calibration = "calib/cam2.txt"')
    with pytest.raises(CaseError, match="the same source position as cam1"):
        load_case(case)


def test_nearly_parallel_landmark_rays_meeting_behind_a_source_say_why(tmp_path, capsys):
    """Reproducer: views 0.5 deg apart, different landmarks clicked in each, failed with
    "[registration]: X: point(s) [0] lie behind the source of view 'cam1'"."""
    from biplanar_reg.simulate.scenes import look_at_view

    a = np.deg2rad(0.5) / 2
    views = [
        look_at_view(
            900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]),
            sdd=1200.0,
            pixel=0.6,
            image_size=(256, 256),
            name=name,
        )
        for sx, name in ((-1.0, "cam1"), (1.0, "cam2"))
    ]
    case = write_synthetic_case(
        tmp_path / "c", 0, views=views, landmark_noise_px=1.0, silhouettes=False
    )
    doc = json.loads((case / "annotations.json").read_text())
    for cam, keep in (("cam1", slice(0, 4)), ("cam2", slice(4, 8))):
        marks = doc["views"][cam]["landmarks"]
        doc["views"][cam]["landmarks"] = dict(list(marks.items())[keep])
    (case / "annotations.json").write_text(json.dumps(doc))
    err = _one_line_error(case, capsys)
    assert "[annotations] file: annotations.json: the landmark rays meet behind the source of " in (
        err
    ), err
    assert "nearly parallel (cam1/cam2: central rays 0.5 deg apart)" in err, err
    assert "X: point" not in err
