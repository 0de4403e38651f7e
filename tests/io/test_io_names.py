"""File-name words made from user names, and the one-folder check of names read from files."""

from __future__ import annotations

import pytest

from biplanar_reg.io.names import file_name_word, is_path_component


@pytest.mark.parametrize(
    ("text", "default", "strip", "word"),
    [
        ("cam1", "view", "", "cam1"),
        ("cam 1/AP", "view", "", "cam_1_AP"),
        ("..\\x", "view", "", ".._x"),  # no separator survives
        ("épaule", "view", "", "_paule"),  # one "_" per non-ASCII character
        ("", "view", "", "view"),
        ("..hidden.", "case", ".", "hidden"),
        ("...", "case", ".", "case"),
        ("_img_.", "view", "._", "img"),
    ],
)
def test_file_name_word(text, default, strip, word):
    assert file_name_word(text, default, strip) == word


@pytest.mark.parametrize("name", ["case01", "a b", "k.17", "épaule"])
def test_a_path_component(name):
    assert is_path_component(name)


@pytest.mark.parametrize("name", ["", ".", "..", ".hidden", "a/b", "a\\b", "a\0b", None, 3])
def test_not_a_path_component(name):
    assert not is_path_component(name)
