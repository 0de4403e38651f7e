"""Case loading: the case format, unit conversion, and the broken-case corpus (one-line errors,
exit code 2 or 1, no output written)."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from biplanar_reg.cases import CaseError, load_case, to_view_observations
from biplanar_reg.cli import main
from biplanar_reg.io import read_mesh, write_mesh
from biplanar_reg.simulate import write_synthetic_case
from biplanar_reg.ssm import ShapeModel


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


def _add_expert(case: Path, keys: str) -> None:
    """Append a ``[registration.expert]`` table with ``keys`` to the case's case.toml."""
    p = case / "case.toml"
    p.write_text(p.read_text() + "\n[registration.expert]\n" + keys + "\n")


def _edit_json(path: Path, fn) -> None:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def test_load_synthetic_case(case):
    c = load_case(case)
    assert c.id == "case0"  # id from case.toml
    assert [v.name for v in c.views] == ["cam1", "cam2"]
    assert [v.calibration_format for v in c.views] == ["mayacam2", "json"]
    assert c.views[0].image_size == (256, 256)
    assert c.model.n_vertices == 482 and len(c.landmarks) == 8
    assert c.ground_truth is not None and len(c.ground_truth.vertices) == 482
    obs = to_view_observations(c)
    assert [len(o.landmark_ids) for o in obs] == [8, 8]
    assert all(len(o.contours) == 1 for o in obs)
    assert c.warnings == []


def test_units_m_converts_to_mm(case):
    ref = load_case(case)
    # rewrite every length file in metres
    m = ShapeModel.load(case / "model/bone_ssm.npz")
    ShapeModel(
        m.mean / 1000,
        m.modes / 1000,
        faces=m.faces,
        variances=m.variances / 1e6,
        landmarks=m.landmarks,
    ).save(case / "model/bone_ssm.npz")
    V, F = read_mesh(case / "gt/bone.ply")
    write_mesh(case / "gt/bone.ply", V / 1000, F)
    _edit_json(case / "calib/cam2.json", lambda d: d.update(t=[x / 1000 for x in d["t"]]))
    lines = (case / "calib/cam1.txt").read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.lower().startswith("translation"))
    for k in range(i + 1, i + 4):  # MayaCam 2.0: one translation component per line
        lines[k] = str(float(lines[k]) / 1000)
    (case / "calib/cam1.txt").write_text("\n".join(lines) + "\n")
    _edit_toml(case, 'units = "mm"', 'units = "m"')
    c = load_case(case)
    assert c.units == "m"
    np.testing.assert_allclose(c.model.mean, ref.model.mean, atol=1e-9)
    np.testing.assert_allclose(c.ground_truth.vertices, ref.ground_truth.vertices, atol=1e-9)
    for a, b in zip(c.views, ref.views, strict=True):
        np.testing.assert_allclose(a.view.t, b.view.t, atol=1e-6)
        X = ref.model.mean[:5]
        np.testing.assert_allclose(a.view.project(X), b.view.project(X), atol=1e-6)


def test_unknown_keys_warn(case, caplog):
    _edit_toml(case, "[registration]", "colour = 'red'\n[registration]\nfoo = 1")
    _add_expert(case, "max_iterations = 3\nbar = 2")
    with caplog.at_level(logging.WARNING):
        c = load_case(case)
    assert c.options.max_iterations == 3
    assert any("'foo'" in w for w in c.warnings) and any("'colour'" in w for w in c.warnings)
    assert any("[registration.expert]: unknown key 'bar' ignored" in w for w in c.warnings)


def test_allow_outside(case, tmp_path):
    shutil.move(case / "gt", tmp_path / "gt_outside")
    _edit_toml(case, 'mesh = "gt/bone.ply"', 'mesh = "../gt_outside/bone.ply"')
    with pytest.raises(CaseError, match="outside the case folder"):
        load_case(case)
    assert load_case(case, allow_outside=True).ground_truth is not None


def _nan_annotation(case):
    text = (case / "annotations.json").read_text()
    i = text.index('"uv": [') + len('"uv": [')
    (case / "annotations.json").write_text(text[:i] + "NaN, " + text[text.index(",", i) + 1 :])


def _empty_annotations(case):
    _edit_json(
        case / "annotations.json",
        lambda d: d.update(views={k: {"landmarks": {}, "contours": []} for k in d["views"]}),
    )


def _unknown_view(case):
    _edit_json(case / "annotations.json", lambda d: d["views"].update(cam9={"landmarks": {}}))


def _unknown_landmark(case):
    _edit_json(
        case / "annotations.json",
        lambda d: d["views"]["cam1"]["landmarks"].update(bogus={"uv": [10.0, 10.0]}),
    )


