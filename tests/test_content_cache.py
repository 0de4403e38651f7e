"""Work kept by the content of its arrays (:mod:`biplanar_reg._content`): a copy of the same
arrays finds it, other content does not, and what a cache hands out cannot be changed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from biplanar_reg._content import ContentCache, content_key
from biplanar_reg.io import read_mesh
from biplanar_reg.mesh_cuts import detect_cuts

#: The shipped wrist radius template: a CT-cropped bone with a flat cap.
TEMPLATE = (
    Path(__file__).resolve().parents[1] / "sample_cases/wrist_radius/model/radius_template.ply"
)


def test_the_key_is_the_content_dtype_and_shape():
    a = np.arange(12.0).reshape(4, 3)
    assert content_key(a) == content_key(a.copy()) == content_key(np.asfortranarray(a))
    assert content_key(a) != content_key(a + 1e-12)
    assert content_key(a) != content_key(a.reshape(3, 4))
    assert content_key(a) != content_key(a.astype(np.float32))
    assert content_key(a, a) != content_key(a)


def test_the_cache_computes_once_per_key_and_keeps_the_last_few():
    cache: ContentCache[int] = ContentCache(size=2)
    calls = []

    def compute(v):
        calls.append(v)
        return v

    assert [cache.get(k, lambda k=k: compute(k)) for k in ("a", "a", "b", "a")] == list("aaba")
    assert calls == ["a", "b"]
    cache.get("c", lambda: compute("c"))  # "b" is the oldest now: dropped
    cache.get("b", lambda: compute("b"))
    assert calls == ["a", "b", "c", "b"]


def test_a_templates_cuts_are_found_once_and_cannot_be_changed():
    V, F = read_mesh(TEMPLATE)
    first = detect_cuts(V, F)
    again = detect_cuts(*read_mesh(TEMPLATE))  # a case loading the model afresh
    assert again is first and first.caps
    with pytest.raises(ValueError, match="read-only"):
        first.caps[0].faces[0] = 0
    moved = detect_cuts(V + 1.0, F)
    assert moved is not first and len(moved.caps) == len(first.caps)
