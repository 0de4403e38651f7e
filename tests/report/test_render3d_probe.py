"""The 3D view is PyVista's, off screen, once a child process has rendered with VTK here (once
per process): without EGL, OSMesa or an X display, VTK's off-screen window kills the process
with SIGSEGV instead of raising. Where the child fails, the view is drawn with matplotlib and a
warning in ``result.json`` says why."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _mesh():
    from biplanar_reg.simulate import synthetic_bone_model

    return synthetic_bone_model(2)


def test_missing_backend_falls_back_without_calling_vtk(tmp_path, monkeypatch, caplog):
    from biplanar_reg.report import render3d

    calls = []

    def vtk_render(*args, **kwargs):  # would crash the process where the probe failed
        calls.append(args)

    monkeypatch.setattr(
        render3d, "offscreen_rendering_available", lambda: (False, "a test render crashed")
    )
    monkeypatch.setattr(render3d, "render_pyvista", vtk_render)
    m = _mesh()
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        used, warning = render3d.render_surface(tmp_path / "e.png", m.mean, m.faces, None, "t")
    assert used == "matplotlib" and not calls
    assert (tmp_path / "e.png").stat().st_size > 1000
    assert "\n" not in warning and "a test render crashed" in warning
    assert "drawn with matplotlib" in warning and "libegl1" in warning
    assert not caplog.records  # returned for result.json, not logged here


class _FakeChild:
    """What the probe reads of a child process: ``communicate`` and ``returncode``."""

    def __init__(self, returncode=0, stdout="", stderr="", hang=False):
        self.returncode, self.out, self.hang, self.killed = returncode, (stdout, stderr), hang, 0

    def communicate(self, timeout=None):
        if self.hang and not self.killed:
            raise subprocess.TimeoutExpired("python", timeout)
        return self.out

    def kill(self):
        self.killed += 1


def _fake_popen(monkeypatch, child):
    from biplanar_reg.report import gl_probe

    started = []

    def popen(cmd, **kwargs):
        started.append(kwargs["env"])
        return child

    monkeypatch.setattr(gl_probe, "_cache", {})
    monkeypatch.setattr(gl_probe, "_running", {})
    monkeypatch.setattr(gl_probe.subprocess, "Popen", popen)
    return gl_probe, started


def test_probe_runs_once_per_process_and_names_the_crash(monkeypatch):
    child = _FakeChild(-11, stderr="\x1b[33mWARN| Failed to initialize OpenGL\x1b[0m\n")
    gl_probe, started = _fake_popen(monkeypatch, child)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    gl_probe.start_probe()
    gl_probe.start_probe()  # already running: not started twice
    ok, why = gl_probe.offscreen_rendering_available()
    assert not ok and "SIGSEGV" in why
    assert gl_probe.offscreen_rendering_available() == (ok, why)
    assert len(started) == 1  # cached
    # the child asks for the window the renderer will use (EGL when there is no display)
    assert started[0]["VTK_DEFAULT_OPENGL_WINDOW"] == "vtkEGLRenderWindow"


@pytest.mark.parametrize(
    ("child", "ok", "reason"),
    [
        (_FakeChild(0, stdout="ok vtkEGLRenderWindow\n"), True, "vtkEGLRenderWindow"),
        (_FakeChild(1, stderr="\x1b[31mERR| no module vtk\x1b[0m\n"), False, "no module vtk"),
        (_FakeChild(hang=True), False, "did not finish"),
    ],
)
def test_probe_outcomes(monkeypatch, child, ok, reason):
    gl_probe, _ = _fake_popen(monkeypatch, child)
    got_ok, why = gl_probe.offscreen_rendering_available()
    assert got_ok is ok and reason in why and "\x1b" not in why
    assert child.killed == (1 if child.hang else 0)  # a hung child is killed


def _without_egl(tmp_path: Path) -> dict[str, str]:
    """The environment of a machine with no usable EGL, OSMesa or X display: no ``DISPLAY``,
    and libglvnd pointed at an empty folder of EGL vendor libraries (it finds none, as where
    no EGL driver is installed); VTK is asked for its EGL window, so it does not go on to
    OSMesa either."""
    (tmp_path / "no_egl_vendors").mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(
        __EGL_VENDOR_LIBRARY_DIRS=str(tmp_path / "no_egl_vendors"),
        VTK_DEFAULT_OPENGL_WINDOW="vtkEGLRenderWindow",
        PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]),
    )
    return env


def test_register_without_egl_or_osmesa_writes_the_fallback_view(tmp_path):
    """The real thing, end to end: ``biplanar-reg register`` where VTK cannot render (the probe
    child dies of SIGSEGV): exit 0, the report written with the matplotlib 3D view, and the
    warning in ``result.json`` and on the page."""
    case = Path(shutil.copytree(ROOT / "sample_cases" / "synthetic_demo", tmp_path / "case"))
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "biplanar_reg.cli", "register", str(case), "--out", str(out)],
        env=_without_egl(tmp_path),
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, f"exit {proc.returncode}: {proc.stderr[-2000:]}"
    doc = json.loads((out / "result.json").read_text())
    assert doc["report"]["renderer"] == "matplotlib"
    (warning,) = [w for w in doc["warnings"] if "3D view" in w]
    assert "drawn with matplotlib" in warning and "crashed (SIGSEGV)" in warning
    view = doc["report"]["figures"][0]
    assert view in ("error_3d.png", "registered_3d.png") and (out / view).stat().st_size > 10000
    assert "3D view drawn with matplotlib" in (out / "report.html").read_text()


def test_pyvista_is_the_default_where_it_can_render(tmp_path):
    """Where the probe renders, the report's 3D view is PyVista's and there is no warning."""
    from biplanar_reg.report.gl_probe import offscreen_rendering_available
    from biplanar_reg.report.render3d import render_surface

    ok, why = offscreen_rendering_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL here: {why}")
    m = _mesh()
    used, warning = render_surface(tmp_path / "e.png", m.mean, m.faces, None, "t")
    assert (used, warning) == ("pyvista", None) and (tmp_path / "e.png").stat().st_size > 1000
