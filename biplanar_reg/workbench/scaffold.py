"""A new case folder's ``case.toml``, written from a model, calibrations and images.

``biplanar-reg workbench --new CASE_DIR`` (options, or the page's "new case" form) calls
:func:`scaffold_case`. Every path is given relative to the case folder (or absolute) and must
stay inside it, symlinks resolved, as the case loader requires; the written file is then read
back with :func:`biplanar_reg.cases.read_case_setup` and removed again if the loader refuses
it, so a refused scaffold leaves nothing behind.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from ..cases import CaseSetup, read_case_setup
from ..io import atomic_write_text
from ..io.names import file_name_word

__all__ = [
    "NewView",
    "scaffold_case",
    "case_toml_text",
    "candidate_files",
    "create_new_case_app",
]

#: Model files by suffix: an SSM written by ``biplanar-reg ssm build``, or a template mesh.
SSM_SUFFIXES = (".npz",)
MESH_SUFFIXES = (".ply", ".stl", ".obj", ".vtk", ".vtp", ".off")
CALIBRATION_SUFFIXES = (".txt", ".json", ".csv", ".cal", ".dcm", ".xml")
IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".dcm", ".bmp")
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: Text files that are documentation, not calibrations (licence, read-me, notices).
_NOT_CALIBRATION = re.compile(r"^(licen[cs]e|readme|copying|notice|authors|changelog)", re.I)
#: Files listed for the page's form, at most.
MAX_LISTED = 2000


@dataclass(frozen=True)
class NewView:
    """One view of a new case: its name, calibration file and (optional) image file."""

    name: str
    calibration: str
    image: str | None = None


def parse_view_option(text: str) -> NewView:
    """``NAME=CALIBRATION[,IMAGE]`` (the ``--view`` option) as a :class:`NewView`."""
    name, sep, rest = text.partition("=")
    if not sep or not rest:
        raise ValueError(f"--view: expected NAME=CALIBRATION[,IMAGE], got {text!r}")
    calib, _, image = rest.partition(",")
    return NewView(name.strip(), calib.strip(), image.strip() or None)


def _inside(case_dir: Path, value: object, field: str, must_exist: bool = True) -> str:
    """``value`` as a path relative to ``case_dir`` (POSIX), checked to stay inside it."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{field}: expected a file path, got {value!r}")
    path = Path(value.strip())
    full = (path if path.is_absolute() else case_dir / path).resolve()
    if not full.is_relative_to(case_dir):
        raise ValueError(f"{field}: {value!r} is outside the case folder {case_dir}")
    if must_exist and not full.is_file():
        raise ValueError(f"{field}: {value!r}: file not found in {case_dir}")
    return full.relative_to(case_dir).as_posix()


