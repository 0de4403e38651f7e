"""What to do about each quality flag of a registration (one table for the report and the
workbench).

A flag is a line of text from :func:`biplanar_reg.registration.register_views` (its ``flags``,
and ``result.json["flags"]``); its *kind* is the text before its details, e.g.
``"relaxation not tight (certificate 0.038)"`` is of kind ``"relaxation not tight"``.
:data:`FLAG_ADVICE` maps every kind the registration raises to a one-line advice;
:func:`flag_advice` looks a flag up.
"""

from __future__ import annotations

import re

__all__ = ["FLAG_ADVICE", "flag_advice", "flag_kind"]

#: Flag kind -> what to do about it (one line, plain text).
FLAG_ADVICE: dict[str, str] = {
    "relaxation not tight": (
        "The convex relaxation's own answer is far from the returned fit, so the result rests "
        "on the local refinement alone: add landmarks (spread over the bone, each in both "
        "views if possible), check that every landmark's name is the model landmark it marks, "
        "and trace more of each outline."
    ),
    "large landmark reprojection error": (
        "Landmarks and registered bone disagree by more than reprojection_flag_px: check the "
        "calibration of each view (file, format, image flips) and look in the landmark table "
        "for a landmark with a large error in one view only (swapped or misnamed click)."
    ),
    "rejected observations": (
        "These landmark clicks disagree with the other landmarks and the outlines by far more "
        "than the others do and were given weight 0 (landmark_weights in result.json): check "
        "each one's position and name in its view, then fix or delete it and register again."
    ),
    "landmark disagrees with the outlines": (
        "This landmark's error stands far out from the others' (robust_threshold, 4, of their "
        "robust sigmas), or, with the shape implausible, the bone registered without it fitted "
        'the outlines as well and kept a plausible shape ("the shape was implausible with '
        'it"). With known view poses it was left out of the fit (weight 0; "left out of the '
        'fit"), with estimated view poses it is still in it. Check that the click is on the '
        "landmark's anatomical point in that view and that the name is right (a point hidden "
        "by another bone is better deleted), then register again."
    ),
    "one-sided outline": (
        "Only one side of the bone is traced in this view, so the other side rests on the "
        "shape model and the landmarks: trace the other border where it can be seen (even a "
        "short stretch), or add a landmark on that side."
    ),
    "shape outside the model's plausible range": (
        "The registered shape is further from the model's mean than its population allows "
        "(weights or volume): look for a traced stretch on the wrong edge or a misplaced "
        "landmark, check the calibration, and check that the model is for this bone."
    ),
    "views nearly parallel": (
        "The views see the bone from almost one direction, so its depth along the rays rests "
        "on the bone's size in the images and on the shape model: such registrations had long "
        "error tails and an uncertainty that covered fewer of their errors. Check that each "
        "view has its own calibration (not one file twice, the right DLT column or MayaCam "
        "file, the DICOM positioner angles); for new images, set the views 60-90 deg apart."
    ),
    "local refinement did not converge": (
        "Raise refine_iterations in [registration] of case.toml and register again; if it "
        "persists, look for contour stretches far from the bone (contour table) and trim them."
    ),
}

#: Advice for a flag of a kind not in :data:`FLAG_ADVICE`.
GENERIC_ADVICE = "See docs/registration.md (quality flags) and review the figures below."


def flag_kind(flag: str) -> str:
    """A flag's kind: its text before the first ``(`` or ``:``, stripped.

    Parameters
    ----------
    flag : str
        A quality flag, e.g. ``"rejected observations: cam1/tip"``.

    Returns
    -------
    str
        E.g. ``"rejected observations"``.
    """
    return re.split(r"[(:]", flag, maxsplit=1)[0].strip()


def flag_advice(flag: str) -> str:
    """What to do about a quality flag (one line).

    Parameters
    ----------
    flag : str
        A quality flag of a registration result.

    Returns
    -------
    str
        The advice of its kind in :data:`FLAG_ADVICE`, or a pointer to the docs for a kind it
        does not list.
    """
    return FLAG_ADVICE.get(flag_kind(flag), GENERIC_ADVICE)