# (name, edit, expected fragment of the one-line message)
CORPUS = [
    ("missing case.toml", lambda c: (c / "case.toml").unlink(), "case.toml: file not found"),
    (
        "missing calibration",
        lambda c: (c / "calib/cam1.txt").unlink(),
        "calibration: calib/cam1.txt: file not found",
    ),
    ("missing model", lambda c: (c / "model/bone_ssm.npz").unlink(), "[model] ssm"),
    ("wrong case format tag", lambda c: _edit_toml(c, "case@1", "case@2"), "format: expected"),
    (
        "wrong calibration format tag",
        lambda c: _edit_toml(c, 'calibration_format = "mayacam2"', 'calibration_format = "maya"'),
        "calibration_format: unknown format 'maya'",
    ),
    (
        "calibration of the wrong format",
        lambda c: _edit_toml(c, 'calibration_format = "mayacam2"', 'calibration_format = "json"'),
        "[[views]][0] (cam1) calibration",
    ),
    (
        "wrong annotation format tag",
        lambda c: _edit_json(c / "annotations.json", lambda d: d.update(format="x@1")),
        "format: expected 'biplanar-reg/annotations@1'",
    ),
    ("unknown view", _unknown_view, "views.cam9: unknown view"),
    (
        "landmark not in the model",
        _unknown_landmark,
        "views.cam1.landmarks.bogus: unknown landmark",
    ),
    (
        "NaN in annotations",
        _nan_annotation,
        "views.cam1.landmarks.distal_tip.uv: coordinates must be finite numbers, got [NaN,",
    ),
    ("empty annotations", _empty_annotations, "0 landmark observation(s)"),
    (
        "contradicting units",
        lambda c: _edit_toml(c, 'units = "mm"', 'units = "m"'),
        "units: the model is",
    ),
    (
        "unsupported units",
        lambda c: _edit_toml(c, 'units = "mm"', 'units = "cm"'),
        "units: expected one of",
    ),
    (
        "path escaping the folder",
        lambda c: _edit_toml(c, 'file = "annotations.json"', 'file = "../../etc/passwd"'),
        "points outside the case folder",
    ),
    (
        "landmark index out of range",
        lambda c: (c / "model/landmarks.json").write_text('{"distal_tip": 99999}'),
        "expected a vertex index in 0..481",
    ),
    (
        "both ssm and template",
        lambda c: _edit_toml(c, "[model]", '[model]\ntemplate = "gt/bone.ply"'),
        "exactly one of 'ssm' and 'template'",
    ),
    (
        "bad option type",
        lambda c: _add_expert(c, "gate_px = 'x'"),
        "[registration.expert] gate_px: expected a finite float",
    ),
    (
        "unsupported poses",
        lambda c: _edit_toml(c, 'poses = "known"', 'poses = "guess"'),
        "[registration] poses",
    ),
]


@pytest.mark.parametrize(("name", "edit", "fragment"), CORPUS, ids=[c[0] for c in CORPUS])
def test_broken_case_corpus(case, capsys, name, edit, fragment):
    edit(case)
    rc = main(["register", str(case)])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    line = err.splitlines()
    assert len(line) == 1, err  # one line
    assert line[0].startswith("error: ") and fragment in line[0], line[0]
    assert not (case / "out").exists()
    assert not list(case.glob(".out.*"))  # no temporary folder either


def test_solver_failure_exit_1_no_output(case, capsys, monkeypatch):
    # No case input found makes the convex solver fail for real (it flags instead), so the
    # failure is injected where the solver reports it.
    from biplanar_reg.cases import bone_fit
    from biplanar_reg.registration import SolverFailure

    def fail(*args, **kwargs):
        raise SolverFailure("SDP interior-point solver did not converge (injected)")

    monkeypatch.setattr(bone_fit, "register_views", fail)
    rc = main(["register", str(case)])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert len(err.splitlines()) == 1 and "registration failed" in err
    assert not (case / "out").exists() and not list(case.glob(".out.*"))


def test_unknown_poses_is_a_case_error(case, capsys):
    # "unknown" is a valid case value; a registration version without it rejects it cleanly
    _edit_toml(case, 'poses = "known"', 'poses = "unknown"')
    rc = main(["register", str(case), "--no-report"])
    err = capsys.readouterr().err
    if rc == 2:
        assert "[registration]" in err and len(err.strip().splitlines()) == 1
        assert not (case / "out").exists()
    else:  # the solver supports unknown poses: it must then succeed completely
        assert rc == 0 and (case / "out/result.json").is_file()


