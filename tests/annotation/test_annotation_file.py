"""Tests of the annotation file: round trip, validation messages, atomic save, merge."""

from __future__ import annotations

import json

import numpy as np
import pytest

from biplanar_reg.annotation.annotations import (
    FORMAT,
    AnnotationError,
    Annotations,
    Contour,
    Landmark,
    ViewAnnotations,
    load_annotations,
    merge_annotations,
    save_annotations,
)


def _doc() -> dict:
    return {
        "format": FORMAT,
        "views": {
            "cam1": {
                "landmarks": {"styloid": {"uv": [812.3, 901.2], "sigma_px": 2.0}},
                "contours": [
                    {"uv": [[640.0, 410.5], [641.2, 411.0], [642.0, 413.5]], "closed": False}
                ],
            },
            "cam2": {"landmarks": {}, "contours": []},
        },
    }


def _write(tmp_path, doc, name="a.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def test_round_trip(tmp_path):
    ann = load_annotations(_write(tmp_path, _doc()))
    lm = ann.views["cam1"].landmarks["styloid"]
    np.testing.assert_array_equal(lm.uv, [812.3, 901.2])
    assert lm.sigma_px == 2.0
    c = ann.views["cam1"].contours[0]
    assert c.uv.shape == (3, 2) and c.closed is False
    out = save_annotations(ann, tmp_path / "sub" / "b.json")
    again = load_annotations(out)
    assert again.to_json() == ann.to_json() == _doc()
    assert [p.name for p in out.parent.iterdir()] == ["b.json"]  # no temp file left


def test_default_sigma(tmp_path):
    doc = _doc()
    del doc["views"]["cam1"]["landmarks"]["styloid"]["sigma_px"]
    ann = load_annotations(_write(tmp_path, doc))
    assert ann.views["cam1"].landmarks["styloid"].sigma_px == 1.0


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: d["views"]["cam1"]["contours"][0]["uv"].__setitem__(1, [1.0, "x"]),
            r"views\.cam1\.contours\[0\]\.uv\[1\]: coordinates must be finite",
        ),
        (
            lambda d: d["views"]["cam1"]["contours"][0].__setitem__("uv", [[1, 2], [3, 4]]),
            r"views\.cam1\.contours\[0\]: has 2 point\(s\); a contour needs at least 3",
        ),
        (
            lambda d: d["views"]["cam1"]["landmarks"]["styloid"].__setitem__("sigma_px", -1),
            r"views\.cam1\.landmarks\.styloid\.sigma_px: must be a positive number",
        ),
        (lambda d: d.__setitem__("format", "other@2"), r"format: expected"),
        (
            lambda d: d["views"]["cam1"]["landmarks"]["styloid"].__setitem__("uv", [1.0]),
            r"views\.cam1\.landmarks\.styloid\.uv: expected \[u, v\]",
        ),
        (
            lambda d: d["views"]["cam2"].__setitem__("contours", {}),
            r"views\.cam2\.contours: expected a list",
        ),
    ],
)
def test_validation_messages(tmp_path, mutate, message):
    doc = _doc()
    mutate(doc)
    with pytest.raises(AnnotationError, match=message):
        load_annotations(_write(tmp_path, doc))


@pytest.mark.parametrize(
    ("old", "token", "where"),
    [
        ("812.3", "NaN", r"views\.cam1\.landmarks\.styloid\.uv"),
        ("901.2", "Infinity", r"views\.cam1\.landmarks\.styloid\.uv"),
        ("2.0", "-Infinity", r"views\.cam1\.landmarks\.styloid\.sigma_px"),
        ("641.2", "NaN", r"views\.cam1\.contours\[0\]\.uv\[1\]"),
    ],
)
def test_nan_and_infinity_name_the_view_and_landmark(tmp_path, old, token, where):
    """Reproducer (issue 18): a ``NaN``/``Infinity`` token was refused while parsing, with a
    message naming only the file ("non-standard JSON number 'NaN'"), not the view/landmark."""
    p = tmp_path / "nan.json"
    p.write_text(json.dumps(_doc()).replace(old, token, 1))
    with pytest.raises(AnnotationError, match=rf"nan\.json: .*\n  {where}: .*{token}") as info:
        load_annotations(p)
    assert len(info.value.problems) == 1


