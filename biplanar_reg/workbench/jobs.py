"""The registration of the open case in a background thread, and the review of its result.

:class:`RegistrationJob` runs :func:`biplanar_reg.cases.run_case_dir` (what ``biplanar-reg
register CASE_DIR`` does, the same outputs in ``CASE_DIR/out``) with a progress callback that
records each stage message; :func:`review` turns ``out/result.json`` and
``out/registered.ply`` into what the page draws: the registered model's outline and landmarks
in each view, in pixels.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..cases import run_case_dir
from ..cases.case import CaseView
from ..errors import CommandError, one_line
from ..io import read_mesh
from ..outline import outline_polylines
from ..result import ViewResult, read_result

__all__ = ["RegistrationJob", "review"]

log = logging.getLogger(__name__)

STATES = ("idle", "running", "done", "failed")
#: A registration waits at most this long (s) for the previous one's report to be written.
REPORT_WAIT_S = 60.0


class RegistrationJob:
    """One registration at a time of a case folder, in a daemon thread.

    Parameters
    ----------
    case_dir, out_dir : Path
        The case folder and the output folder (``run_case_dir(case_dir, out_dir)``).
    warm : bool
        Start each registration from the result in ``out_dir`` when it may (``run_case_dir(...,
        warm=True)``: the same model, views and options, no landmark moved far); the result's
        ``start`` says which start was used and why.

    Attributes
    ----------
    run : int
        Number of registrations started (tells one run's messages from the next one's).
    """

    def __init__(self, case_dir: Path, out_dir: Path, warm: bool = True):
        self.case_dir = Path(case_dir)
        self.out_dir = Path(out_dir)
        self.warm = warm
        self.run = 0
        self._state = "idle"
        self._messages: list[str] = []
        self._error: str | None = None
        self._result: dict[str, Any] | None = None
        self._t0 = 0.0
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    def start(self) -> bool:
        """Start a registration; False (nothing started) when one is running. A previous
        one still writing its report (after its result) is waited for."""
        prev = self._thread
        if prev is not None and prev.is_alive() and self._state != "running":
            prev.join(REPORT_WAIT_S)
        with self._cond:
            if self._state == "running":
                return False
            self.run += 1
            self._state, self._messages, self._error, self._result = "running", [], None, None
            self._t0 = time.perf_counter()
        self._thread = threading.Thread(
            target=self._work, name="biplanar-reg-register", daemon=True
        )
        self._thread.start()
        return True

    def _say(self, message: str) -> None:
        """The progress callback: one line per message."""
        with self._cond:
            self._messages.append(one_line(message))
            self._cond.notify_all()

    def _finish(self, state: str, result: dict[str, Any] | None, error: str | None) -> None:
        with self._cond:
            self._state, self._result, self._error = state, result, error
            self._cond.notify_all()

    def _register(self) -> None:
        """Register; the state is "done" as soon as ``out/`` holds the result and the mesh
        (:meth:`_done`), the report is written after that."""
        try:
            outcome = run_case_dir(
                self.case_dir,
                self.out_dir,
                progress=self._say,
                warm=self.warm,
                on_written=self._done,
            )
        except Exception as exc:
            if self._state != "done":
                raise
            # the result is out already: only its report failed (the page keeps the result)
            log.exception("the report of %s was not written", self.case_dir)
            self._say(f"report not written: {type(exc).__name__}: {one_line(str(exc))}")
            return
        if self._state != "done":  # a multi-bone or multi-frame case: no early result
            self._done(outcome)

    def _work(self) -> None:
        self._say("loading the case")
        try:
            self._register()
        except (ValueError, CommandError, FileNotFoundError) as exc:
            # bad input (CaseError, ...) or a failed registration (CaseFailure): the one-line
            # message names the file and key, as `biplanar-reg register` prints it
            from .session import inside_only  # (no --allow-outside here)

            msg = inside_only(one_line(str(exc)))
            self._say(f"failed: {msg}")
            self._finish("failed", None, msg)
            return
        except Exception as exc:  # noqa: BLE001 - a bug must not kill the server's thread
            log.exception("registration of %s failed", self.case_dir)
            msg = f"internal error: {type(exc).__name__}: {one_line(str(exc))}"
            self._say(f"failed: {msg}")
            self._finish("failed", None, msg)

    def _done(self, outcome: Any) -> None:
        """The result is in ``out/``: the job is done (for the page)."""
        res = outcome.result
        seconds = time.perf_counter() - self._t0
        self._say(f"done in {seconds:.1f} s")
        result = {
            "id": res.id,
            "metrics": res.metrics,
            "flags": res.flags,
            "rejected": res.rejected,
            "seconds": seconds,
            "start": start_entry(res.extra.get("restart"), res.layout == "frames"),
        }
        self._finish("done", result, None)

    def status(self) -> dict[str, Any]:
        """``{"state", "messages", "error"?, "result"?, "run"}`` (``GET /api/register``)."""
        with self._cond:
            out: dict[str, Any] = {
                "state": self._state,
                "messages": list(self._messages),
                "run": self.run,
            }
            if self._error is not None:
                out["error"] = self._error
            if self._result is not None:
                out["result"] = self._result
            return out

    def since(self, run: int, index: int) -> tuple[int, list[str], str, dict[str, Any]]:
        """For a stream of events: ``(run, new messages, state, status)``.

        The messages of run ``run`` from ``index`` on; all of the current run's when another
        run has started since.
        """
        with self._cond:
            start = index if run == self.run else 0
            return self.run, self._messages[start:], self._state, self.status()

    def wait(self, timeout: float) -> None:
        """Block until a message arrives or the state changes (or ``timeout`` seconds)."""
        with self._cond:
            self._cond.wait(timeout)


def start_entry(restart: Mapping[str, Any] | None, frames: bool = False) -> dict[str, Any] | None:
    """Which start a result was registered from, for the page: ``{"start": "warm" | "cold",
    "reason", "text"}`` (``result.json["restart"]``; ``frames``: a multi-frame result, which
    has none; None for another result without it)."""
    restart = restart or {}
    if frames and not restart:
        restart = {"start": "cold", "reason": "a multi-frame case always starts cold"}
    if not isinstance(restart, Mapping) or not restart.get("start"):
        return None
    kind, reason = str(restart["start"]), str(restart.get("reason") or "")
    if kind == "warm":
        text = "warm start: from the previous result"
    else:
        text = "cold start" + (f" ({reason})" if reason else "")
    return {"start": kind, "reason": reason, "text": text}


def view_warnings(name: str, entry: Mapping[str, Any], rejected: list[Any]) -> dict[str, Any]:
    """The registration's warnings about one view, placed: ``{"outline": {"kind":
    "one_sided", "untraced", "covered", "text"} | None, "landmarks": {name: [{"kind":
    "disagrees" | "rejected", "px"?, "text"}]}, "landmark_sigmas_px", "landmark_weights"}``
    from the view's ``result.json`` entry (``outline_coverage``,
    ``landmarks_disagreeing_px``, sigmas and robust weights) and the rejected landmarks
    (``[[view, name], ...]``)."""
    cov = entry.get("outline_coverage") or {}
    outline = None
    if cov.get("one_sided"):
        side = cov.get("untraced")
        where = f"the bone's {side} border" if side else "one border"
        outline = {
            "kind": "one_sided",
            "untraced": side,
            "covered": cov.get("covered"),
            "text": f"one-sided outline: {where} is not traced",
        }
    marks: dict[str, list[dict[str, Any]]] = {}
    for lm, px in (entry.get("landmarks_disagreeing_px") or {}).items():
        text = f"disagrees with the outlines by {float(px):.0f} px"
        marks.setdefault(lm, []).append({"kind": "disagrees", "px": float(px), "text": text})
    for item in rejected:
        if len(item) == 2 and item[0] == name:
            text = "rejected as a blunder: not used in the fit"
            marks.setdefault(str(item[1]), []).append({"kind": "rejected", "text": text})
    return {
        "outline": outline,
        "landmarks": marks,
        "landmark_sigmas_px": entry.get("landmark_sigmas_px") or {},
        "landmark_weights": entry.get("landmark_weights") or {},
    }


def _posed_view(cv: CaseView, entry: ViewResult | None) -> Any:
    """The view with the pose the result used (estimated with ``poses = unknown/refine``)."""
    if entry is None or entry.R is None or entry.t is None:
        return cv.view
    return dataclasses.replace(cv.view, R=entry.R, t=entry.t)


def _warning_entry(entry: ViewResult | None) -> dict[str, Any]:
    """What :func:`view_warnings` reads of a view's result."""
    if entry is None:
        return {}
    return {
        "outline_coverage": entry.outline_coverage,
        "landmarks_disagreeing_px": entry.extra.get("landmarks_disagreeing_px"),
        "landmark_sigmas_px": entry.landmark_sigmas_px,
        "landmark_weights": entry.landmark_weights,
    }