def _q(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(text, ensure_ascii=False)


def _model_lines(case_dir: Path, model: object, landmarks: object) -> list[str]:
    rel = _inside(case_dir, model, "model")
    suffix = Path(rel).suffix.lower()
    if suffix in SSM_SUFFIXES:
        key = "ssm"
    elif suffix in MESH_SUFFIXES:
        key = "template"
    else:
        known = ", ".join(SSM_SUFFIXES + MESH_SUFFIXES)
        raise ValueError(f"model: {rel!r}: expected a shape model or a mesh ({known})")
    if landmarks is None:  # beside the model; the 3D view creates it
        landmarks = (Path(rel).parent / "landmarks.json").as_posix()
    lm = _inside(case_dir, landmarks, "landmarks", must_exist=False)
    if (case_dir / lm).exists() and not (case_dir / lm).is_file():
        raise ValueError(f"landmarks: {lm!r} is not a file")
    return ["[model]", f"{key} = {_q(rel)}", f"landmarks = {_q(lm)}", ""]


def _view_lines(case_dir: Path, views: Sequence[NewView]) -> list[str]:
    if len(views) < 2:
        raise ValueError(f"views: {len(views)} given; a biplanar case needs at least 2")
    names = [v.name for v in views]
    lines: list[str] = []
    for i, v in enumerate(views):
        field = f"views[{i}]"
        if not _NAME.match(v.name or ""):
            raise ValueError(f"{field}.name: {v.name!r}: use 1-64 letters, digits, '_', '-', '.'")
        if v.name in names[:i]:
            raise ValueError(f"{field}.name: {v.name!r} is given twice")
        lines += ["[[views]]", f"name = {_q(v.name)}"]
        calib = _inside(case_dir, v.calibration, field + ".calibration")
        lines.append(f"calibration = {_q(calib)}")
        if v.image:
            lines.append(f"image = {_q(_inside(case_dir, v.image, field + '.image'))}")
        lines.append("")
    return lines


def case_toml_text(
    case_dir: Path,
    *,
    model: object,
    views: Sequence[NewView],
    landmarks: object = None,
    annotations: str = "annotations.json",
    poses: str = "known",
    units: str = "mm",
) -> str:
    """The text of a new ``case.toml`` (paths checked; see :func:`scaffold_case`)."""
    if poses not in ("known", "unknown", "refine"):
        raise ValueError(f"poses: expected 'known', 'unknown' or 'refine', got {poses!r}")
    if units not in ("mm", "m"):
        raise ValueError(f"units: expected 'mm' or 'm', got {units!r}")
    ann = _inside(case_dir, annotations, "annotations", must_exist=False)
    lines = [
        "# written by biplanar-reg workbench --new; format: docs/cases.md",
        'format = "biplanar-reg/case@1"',
        f"id = {_q(case_dir.name)}",
        f"units = {_q(units)}",
        "",
        *_model_lines(case_dir, model, landmarks),
        *_view_lines(case_dir, views),
        "[annotations]",
        f"file = {_q(ann)}",
        "",
        "[registration]",
        f"poses = {_q(poses)}",
        "silhouettes = true",
    ]
    return "\n".join(lines) + "\n"


def scaffold_case(
    case_dir: str | os.PathLike,
    *,
    model: object,
    views: Sequence[NewView],
    landmarks: object = None,
    annotations: str = "annotations.json",
    poses: str = "known",
    units: str = "mm",
) -> CaseSetup:
    """Write ``CASE_DIR/case.toml`` for the given files and read it back.

    Parameters
    ----------
    case_dir : path
        An existing folder without a ``case.toml``.
    model : str
        The shape model (``.npz``, ``[model] ssm``) or template mesh (``[model] template``).
    views : sequence of NewView
        Two or more views (name, calibration file, image file or None); calibration formats
        are detected from the content.
    landmarks : str, optional
        The model landmark file (``{"name": vertex}``; may not exist yet). Default:
        ``landmarks.json`` beside the model.
    annotations, poses, units : str
        ``[annotations] file`` (may not exist yet), ``[registration] poses``, ``units``.

    Returns
    -------
    CaseSetup
        The new case, as the workbench opens it.

    Raises
    ------
    ValueError
        A field naming the option (``model``, ``views[1].calibration``, ...), or the loader's
        :class:`CaseError`; nothing is left written then.
    """
    folder = Path(case_dir)
    if not folder.is_dir():
        raise ValueError(f"CASE_DIR: {folder}: not a folder (create it and put the files in it)")
    folder = folder.resolve()
    target = folder / "case.toml"
    if target.exists():
        raise ValueError(f"{target}: exists already; open it with biplanar-reg workbench CASE_DIR")
    text = case_toml_text(
        folder, model=model, views=views, landmarks=landmarks, annotations=annotations,
        poses=poses, units=units,
    )  # fmt: skip
    atomic_write_text(target, text)
    try:
        return read_case_setup(folder)
    except BaseException:
        target.unlink(missing_ok=True)
        raise


def candidate_files(case_dir: str | os.PathLike) -> dict[str, list[str]]:
    """The case folder's files a new case may use, by role: ``{"models", "calibrations",
    "images", "landmarks"}`` (POSIX paths relative to the folder; hidden files and ``out/``
    skipped; links leaving the folder skipped)."""
    root = Path(case_dir).resolve()
    found: dict[str, list[str]] = {"models": [], "calibrations": [], "images": [], "landmarks": []}
    count = 0
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d != "out")
        for name in sorted(filenames):
            path = Path(dirpath) / name
            if name.startswith(".") or not path.resolve().is_relative_to(root):
                continue
            count += 1
            if count > MAX_LISTED:
                return found
            _classify(found, path, path.relative_to(root).as_posix())
    return found


def _is_landmark_file(path: Path) -> bool:
    """A small JSON object of names to vertex indices (the ``[model] landmarks`` format)."""
    try:
        if path.stat().st_size > 1_000_000:
            return False
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (
        bool(doc)
        and isinstance(doc, dict)
        and all(isinstance(v, int) and not isinstance(v, bool) for v in doc.values())
    )