def test_malformed_json_names_the_file_and_line(tmp_path):
    p = tmp_path / "nan.json"
    p.write_text('{"format": ')
    with pytest.raises(ValueError, match=r"nan\.json: malformed JSON at line 1"):
        load_annotations(p)


def test_known_sets_and_image_size(tmp_path):
    p = _write(tmp_path, _doc())
    with pytest.raises(AnnotationError, match=r"views\.cam2: unknown view"):
        load_annotations(p, known_views={"cam1"})
    with pytest.raises(AnnotationError, match=r"landmarks\.styloid: unknown landmark"):
        load_annotations(p, known_landmarks={"epicondyle"})
    with pytest.raises(AnnotationError, match=r"styloid\.uv: point \(812\.3, 901\.2\) is outside"):
        load_annotations(p, image_sizes={"cam1": (800, 1000)})
    # a point half a pixel beyond the last pixel centre is still inside
    ok = load_annotations(p, image_sizes={"cam1": (813, 902)})
    assert "styloid" in ok.views["cam1"].landmarks


def test_all_problems_reported_and_nothing_built(tmp_path):
    doc = _doc()
    doc["views"]["cam1"]["contours"].append({"uv": [[0, 0]], "closed": False})
    doc["views"]["cam1"]["landmarks"]["bad"] = {"uv": [None, 1]}
    with pytest.raises(AnnotationError) as info:
        load_annotations(_write(tmp_path, doc))
    assert len(info.value.problems) == 2
    assert "contours[1]" in str(info.value) and "landmarks.bad" in str(info.value)


def test_save_invalid_keeps_previous_file(tmp_path):
    good = load_annotations(_write(tmp_path, _doc()))
    target = save_annotations(good, tmp_path / "out.json")
    before = target.read_bytes()
    bad = Annotations({"cam1": ViewAnnotations(contours=[Contour(np.array([[0.0, np.nan]] * 3))])})
    with pytest.raises(AnnotationError, match=r"contours\[0\]\.uv\[0\]"):
        save_annotations(bad, target)
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "out.json"]


def test_merge():
    a = Annotations(
        {
            "cam1": ViewAnnotations(
                landmarks={"p": Landmark(np.array([1.0, 2.0]))},
                contours=[Contour(np.zeros((3, 2)))],
            )
        }
    )
    b = Annotations(
        {
            "cam1": ViewAnnotations(
                landmarks={"q": Landmark(np.array([3.0, 4.0]), 2.0)},
                contours=[Contour(np.ones((4, 2)), True)],
            ),
            "cam2": ViewAnnotations(landmarks={"p": Landmark(np.array([5.0, 6.0]))}),
        }
    )
    m = merge_annotations([a, b])
    assert sorted(m.views) == ["cam1", "cam2"]
    assert sorted(m.views["cam1"].landmarks) == ["p", "q"]
    assert [len(c.uv) for c in m.views["cam1"].contours] == [3, 4]
    c = Annotations({"cam1": ViewAnnotations(landmarks={"p": Landmark(np.array([9.0, 9.0]))})})
    with pytest.raises(ValueError, match=r"landmark 'p' of view 'cam1' appears again in part 1"):
        merge_annotations([a, c])
    np.testing.assert_array_equal(
        merge_annotations([a, c], overwrite=True).views["cam1"].landmarks["p"].uv, [9, 9]
    )
    # the inputs are not modified
    assert list(a.views["cam1"].landmarks) == ["p"] and len(a.views["cam1"].contours) == 1


def test_deeply_nested_json_is_a_named_error(tmp_path):
    """Reproducer (issue 18): a deeply nested document raised ``RecursionError``."""
    p = tmp_path / "deep.json"
    p.write_text('{"views": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ValueError, match=r"deep\.json: nested too deeply \(more than \d+ levels"):
        load_annotations(p)


@pytest.mark.parametrize("closed", [False, True])
def test_a_contour_of_one_repeated_point_is_named(tmp_path, closed):
    """Reproducer (issue 18): a contour whose points are all the same passed validation and
    failed in the registration with "zero-size array to reduction operation maximum"."""
    doc = _doc()
    doc["views"]["cam1"]["contours"].append({"uv": [[640.0, 410.5]] * 4, "closed": closed})
    with pytest.raises(
        AnnotationError,
        match=r"views\.cam1\.contours\[1\]: all 4 points are \(640, 410\.5\); a contour needs "
        r"at least 2 different points",
    ):
        load_annotations(_write(tmp_path, doc))