def _view_review(
    cv: CaseView,
    entry: ViewResult | None,
    vertices: np.ndarray,
    faces: np.ndarray | None,
    landmarks: Mapping[str, int],
    rejected: list[Any],
) -> dict[str, Any]:
    """One view's entry of :func:`review`."""
    view = _posed_view(cv, entry)
    lines, closed = outline_polylines(vertices, view, faces)
    names = [n for n, i in landmarks.items() if 0 <= i < len(vertices)]
    ids = np.array([landmarks[n] for n in names], dtype=np.int64)
    uv = view.project(vertices[ids]) if len(ids) else np.zeros((0, 2))
    return {
        "outline_px": [np.round(line, 2).tolist() for line in lines],
        "outline_closed": [bool(c) for c in closed],
        "landmarks_px": {n: np.round(p, 3).tolist() for n, p in zip(names, uv, strict=True)},
        "landmark_errors_px": {} if entry is None else entry.landmark_errors_px,
        "landmark_rms_px": None if entry is None else entry.landmark_rms_px,
        "contour_error_stats_px": None if entry is None else entry.contour_error_stats_px,
        "warnings": view_warnings(cv.name, _warning_entry(entry), rejected),
    }


def review(views: list[CaseView], landmarks: Mapping[str, int], out_dir: Path) -> dict[str, Any]:
    """What the page draws of a registration result.

    Parameters
    ----------
    views : list of CaseView
        The case's views (calibrations); each is posed as ``result.json`` says.
    landmarks : mapping of str to int
        Model landmark name -> vertex index, projected from the registered mesh.
    out_dir : Path
        The output folder of ``biplanar-reg register`` (``result.json``, ``registered.ply``).

    Returns
    -------
    dict
        ``{"id", "views": {name: {"outline_px": [[[u, v], ...], ...], "outline_closed",
        "landmarks_px": {name: [u, v]}, "landmark_errors_px", "landmark_rms_px",
        "contour_error_stats_px", "warnings"}}, "metrics", "flags", "rejected", "certificate",
        "timings", "start"}`` (pixels; outlines by :func:`biplanar_reg.outline.outline_polylines`,
        longest first; ``warnings``: :func:`view_warnings`, ``start``: :func:`start_entry`).
    """
    result = read_result(out_dir / "result.json")
    vertices, faces = read_mesh(out_dir / "registered.ply")
    entries = result.views
    rejected = [list(r) for r in result.rejected or []]
    return {
        "id": result.id,
        "views": {
            cv.name: _view_review(cv, entries.get(cv.name), vertices, faces, landmarks, rejected)
            for cv in views
        },
        "metrics": result.metrics,
        "flags": result.flags,
        "rejected": result.rejected,
        "certificate": result.certificate,
        "timings": result.timings,
        "start": start_entry(result.extra.get("restart"), result.layout == "frames"),
    }
