"""A landmark that makes the shape implausible: registered again without it.

With known view poses, a final fit whose shape lies outside the model's plausible range
(:func:`.quality.shape_plausibility`: the flag "shape outside the model's plausible range") is
registered again, from the start, without one landmark, for each of the :data:`MAX_SUSPECTS`
landmarks the fit kept, more than 10 px off it, with the largest errors over their stated
sigmas
(:func:`refit_without_suspect`). Of the new fits whose shape is plausible and which the
outlines fit no worse (their RMS error, all views), the one the outlines fit best is kept; the
result then names the landmark ("landmark disagrees with the outlines: ... (left out of the
fit: the shape was implausible with it)", and among the rejected observations, with its error
at the new fit and weight 0).

Why: a click far off (a blunder the robust weights kept) in a view traced along one border
only bends the bone towards itself. The one border cannot contradict it, so neither the robust
reweighting (:mod:`.blunders`) nor the check of :mod:`.disagreement` leaves it out: at the
bent fit its error no longer stands out from the other clicks'. Refitting from the bent fit
without it stays bent (the traced border fits the bent shape too); a registration without it
from the start does not. What gives the click away is the shape it needs. Measured:
docs/registration.md, "Landmarks that disagree with the outlines".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .observations import ViewObservations, landmark_errors
from .quality import DISAGREE_MIN_PX

__all__: list[str] = []

#: The start of the quality flag of an implausible shape (:func:`.register._flags` writes it;
#: tests/registration/test_implausible.py checks that the two agree).
IMPLAUSIBLE_FLAG = "shape outside the model's plausible range"
#: The start of the flag listing the rejected landmarks.
REJECTED_FLAG = "rejected observations: "
#: How many landmarks are tried, each left out in turn (the largest errors first): each try is
#: a registration.
MAX_SUSPECTS = 3


def implausible(result) -> bool:
    """Whether ``result`` (a :class:`.register.RegistrationResult`) carries the flag of an
    implausible shape."""
    return any(f.startswith(IMPLAUSIBLE_FLAG) for f in result.flags)


def suspect_landmarks(result, views: list[ViewObservations]) -> list[tuple[str, str]]:
    """``(view, landmark)`` of the landmarks the fit kept (robust weight above 0, not
    rejected) that are more than :data:`.quality.DISAGREE_MIN_PX` (10 px) off it, the largest
    reprojection error over stated sigma first, at most :data:`MAX_SUSPECTS`. (A landmark a
    few pixels off is not what bends the bone: left out, such good landmarks were measured to
    make a clean case worse, docs/registration.md.)"""
    rejected = {tuple(r) for r in result.rejected}
    scored = []
    for v in views:
        errors = result.landmark_errors_px.get(v.name, {})
        weights = result.landmark_weights.get(v.name, {})
        for name, sigma in zip(v.landmark_names, v.landmark_sigma_px, strict=True):
            kept = weights.get(name, 1.0) > 0 and (v.name, name) not in rejected
            if kept and errors.get(name, 0.0) > DISAGREE_MIN_PX:
                scored.append((-errors[name] / sigma, v.name, name))
    return [(v, n) for _, v, n in sorted(scored)[:MAX_SUSPECTS]]


def without_landmark(views: list[ViewObservations], which: tuple[str, str]) -> list:
    """``views`` with the landmark ``which`` (view, name) taken out."""
    view, name = which
    out = []
    for v in views:
        keep = [i for i, n in enumerate(v.landmark_names) if v.name != view or n != name]
        out.append(
            replace(
                v,
                landmark_names=[v.landmark_names[i] for i in keep],
                landmark_ids=np.asarray(v.landmark_ids)[keep],
                landmark_uv=np.asarray(v.landmark_uv)[keep],
                landmark_sigma_px=np.asarray(v.landmark_sigma_px)[keep],
            )
        )
    return out


def contour_rms_px(result) -> float:
    """RMS of every annotated outline point's distance to the fit's outline, all views (px;
    0 without outlines)."""
    errors = [np.asarray(e, float).ravel() for e in result.contour_errors_px.values()]
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.sqrt(np.mean(e**2))) if e.size else 0.0


def refit_without_suspect(
    result,
    views: list[ViewObservations],
    register: Callable[[list[ViewObservations]], object],
    say: Callable[[str], None],
):
    """``result``, or, when its shape is implausible, the best of the registrations
    ``register(views without one suspect)`` (:func:`suspect_landmarks`, each in turn): of
    those whose shape is plausible and whose outline RMS error is no larger than
    ``result``'s, the one with the smallest (module doc). A refused registration
    (``ValueError``: too few landmarks left) is passed over."""
    if not implausible(result):
        return result
    suspects = suspect_landmarks(result, views)
    if not suspects:
        say(f"shape implausible; no landmark more than {DISAGREE_MIN_PX:.0f} px off to leave out")
        return result
    best, best_rms = None, contour_rms_px(result)
    for view, name in suspects:
        px = result.landmark_errors_px[view][name]
        say(f"shape implausible: registering again without {view}/{name} ({px:.0f} px off)")
        try:
            again = register(without_landmark(views, (view, name)))
        except ValueError as exc:
            say(f"without {view}/{name} the registration is refused ({exc})")
            continue
        rms = contour_rms_px(again)
        if not implausible(again) and rms <= best_rms:
            best, best_rms = (again, (view, name)), rms
    if best is None:
        say("no landmark left out: no registration without one was plausible and as close")
        return result
    return with_left_out(best[0], views, best[1])


def with_left_out(result, views: list[ViewObservations], which: tuple[str, str]):
    """``result`` (registered without the landmark ``which``) with that landmark reported as
    left out: its error at this fit, weight 0, rejected, and the flags that say so."""
    view, name = which
    px = landmark_errors(views, result.vertices)[view][name]
    errors = {v: dict(d) for v, d in result.landmark_errors_px.items()}
    weights = {v: dict(d) for v, d in result.landmark_weights.items()}
    errors.setdefault(view, {})[name] = px
    weights.setdefault(view, {})[name] = 0.0
    rejected = sorted({*(tuple(r) for r in result.rejected), (view, name)})
    flags = [f for f in result.flags if not f.startswith(REJECTED_FLAG)]
    flags.insert(
        0,
        f"landmark disagrees with the outlines: {view}/{name} by {px:.0f} px (left out of the "
        "fit: the shape was implausible with it)",
    )
    flags.append(REJECTED_FLAG + ", ".join(f"{v}/{n}" for v, n in rejected))
    return replace(
        result, landmark_errors_px=errors, landmark_weights=weights, rejected=rejected, flags=flags
    )
