"""The PyVista renderer asks first whether off-screen OpenGL works here (a short subprocess,
once per process) and falls back to the software renderer when it does not: without EGL,
OSMesa or an X display, VTK's off-screen window kills the process with SIGSEGV instead of
raising."""

from __future__ import annotations

import importlib.util
import logging
import os
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

    monkeypatch.setenv("BIPLANAR_REG_RENDERER", "pyvista")
    monkeypatch.setattr(
        render3d, "offscreen_rendering_available", lambda: (False, "a test render crashed")
    )
    monkeypatch.setattr(render3d, "render_pyvista", vtk_render)
    m = _mesh()
    with caplog.at_level(logging.WARNING, logger="biplanar_reg"):
        used = render3d.render_error_mesh(tmp_path / "e.png", m.mean, m.faces, None, "t")
    assert used == "software" and not calls
    assert (tmp_path / "e.png").stat().st_size > 1000
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert "a test render crashed" in warnings[0] and "using software" in warnings[0]


def _completed(returncode: int, stdout: str = "", stderr: str = ""):
    return subprocess.CompletedProcess(["python"], returncode, stdout, stderr)


def test_probe_runs_once_per_process_and_names_the_crash(monkeypatch):
    from biplanar_reg.report import gl_probe

    runs = []

    def fake_run(cmd, **kwargs):
        runs.append(kwargs["env"])
        return _completed(-11, stderr="\x1b[33mWARN| Failed to initialize OpenGL\x1b[0m\n")

    monkeypatch.setattr(gl_probe, "_cache", {})
    monkeypatch.setattr(gl_probe.subprocess, "run", fake_run)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    ok, why = gl_probe.offscreen_rendering_available()
    assert not ok and "SIGSEGV" in why
    assert gl_probe.offscreen_rendering_available() == (ok, why)
    assert len(runs) == 1  # cached
    # the child asks for the window the renderer will use (EGL when there is no display)
    assert runs[0]["VTK_DEFAULT_OPENGL_WINDOW"] == "vtkEGLRenderWindow"


@pytest.mark.parametrize(
    ("result", "ok", "reason"),
    [
        (_completed(0, stdout="ok vtkEGLRenderWindow\n"), True, "vtkEGLRenderWindow"),
        (_completed(1, stderr="\x1b[31mERR| no module vtk\x1b[0m\n"), False, "no module vtk"),
        (subprocess.TimeoutExpired("python", 30), False, "did not finish"),
    ],
)
def test_probe_outcomes(monkeypatch, result, ok, reason):
    from biplanar_reg.report import gl_probe

    def fake_run(cmd, **kwargs):
        if isinstance(result, BaseException):
            raise result
        return result

    monkeypatch.setattr(gl_probe, "_cache", {})
    monkeypatch.setattr(gl_probe.subprocess, "run", fake_run)
    got_ok, why = gl_probe.offscreen_rendering_available()
    assert got_ok is ok and reason in why and "\x1b" not in why


SCRIPT = """
import numpy as np
from biplanar_reg.report.render3d import render_error_mesh
from biplanar_reg.simulate import synthetic_bone_model
m = synthetic_bone_model(2)
print(render_error_mesh({path!r}, m.mean, m.faces, None, "t"))
"""


@pytest.mark.skipif(importlib.util.find_spec("pyvista") is None, reason="PyVista not installed")
def test_no_egl_vendor_does_not_kill_the_process(tmp_path):
    """The real thing: with no display and no EGL vendor library (libglvnd finds none),
    VTK's EGL window segfaults; the report must survive and say which renderer it used."""
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    env.update(
        BIPLANAR_REG_RENDERER="pyvista",
        __EGL_VENDOR_LIBRARY_DIRS=str(tmp_path / "none"),
        PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]),
    )
    path = tmp_path / "e.png"
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(path=str(path))],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, f"exit {proc.returncode}: {proc.stderr[-2000:]}"
    used = proc.stdout.split()[-1]
    assert used in ("software", "pyvista") and path.stat().st_size > 1000
    if used == "software":  # EGL really missing: one warning line says why
        assert "PyVista off-screen rendering is not available" in proc.stderr
