"""Can VTK render off-screen here? Asked once per process, in a short child process.

This is what decides whether the report's 3D view is rendered by PyVista (:mod:`.render3d`):
VTK is never called in the report's own process before this child has rendered successfully.

Where neither an X display, EGL nor OSMesa is usable, creating VTK's off-screen render window
does not raise an exception: VTK logs "Failed to initialize OpenGL functions!" and the process
dies with a segmentation fault (measured with VTK 9.7.2 and libglvnd finding no EGL vendor
library). Nothing in the process can catch that, so before PyVista renders, a child Python
process creates the same window (the same environment, :func:`offscreen_env`), renders an
8 x 8 image and reads it back. Its outcome is cached per process and per the environment
variables that choose the OpenGL library (about 0.4 CPU s, once). :func:`start_probe` starts the
child without waiting for it, so that it runs while the report draws its 2D figures. A batch
checks once for all its worker processes (:func:`checked_outcome` in the batch,
:func:`adopt_outcome` in each worker it starts, with the batch's environment): same machine,
same libraries, same environment. The outcome is never stored in a file: a stale one could
crash a later run.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping, Sequence

__all__ = [
    "adopt_outcome",
    "checked_outcome",
    "offscreen_env",
    "offscreen_rendering_available",
    "start_probe",
]

#: Seconds the child process may take (it needs about 0.4 CPU s; more wall time on a busy
#: machine).
PROBE_TIMEOUT_S = 30.0

#: Environment variables that decide which OpenGL library VTK ends up with (the cache key).
_ENV_KEYS = (
    "DISPLAY",
    "WAYLAND_DISPLAY",
    "VTK_DEFAULT_OPENGL_WINDOW",
    "LD_LIBRARY_PATH",
    "LD_PRELOAD",
    "__EGL_VENDOR_LIBRARY_DIRS",
    "__EGL_VENDOR_LIBRARY_FILENAMES",
    "EGL_PLATFORM",
    "LIBGL_ALWAYS_SOFTWARE",
    "GALLIUM_DRIVER",
)

_PROBE = """
import vtkmodules.vtkRenderingOpenGL2
from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow, vtkWindowToImageFilter
window = vtkRenderWindow()
window.SetOffScreenRendering(1)
window.SetSize(8, 8)
window.AddRenderer(vtkRenderer())
window.Render()
grab = vtkWindowToImageFilter()
grab.SetInput(window)
grab.Update()
assert grab.GetOutput().GetDimensions()[:2] == (8, 8)
print("ok", window.GetClassName())
window.Finalize()
"""

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")

#: Outcomes per environment key, and children still running (both under ``_lock``, held
#: briefly; the report and :mod:`.prepare`'s thread may ask at once). One thread at a time waits
#: for a child (``_collecting``); the others then find its outcome.
_cache: dict[tuple[str | None, ...], tuple[bool, str]] = {}
_running: dict[tuple[str | None, ...], subprocess.Popen] = {}
_lock = threading.Lock()
_collecting = threading.Lock()


def offscreen_env(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment PyVista renders in: ``environ`` (default ``os.environ``) with, when
    there is no ``DISPLAY``, ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` unless it is set
    (VTK's X11 window fails without a display; it would fall back to EGL anyway)."""
    env = dict(os.environ if environ is None else environ)
    if not env.get("DISPLAY"):
        env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    return env


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in _ANSI.sub("", text).splitlines() if ln.strip()]
    return lines[-1][-200:] if lines else "no message"


def _start(env: dict[str, str]) -> subprocess.Popen | tuple[bool, str]:
    """The probe's child process, started; ``(False, why)`` when it cannot start."""
    try:
        return subprocess.Popen(
            [sys.executable, "-c", _PROBE],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    except OSError as exc:
        return False, f"cannot start a test render ({exc})"


def _finish(proc: subprocess.Popen, timeout: float) -> tuple[bool, str]:
    """Wait for the probe's child (killed after ``timeout`` s) and read its outcome."""
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return False, f"a test render did not finish in {timeout:g} s"
    if proc.returncode == 0 and stdout.startswith("ok"):
        return True, f"test render with {stdout.split()[-1]}"
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        return False, f"a test render crashed ({name}): no usable EGL, OSMesa or X display"
    return False, f"a test render failed (exit {proc.returncode}: {_last_line(stderr)})"


def _key(env: Mapping[str, str]) -> tuple[str | None, ...]:
    """The cache key of ``env``: its values of :data:`_ENV_KEYS`, ``LD_LIBRARY_PATH`` without
    repeated folders (the loader searches the same folders in the same order; importing OpenCV
    prepends its folder to the variable again in each process that imports it)."""
    values = dict.fromkeys(_ENV_KEYS)
    values.update((k, env[k]) for k in _ENV_KEYS if k in env)
    if values["LD_LIBRARY_PATH"] is not None:
        values["LD_LIBRARY_PATH"] = ":".join(dict.fromkeys(values["LD_LIBRARY_PATH"].split(":")))
    return tuple(values.values())


def start_probe() -> None:
    """Start the probe's child for the current environment unless its outcome is known or it
    is running already; returns at once (:func:`offscreen_rendering_available` collects it)."""
    env = offscreen_env()
    key = _key(env)
    with _lock:
        if key in _cache or key in _running:
            return
        started = _start(env)
        if isinstance(started, tuple):
            _cache[key] = started
        else:
            _running[key] = started


def offscreen_rendering_available(timeout: float = PROBE_TIMEOUT_S) -> tuple[bool, str]:
    """``(True, what rendered)`` when VTK can render off-screen in this environment, else
    ``(False, why)`` (one line). Runs the child process once per process and environment
    (waits for the one :func:`start_probe` started)."""
    start_probe()
    key = _key(offscreen_env())
    with _collecting:
        with _lock:
            if key in _cache:
                return _cache[key]
            proc = _running[key]
        outcome = _finish(proc, timeout)
        with _lock:
            _cache[key] = outcome
            del _running[key]
        return outcome


#: An environment key and the outcome of the check in it, as passed between processes.
Outcome = tuple[tuple[str | None, ...], tuple[bool, str]]


def checked_outcome() -> Outcome:
    """This process's environment key and the outcome of
    :func:`offscreen_rendering_available` in it (runs the check, or waits for it), for
    :func:`adopt_outcome` in processes started with the same environment."""
    outcome = offscreen_rendering_available()
    return _key(offscreen_env()), outcome


def adopt_outcome(key: Sequence[str | None], outcome: tuple[bool, str]) -> None:
    """Take ``outcome``, found by the process that started this one for the environment
    ``key`` (:func:`checked_outcome`), as this process's own. Ignored when this process's
    environment gives another key (it then checks for itself) or knows its outcome already."""
    key = tuple(key)
    if key == _key(offscreen_env()):
        with _lock:
            _cache.setdefault(key, (bool(outcome[0]), str(outcome[1])))
