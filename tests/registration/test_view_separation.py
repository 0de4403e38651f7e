"""Views that see the bone from nearly one direction: the angle between them, and the quality
flag that says so (with advice)."""

from __future__ import annotations

import numpy as np
import pytest

from biplanar_reg.calibration.views import OrthographicView
from biplanar_reg.cases import load_case, to_view_observations
from biplanar_reg.registration import register_views
from biplanar_reg.registration.quality import NEARLY_PARALLEL_DEG, same_viewpoint, view_separation
from biplanar_reg.report.advice import FLAG_ADVICE, flag_advice
from biplanar_reg.simulate import write_synthetic_case
from biplanar_reg.simulate.scenes import look_at_view


def _views(deg: float, size=(256, 256)):
    """Two perspective views ``deg`` apart about the origin (the synthetic case's geometry)."""
    a = np.deg2rad(deg) / 2
    return [
        look_at_view(
            900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]),
            sdd=1200.0,
            pixel=0.3 * 512 / size[0],
            image_size=size,
            name=name,
        )
        for sx, name in ((-1.0, "cam1"), (1.0, "cam2"))
    ]


@pytest.mark.parametrize("deg", [0.2, 2.0, 30.0, 75.0])
def test_the_separation_is_the_angle_between_the_rays_at_the_bone(deg):
    angle, i, j = view_separation([v for v in _views(deg)], np.zeros(3))
    assert (i, j) == (0, 1)
    assert angle == pytest.approx(deg, abs=1e-6)


def test_opposed_views_are_parallel_and_the_widest_pair_is_named():
    v1, v2 = _views(0.0)
    back = look_at_view(np.array([0.0, 0.0, 900.0]), name="back")
    side = look_at_view(np.array([900.0, 0.0, 0.0]), name="side")
    assert view_separation([v1, back], np.zeros(3))[0] == pytest.approx(0.0, abs=1e-6)
    angle, i, j = view_separation([v1, back, side], np.zeros(3))
    assert angle == pytest.approx(90.0) and {i, j} in ({0, 2}, {1, 2})
    ortho = OrthographicView(R=v1.R, t=v1.t, K=np.diag([3.0, 3.0, 1.0]), name="o")
    assert view_separation([ortho, side], np.zeros(3))[0] == pytest.approx(90.0)


def test_same_viewpoint():
    v1, v2 = _views(10.0)
    assert same_viewpoint(v1, v1) and not same_viewpoint(v1, v2)
    turned = look_at_view(v1.centre, np.array([5.0, 0.0, 0.0]), name="turned")
    assert same_viewpoint(v1, turned)  # one source, another direction: still one viewpoint
    o1 = OrthographicView(R=v1.R, t=v1.t, K=np.diag([3.0, 3.0, 1.0]))
    o2 = OrthographicView(R=v1.R, t=v1.t + 10.0, K=np.diag([3.0, 3.0, 1.0]))
    assert same_viewpoint(o1, o2) and not same_viewpoint(
        o1, OrthographicView(R=v2.R, t=v2.t, K=o1.K)
    )


@pytest.fixture(scope="module")
def registered(tmp_path_factory):
    """``{deg: RegistrationResult}`` of the synthetic case with its views ``deg`` apart."""
    out = {}
    for deg in (2.0, 75.0):
        d = write_synthetic_case(tmp_path_factory.mktemp(f"a{deg:g}") / "c", 0, views=_views(deg))
        case = load_case(d)
        out[deg] = register_views(case.model, to_view_observations(case), options=case.options)
    return out


def test_nearly_parallel_views_are_flagged_with_their_angle(registered):
    """Reproducer: views 0.2-3 deg apart registered with no flag (vertex error 1.36 mm
    against 0.02 mm with the views 75 deg apart)."""
    (flag,) = [f for f in registered[2.0].flags if f.startswith("views nearly parallel")]
    assert flag.startswith("views nearly parallel: cam1/cam2 2.0 deg apart"), flag
    assert "calibration" in flag  # the flag says what to check
    assert not any("nearly parallel" in f for f in registered[75.0].flags)
    assert NEARLY_PARALLEL_DEG == 5.0


def test_the_flag_has_its_own_advice(registered):
    (flag,) = [f for f in registered[2.0].flags if f.startswith("views nearly parallel")]
    advice = flag_advice(flag)
    assert advice in FLAG_ADVICE.values() and "60-90" in advice


def test_several_frames_flag_the_frame_whose_views_are_nearly_parallel():
    from biplanar_reg.registration import ViewObservations
    from biplanar_reg.registration.frames import _parallel_views_flags

    def frame(deg):
        return [
            ViewObservations(
                name=v.name,
                view=v,
                landmark_names=["a"],
                landmark_ids=np.array([0]),
                landmark_uv=np.array([[128.0, 128.0]]),
                landmark_sigma_px=np.array([1.0]),
            )
            for v in _views(deg)
        ]

    flags = _parallel_views_flags([frame(75.0), frame(2.0)], ["f0", "f1"], [np.zeros(3)] * 2)
    assert len(flags) == 1 and flags[0].startswith("views nearly parallel: f1: cam1/cam2 2.0 deg")
    assert flag_advice(flags[0]) == FLAG_ADVICE["views nearly parallel"]
