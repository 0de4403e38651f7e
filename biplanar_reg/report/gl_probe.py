"""Can VTK render off-screen here? Asked once per process, in a short child process.

Where neither an X display, EGL nor OSMesa is usable, creating VTK's off-screen render window
does not raise an exception: VTK logs "Failed to initialize OpenGL functions!" and the process
dies with a segmentation fault (measured with VTK 9.7.2 and libglvnd finding no EGL vendor
library). Nothing in the process can catch that, so before PyVista renders, a child Python
process creates the same window (the same environment, :func:`offscreen_env`), renders an
8 x 8 image and reads it back. Its outcome is cached per process and per the environment
variables that choose the OpenGL library (about 1 s, once).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from collections.abc import Mapping

__all__ = ["offscreen_env", "offscreen_rendering_available"]

#: Seconds the child process may take (it needs about 1 s).
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

_cache: dict[tuple[str | None, ...], tuple[bool, str]] = {}


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


def _probe(env: dict[str, str], timeout: float) -> tuple[bool, str]:
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE],
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return False, f"a test render did not finish in {timeout:g} s"
    except OSError as exc:
        return False, f"cannot start a test render ({exc})"
    if proc.returncode == 0 and proc.stdout.startswith("ok"):
        return True, f"test render with {proc.stdout.split()[-1]}"
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        return False, f"a test render crashed ({name}): no usable EGL, OSMesa or X display"
    return False, f"a test render failed (exit {proc.returncode}: {_last_line(proc.stderr)})"


def offscreen_rendering_available(timeout: float = PROBE_TIMEOUT_S) -> tuple[bool, str]:
    """``(True, what rendered)`` when VTK can render off-screen in this environment, else
    ``(False, why)`` (one line). Runs the child process once per process and environment."""
    env = offscreen_env()
    key = tuple(env.get(k) for k in _ENV_KEYS)
    if key not in _cache:
        _cache[key] = _probe(env, timeout)
    return _cache[key]