def _classify(found: Mapping[str, list[str]], path: Path, rel: str) -> None:
    suffix = path.suffix.lower()
    if suffix in SSM_SUFFIXES + MESH_SUFFIXES:
        found["models"].append(rel)
    if suffix == ".json" and _is_landmark_file(path):
        found["landmarks"].append(rel)
    elif suffix in CALIBRATION_SUFFIXES and not _NOT_CALIBRATION.match(path.name):
        found["calibrations"].append(rel)
    if suffix in IMAGE_SUFFIXES:
        found["images"].append(rel)


def view_names(paths: Sequence[str]) -> dict[str, str]:
    """A view name for each file (an image, or a calibration): its file name without the
    suffix, each character other than letters, digits, ``_``, ``-`` and ``.`` replaced by
    ``_``, at most 64 characters, made unique with ``_2``, ``_3``, ... in the order given."""
    out: dict[str, str] = {}
    for path in paths:
        stem = file_name_word(PurePosixPath(path).stem, "view", strip="._")
        name, k = stem[:64], 2
        while name in out.values():
            tail = f"_{k}"
            name, k = stem[: 64 - len(tail)] + tail, k + 1
        out[path] = name
    return out


def views_from_json(value: Any) -> list[NewView]:
    """The ``views`` field of the page's form: ``[{"name", "calibration", "image"?}, ...]``."""
    if not isinstance(value, list):
        raise ValueError(f"views: expected a list of {{name, calibration, image}}, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if not isinstance(v, dict):
            raise ValueError(f"views[{i}]: expected an object {{name, calibration, image}}")
        image = v.get("image") or None
        out.append(NewView(str(v.get("name", "")), v.get("calibration"), image))
    return out


class Switch:
    """An ASGI app that forwards to ``app``, which may be replaced while it runs (the "new
    case" form is replaced by the workbench of the case it wrote)."""

    def __init__(self, app: Any):
        self.app = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        await self.app(scope, receive, send)


def create_new_case_app(case_dir: Path, token: Any, opened: Any) -> Any:
    """The "new case" form's ASGI app (every connection checked as in the workbench).

    ``token`` is the launch token or the command's
    :class:`~biplanar_reg.workbench.access.Access` (shared with the workbench that replaces the
    form, so that the browser stays signed in). ``GET /`` the form (``static/new.html``), ``GET
    /api/new`` ``{"case_dir", "files": candidate_files, "view_names": view_names of the images
    and calibrations}``, ``POST /api/new`` ``{"model",
    "views": [{"name", "calibration", "image"?}], "landmarks"?, "poses"?}``:
    :func:`scaffold_case`, then ``opened(setup)`` (which opens the workbench in its place);
    answers ``{"url": "/"}``, 400 naming the field when the form is wrong (nothing written).
    """
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.requests import Request
    from starlette.responses import HTMLResponse, JSONResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    from .access import Guard
    from .api import STATIC_DIR, _body, _call, _guarded, as_access, page_html

    access = as_access(token)

    async def page(request: Request) -> HTMLResponse:
        html = await _call(page_html, "new.html", access.token)
        return HTMLResponse(html, headers={"Cache-Control": "no-store"})

    async def files(request: Request) -> JSONResponse:
        found = await _call(candidate_files, case_dir)
        # each view is named after its image (else its calibration) file
        names = {**view_names(found["calibrations"]), **view_names(found["images"])}
        return JSONResponse({"case_dir": str(case_dir), "files": found, "view_names": names})

    async def create(request: Request) -> JSONResponse:
        body = await _body(request)
        views = views_from_json(body.get("views"))
        setup = await _call(
            lambda: scaffold_case(
                case_dir, model=body.get("model"), views=views,
                landmarks=body.get("landmarks") or None, poses=body.get("poses") or "known",
            )
        )  # fmt: skip
        await _call(opened, setup)
        return JSONResponse({"url": "/", "case_toml": "case.toml"})

    routes = [
        Route("/", _guarded(page), methods=["GET"]),
        Route("/api/new", _guarded(files), methods=["GET"]),
        Route("/api/new", _guarded(create), methods=["POST"]),
        Mount("/static", app=StaticFiles(directory=STATIC_DIR), name="static"),
    ]
    return Starlette(routes=routes, middleware=[Middleware(Guard, access=access)])
