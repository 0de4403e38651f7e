"""Contour recipes: the small, reviewable record from which a semi-automatic contour is rebuilt.

A recipe (``biplanar-reg/contour-recipe@1``, JSON) names the image, the method and its inputs
(anchors, box or polygon), the method's parameters and the cleaning options::

    {"format": "biplanar-reg/contour-recipe@1",
     "image": "xray/cam1.tif", "frame": 0, "view": "cam1",
     "method": "livewire",                     # or "grabcut"
     "anchors": [[u, v], ...], "closed": false,  # livewire
     "box": [u0, v0, u1, v1], "polygon": [[u, v], ...],   # grabcut: exactly one
     "params": {"sigma_px": 1.5, ...},
     "cleaning": {"spacing_px": 1.0, "border_px": 1.0, "exclusion_zones": [[[u, v], ...]]}}

``image`` is relative to the recipe's folder (absolute paths are kept as given). Running a
recipe is deterministic: the same recipe and image give the same contour.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_write_json
from ..io.jsonfile import is_finite_number, read_json
from .annotations import Contour
from .clean import clean_contour
from .image import XrayImage, load_image
from .livewire import livewire
from .region import grabcut_outline

__all__ = ["ContourRecipe", "load_recipe", "run_recipe"]

RECIPE_FORMAT = "biplanar-reg/contour-recipe@1"
METHODS = ("livewire", "grabcut")
_PARAMS = {
    "livewire": {"sigma_px", "margin_px", "anchor_snap_px", "subpixel"},
    "grabcut": {"iterations", "margin_px", "seed"},
}
_CLEANING = {"spacing_px", "border_px", "exclusion_zones", "min_points"}


@dataclass(eq=False)
class ContourRecipe:
    """Inputs of one semi-automatic contour (see the module docstring for the JSON form)."""

    image: str
    method: str
    frame: int = 0
    view: str = ""
    anchors: np.ndarray | None = None
    closed: bool = False
    box: np.ndarray | None = None
    polygon: np.ndarray | None = None
    params: dict[str, Any] = field(default_factory=dict)
    cleaning: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": RECIPE_FORMAT,
            "image": self.image,
            "frame": int(self.frame),
            "view": self.view,
            "method": self.method,
            "closed": bool(self.closed),
        }
        for key in ("anchors", "box", "polygon"):
            val = getattr(self, key)
            if val is not None:
                out[key] = np.asarray(val, float).tolist()
        out["params"] = dict(self.params)
        cleaning = dict(self.cleaning)
        if "exclusion_zones" in cleaning:
            cleaning["exclusion_zones"] = [
                np.asarray(z, float).tolist() for z in cleaning["exclusion_zones"]
            ]
        out["cleaning"] = cleaning
        return out


def _points(value: object, where: str, min_points: int, problems: list[str]) -> np.ndarray | None:
    """Check a list of at least ``min_points`` ``[u, v]`` pairs of finite numbers (pixels).

    Returns the points as a (K, 2) float array, or None (a problem naming ``where`` appended).
    """
    if not isinstance(value, list) or not all(
        isinstance(p, list) and len(p) == 2 and all(is_finite_number(x) for x in p) for p in value
    ):
        problems.append(f"{where}: expected a list of [u, v] pairs of finite numbers")
        return None
    if len(value) < min_points:
        problems.append(f"{where}: has {len(value)} point(s), need at least {min_points}")
        return None
    return np.array(value, float).reshape(-1, 2)


def _check_header(doc: dict[str, Any], problems: list[str]) -> dict[str, Any]:
    """Check the recipe's scalar fields: ``format``, ``method``, ``image``, ``frame``, ``view``.

    Also ``closed``. ``method`` must be one of :data:`METHODS`, ``image`` a non-empty path,
    ``frame`` an integer >= 0 (default 0), ``view`` a string (default ""), ``closed`` a boolean
    (default false; an invalid value is reported and read as false so that the anchors' minimum
    count can still be checked). Returns the fields as read, keyed by their
    :class:`ContourRecipe` attribute names; problems are appended.
    """
    if doc.get("format") != RECIPE_FORMAT:
        problems.append(f"format: expected {RECIPE_FORMAT!r}, got {doc.get('format')!r}")
    method = doc.get("method")
    if method not in METHODS:
        problems.append(f"method: expected one of {METHODS}, got {method!r}")
    image = doc.get("image")
    if not isinstance(image, str) or not image:
        problems.append("image: expected a file path")
    frame = doc.get("frame", 0)
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        problems.append(f"frame: expected an integer >= 0, got {frame!r}")
    view = doc.get("view", "")
    if not isinstance(view, str):
        problems.append(f"view: expected a string, got {view!r}")
    closed = doc.get("closed", False)
    if not isinstance(closed, bool):
        problems.append(f"closed: expected true or false, got {closed!r}")
        closed = False
    return {"method": method, "image": image, "frame": frame, "view": view, "closed": closed}


def _check_box(value: object, problems: list[str]) -> np.ndarray | None:
    """Check a grabcut ``box`` ``[u0, v0, u1, v1]`` of finite numbers (pixels); (4,) or None."""
    if not (
        isinstance(value, list) and len(value) == 4 and all(is_finite_number(x) for x in value)
    ):
        problems.append(f"box: expected [u0, v0, u1, v1] finite numbers, got {value!r:.60}")
        return None
    return np.array(value, float)


def _check_inputs(
    doc: dict[str, Any], method: object, closed: bool, problems: list[str]
) -> dict[str, np.ndarray | None]:
    """Check the method's inputs (pixels): livewire ``anchors``, grabcut ``box`` or ``polygon``.

    Livewire needs ``anchors``, at least 2 (3 when ``closed``); grabcut needs exactly one of
    ``box`` (:func:`_check_box`) and ``polygon`` (at least 3 points). An unknown ``method`` has
    no inputs to check. Returns ``{"anchors", "box", "polygon"}``, None where absent or invalid.
    """
    inputs: dict[str, np.ndarray | None] = {"anchors": None, "box": None, "polygon": None}
    if method == "livewire":
        if "anchors" not in doc:
            problems.append("anchors: required for method 'livewire'")
        else:
            inputs["anchors"] = _points(doc["anchors"], "anchors", 3 if closed else 2, problems)
    elif method == "grabcut":
        if ("box" in doc) == ("polygon" in doc):
            problems.append("box/polygon: method 'grabcut' needs exactly one of them")
        elif "box" in doc:
            inputs["box"] = _check_box(doc["box"], problems)
        else:
            inputs["polygon"] = _points(doc["polygon"], "polygon", 3, problems)
    return inputs


def _check_params(doc: dict[str, Any], method: object, problems: list[str]) -> dict[str, Any]:
    """Check ``params``: an object whose keys are parameters of ``method`` (see ``_PARAMS``).

    The values are checked by the method itself when the recipe is run. Returns a copy of the
    object ({} when it is not one).
    """
    params = doc.get("params", {})
    if not isinstance(params, dict):
        problems.append("params: expected an object")
        return {}
    if method in _PARAMS:
        for key in params:
            if key not in _PARAMS[method]:
                known = sorted(_PARAMS[method])
                problems.append(f"params.{key}: unknown parameter for {method} (known: {known})")
    return dict(params)


def _check_cleaning(doc: dict[str, Any], problems: list[str]) -> dict[str, Any]:
    """Check ``cleaning``: the options of :func:`~.clean.clean_contour` (see ``_CLEANING``).

    ``exclusion_zones`` must be a list of polygons of at least 3 points (pixels; converted to
    (P, 2) arrays), ``spacing_px`` a number > 0 and ``border_px`` a number > -1 (pixels).
    Returns a copy of the object ({} when it is not one).
    """
    cleaning = doc.get("cleaning", {})
    if not isinstance(cleaning, dict):
        problems.append("cleaning: expected an object")
        cleaning = {}
    cleaning = dict(cleaning)
    for key in cleaning:
        if key not in _CLEANING:
            problems.append(f"cleaning.{key}: unknown option (known: {sorted(_CLEANING)})")
    if "exclusion_zones" in cleaning:
        zones = cleaning["exclusion_zones"]
        if not isinstance(zones, list):
            problems.append("cleaning.exclusion_zones: expected a list of polygons")
        else:
            cleaning["exclusion_zones"] = [
                _points(z, f"cleaning.exclusion_zones[{k}]", 3, problems)
                for k, z in enumerate(zones)
            ]
    for key, low in (("spacing_px", 0.0), ("border_px", -1.0)):
        if key in cleaning and not (is_finite_number(cleaning[key]) and cleaning[key] > low):
            problems.append(f"cleaning.{key}: expected a number > {low:g}, got {cleaning[key]!r}")
    return cleaning


def parse_recipe(doc: object, source: str = "recipe") -> ContourRecipe:
    """Validate a parsed recipe document (``json.load`` output) and build a recipe.

    Checks, in order, the scalar fields (format, method, image, frame, view, closed), the
    method's inputs (anchors, or box / polygon; pixels), ``params`` and ``cleaning``; see the
    module docstring for the form.

    Raises
    ------
    ValueError
        Naming ``source`` and listing every problem found.
    """
    problems: list[str] = []
    if not isinstance(doc, dict):
        raise ValueError(f"{source}: expected a JSON object")
    header = _check_header(doc, problems)
    inputs = _check_inputs(doc, header["method"], header["closed"], problems)
    params = _check_params(doc, header["method"], problems)
    cleaning = _check_cleaning(doc, problems)
    if problems:
        raise ValueError(f"{source}: invalid contour recipe:\n  " + "\n  ".join(problems))
    return ContourRecipe(**header, **inputs, params=params, cleaning=cleaning)


def load_recipe(path: str | os.PathLike[str]) -> ContourRecipe:
    """Read and validate a recipe file."""
    return parse_recipe(read_json(path), str(path))


def save_recipe(recipe: ContourRecipe, path: str | os.PathLike[str]) -> Path:
    """Validate and write a recipe atomically."""
    doc = recipe.to_json()
    parse_recipe(doc, str(path))
    return atomic_write_json(path, doc)


def run_recipe(
    recipe: ContourRecipe,
    base_dir: str | os.PathLike[str] = ".",
    image: XrayImage | None = None,
) -> list[Contour]:
    """Rebuild the contour(s) of a recipe: trace or segment, then clean.

    Parameters
    ----------
    recipe : ContourRecipe
    base_dir : path
        Folder that a relative ``recipe.image`` is relative to (the recipe file's folder).
    image : XrayImage, optional
        The already-loaded image (skips loading ``recipe.image``).

    Returns
    -------
    list of Contour
        The cleaned pieces (a cut outline gives several open pieces; none if all was cut).

    Raises
    ------
    ValueError
        Unreadable image, anchors/box outside it, or invalid parameters (message says which).
    """
    if image is None:
        path = Path(recipe.image)
        if not path.is_absolute():
            path = Path(base_dir) / path
        image = load_image(path, recipe.frame)
    if recipe.method == "livewire":
        raw = livewire(image, recipe.anchors, recipe.closed, **recipe.params)
        closed = recipe.closed
    elif recipe.method == "grabcut":
        raw = grabcut_outline(image, box=recipe.box, polygon=recipe.polygon, **recipe.params)
        closed = True
    else:  # parse_recipe rejects this; kept for recipes built in code
        raise ValueError(f"method: expected one of {METHODS}, got {recipe.method!r}")
    opts = dict(recipe.cleaning)
    pieces, flags = clean_contour(
        raw,
        closed,
        spacing_px=float(opts.get("spacing_px", 1.0)),
        image_size=image.size,
        border_px=float(opts.get("border_px", 1.0)),
        exclusion_zones=opts.get("exclusion_zones") or (),
        min_points=int(opts.get("min_points", 3)),
    )
    return [Contour(p, c) for p, c in zip(pieces, flags, strict=True)]