def test_template_route_builds_a_model(case):
    _edit_toml(
        case,
        'ssm = "model/bone_ssm.npz"',
        'template = "gt/bone.ply"\npopulation_size = 5\npopulation_seed = 3',
    )
    c = load_case(case)
    assert c.model.n_vertices == 482 and 1 <= c.model.n_modes <= 4
    assert c.model_source["population_size"] == 5 and c.model_source["ssm_variance"] == 0.98
    again = load_case(case)  # seeded: the same model
    np.testing.assert_array_equal(again.model.modes, c.model.modes)


def test_read_case_views_is_the_light_reading_of_the_same_format(case, tmp_path):
    from biplanar_reg.cases import read_case_views

    views, ann = read_case_views(case)
    full = load_case(case)
    assert [n for n, _ in views] == [v.name for v in full.views]
    assert [p for _, p in views] == [v.image_path for v in full.views]
    assert ann == full.annotations_path
    # a case being set up: no model, no calibration files, an image outside the folder
    partial = tmp_path / "partial"
    partial.mkdir()
    image = views[0][1]
    (partial / "a.json").write_text("{}")
    (partial / "case.toml").write_text(
        f'[[views]]\nname = "cam1"\nimage = "{image}"\ncalibration = "none.txt"\n'
        '[[views]]\nname = "cam2"\n[annotations]\nfile = "a.json"\n'
    )
    views, ann = read_case_views(partial)
    assert views == [("cam1", image), ("cam2", None)] and ann == (partial / "a.json").resolve()
    # the same rules and messages as load_case
    _edit_toml(partial, 'name = "cam2"', 'name = "cam1"')
    with pytest.raises(CaseError, match=r"\[\[views\]\]\[1\] \(cam1\) name: duplicate view name"):
        read_case_views(partial)
    with pytest.raises(CaseError, match="outside the case folder"):
        read_case_views(partial, allow_outside=False)
    (partial / "a.json").unlink()
    _edit_toml(partial, 'name = "cam1"\n[annotations]', 'name = "cam2"\n[annotations]')
    with pytest.raises(CaseError, match=r"\[annotations\] file: a.json: file not found"):
        read_case_views(partial)


# -- issue 18: input errors that gave a traceback or a vague message ---------------------------


def _one_line_error(case: Path, capsys) -> str:
    """Run ``register`` on ``case``; assert exit 2, one line, no output; return the line."""
    rc = main(["register", str(case)])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"error: {case.resolve() / 'case.toml'}: "), err
    assert not (case / "out").exists() and not list(case.glob(".out.*"))
    return err


def test_a_symlink_loop_in_a_case_path_is_a_case_error(case, capsys):
    """Reproducer: ``Path.resolve()`` raised ``RuntimeError: Symlink loop`` (a traceback)."""
    (case / "calib/loop.txt").symlink_to("loop.txt")
    _edit_toml(case, 'calibration = "calib/cam1.txt"', 'calibration = "calib/loop.txt"')
    err = _one_line_error(case, capsys)
    assert "[[views]][0] (cam1) calibration: 'calib/loop.txt': symlink loop" in err


def test_a_symlink_loop_as_the_case_folder_is_a_case_error(tmp_path):
    (tmp_path / "loop").symlink_to("loop")
    with pytest.raises(CaseError, match=r"loop: symlink loop"):
        load_case(tmp_path / "loop")


def test_a_single_view_case_says_it_needs_two_views(case, capsys):
    """Reproducer: a case with one view failed inside the solver ("point(s) [0] lie behind the
    source") or gave a meaningless result; one view leaves the depth along its rays open."""
    text = (case / "case.toml").read_text()
    start, end = text.index('[[views]]\nname = "cam2"'), text.index("[annotations]")
    (case / "case.toml").write_text(text[:start] + text[end:])
    _edit_json(case / "annotations.json", lambda d: d["views"].pop("cam2"))
    err = _one_line_error(case, capsys)
    assert "[[views]]: 1 view (cam1); a biplanar registration needs at least 2 views" in err


def test_landmarks_in_one_view_only_say_two_views_are_needed(case, capsys):
    """Without outlines; with outlines a start is searched on them (the next test)."""

    def one_view(d):
        d["views"]["cam2"].update(landmarks={})
        for v in d["views"].values():
            v["contours"] = []

    _edit_json(case / "annotations.json", one_view)
    err = _one_line_error(case, capsys)
    assert "[annotations] file: annotations.json: landmarks in 1 view (cam1)" in err
    assert "at least 2 views" in err


