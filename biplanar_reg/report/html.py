"""HTML pages from Jinja2 templates (autoescaped; self-contained CSS; relative links only)."""

from __future__ import annotations

import base64
import functools
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jinja2

from ..io.atomic import atomic_write_text

__all__ = ["render_template", "write_page"]


@functools.cache
def _environment() -> jinja2.Environment:
    # No bytecode cache: it would write outside the output folder (a shared temporary folder)
    # to save about 0.02 s per process.
    return jinja2.Environment(
        loader=jinja2.PackageLoader("biplanar_reg.report", "templates"),
        autoescape=True,  # every value is escaped: case ids, file names, messages
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def render_template(name: str, **context: Any) -> str:
    """Render the template ``name`` (in ``biplanar_reg/report/templates``) to a string."""
    from .. import __version__  # read on first use (package metadata)

    return _environment().get_template(name).render(version=__version__, **context)


def write_page(path: str | os.PathLike, name: str, **context: Any) -> Path:
    """Render a template and write it atomically to ``path``."""
    return atomic_write_text(path, render_template(name, **context))


def data_uri(path: str | os.PathLike) -> str:
    """A PNG file as a ``data:image/png;base64,...`` URI (pages hold their figures)."""
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def embedded_figures(
    folder: Path, figures: Mapping[str, Sequence[Mapping[str, str]]]
) -> dict[str, list[dict[str, str]]]:
    """``figures`` (group -> entries with ``src``, a PNG in ``folder``) with each entry's
    ``data`` URI added, for a self-contained page."""
    return {
        group: [{**f, "data": data_uri(folder / f["src"])} for f in figs]
        for group, figs in figures.items()
    }