def test_landmarks_in_one_view_with_outlines_load(case):
    _edit_json(case / "annotations.json", lambda d: d["views"]["cam2"].update(landmarks={}))
    loaded = load_case(case)
    assert not loaded.annotations.views["cam2"].landmarks


def test_a_degenerate_template_face_is_named_not_a_landmark_range_error(case, capsys):
    """Reproducer: an STL template with two corners at one position (merged into one vertex:
    faces repeating a vertex, fewer vertices) was reported as "landmark ... expected a vertex
    index in 0..480"."""
    V, F = read_mesh(case / "gt/bone.ply")
    V = V.copy()
    V[F[0, 1]] = V[F[0, 0]]
    write_mesh(case / "gt/template.stl", V, F)
    _edit_toml(case, 'ssm = "model/bone_ssm.npz"', 'template = "gt/template.stl"')
    err = _one_line_error(case, capsys)
    assert "[model] template: template.stl: face 0 is degenerate" in err
    assert "landmark" not in err


def test_a_typo_in_a_key_warns_with_a_suggestion(case, caplog):
    """Reproducer: typos in case.toml keys only warned "unknown key ... ignored"."""
    _edit_toml(case, "[registration]", "[registration]\nsilhouete_points = 100")
    _edit_toml(case, 'image = "xray/cam1.png"', 'image = "xray/cam1.png"\ncalibraton = "x"')
    _edit_toml(case, "[model]", "[model]\nlandmark = 'x'")
    with caplog.at_level(logging.WARNING):
        c = load_case(case)
    assert any(
        "[registration]: unknown key 'silhouete_points' ignored (did you mean "
        "'silhouette_points' in [registration.expert]?)" in w
        for w in c.warnings
    ), c.warnings
    assert any("'calibraton' ignored (did you mean 'calibration'?)" in w for w in c.warnings)
    assert any("'landmark' ignored (did you mean 'landmarks'?)" in w for w in c.warnings)
    assert "did you mean 'silhouette_points' in [registration.expert]?" in caplog.text
    assert c.options.silhouette_points == 150  # still a warning: the key is ignored


def test_an_unrelated_unknown_key_has_no_suggestion(case):
    _edit_toml(case, "[registration]", "[registration]\ncolour = 'red'")
    (w,) = load_case(case).warnings
    assert w.endswith("[registration]: unknown key 'colour' ignored")


def test_a_huge_count_option_is_a_case_error(case, capsys):
    """Reproducer: ``silhouette_points = 9223372036854775807`` was accepted."""
    _add_expert(case, "silhouette_points = 9223372036854775807")
    err = _one_line_error(case, capsys)
    assert (
        "[registration.expert]: silhouette_points: too large (9223372036854775807; at most" in err
    )


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("population_size = 100000", r"\[model\] population_size: must be in \[2, 1000\]"),
        ("population_seed = -1", r"\[model\] population_seed: must be in \[0, 4294967295\]"),
        ("ssm_variance = 1.5", r"\[model\] ssm_variance: must be in \(0, 1\], got 1\.5"),
        ("population_strength = 1e9", r"\[model\] population_strength: must be in \(0, 10\]"),
    ],
)
def test_the_template_numbers_are_bounded(case, setting, message):
    """Issue 18: bounds on every numeric option; a template route asking for 100000 shapes is
    refused before any work."""
    _edit_toml(case, 'ssm = "model/bone_ssm.npz"', f'template = "gt/bone.ply"\n{setting}')
    with pytest.raises(CaseError, match=message):
        load_case(case)


def test_the_loader_reads_image_headers_only_and_decodes_once(case, monkeypatch):
    import biplanar_reg.cases.case_types as case_module

    calls = []
    real = case_module.load_image
    monkeypatch.setattr(case_module, "load_image", lambda *a, **k: calls.append(a) or real(*a, **k))
    c = load_case(case)
    assert calls == []  # loading the case decoded no pixel
    assert [v.image_size for v in c.views] == [(256, 256), (256, 256)]
    first = c.views[0].image
    assert c.views[0].image is first and len(calls) == 1  # decoded once, then kept
    assert first.size == (256, 256) and first.pixels.dtype == np.float32


def test_pixel_data_that_cannot_be_decoded_is_a_one_line_case_error(case, capsys):
    png = case / "xray" / "cam1.png"
    data = png.read_bytes()
    png.write_bytes(data[:64])  # a valid header (size read at loading), no pixel data
    load_case(case)  # the header is enough to load the case
    out = case.parent / "out"
    assert main(["register", str(case), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "case.toml: [[views]][0] (cam1) image" in err[0], err
    assert "cam1.png" in err[0]
    assert not out.exists() and not list(case.parent.glob(".out.*"))  # nothing half-written
