"""An offscreen OpenGL context for MuJoCo on machines with no display: EGL or OSMesa.

The backend is fixed per process at the first `import OpenGL.GL` (PyOpenGL reads
PYOPENGL_PLATFORM then), so candidates cannot be tried one after the other in-process.
`MUJOCO_GL=egl|osmesa|glfw` picks one explicitly; otherwise each candidate is tried in a
short child process first and the first that creates a context is used here. A
PYOPENGL_PLATFORM already set must agree (it alone, when MUJOCO_GL is unset, is the only
candidate tried).
"""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
import warnings

CANDIDATES = ("egl", "osmesa")
SUPPORTED = ("egl", "osmesa", "glfw")

INSTALL_HINT = {
    "egl": "libEGL with a headless-capable driver (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri, or a GPU driver)",
    "osmesa": "OSMesa (Debian/Ubuntu: apt install libosmesa6)",
    "glfw": "a display (DISPLAY set) and the glfw Python package",
}

_PROBE = (
    "import sys, mujoco.{b} as g\n"
    "c = g.GLContext(16, 16)\n"
    "c.make_current()\n"
    "c.free()\n"
)

_chosen: str | None = None


class RenderBackendError(ValueError):
    """No OpenGL backend could create an offscreen context; the message says what to install."""


def _explain(tried: dict[str, str], platform: str = "") -> str:
    lines = [f"{b}: {why}; needs {INSTALL_HINT[b]}" for b, why in tried.items()]
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested and list(tried) == [requested]:  # the one backend asked for: the others were never tried
        return (f"environment variable MUJOCO_GL={requested} asks for an OpenGL backend that does not work here ("
                f"{lines[0]}); unset MUJOCO_GL to let pursuit-mj try {' and '.join(CANDIDATES)}, or set it to another backend")
    only = f" (the only one tried: environment variable PYOPENGL_PLATFORM={platform} asks for it; unset it to try all)" if platform else ""
    return "no offscreen OpenGL backend works here (" + " | ".join(lines) + ")" + only + "; install one, or set MUJOCO_GL"


def _probe(backend: str, timeout: float = 60.0) -> str | None:
    """None if `backend` creates a context in a child process, else the reason it failed."""
    env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE.format(b=backend)], env=env,
                             capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"probe failed ({exc})"
    if res.returncode == 0:
        return None
    tail = [l for l in res.stderr.strip().splitlines() if l.strip()]
    return tail[-1] if tail else f"exit code {res.returncode}"


def _pinned_platform() -> str | None:
    """The PyOpenGL platform this process is already committed to, if OpenGL.GL is imported."""
    if "OpenGL.GL" in sys.modules:
        return (os.environ.get("PYOPENGL_PLATFORM") or "glfw").lower()
    return None


def choose_backend() -> str:
    """The backend to use in this process (cached). Raises RenderBackendError if none works."""
    global _chosen
    if _chosen is not None:
        return _chosen
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    pinned = _pinned_platform()
    platform = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    if requested:
        if requested not in SUPPORTED:
            raise RenderBackendError(f"environment variable MUJOCO_GL={requested!r}: offscreen rendering needs one of {', '.join(SUPPORTED)}")
        if requested in CANDIDATES and platform not in ("", requested):  # mujoco's EGL/OSMesa loaders refuse it
            raise RenderBackendError(f"environment variables MUJOCO_GL={requested} and PYOPENGL_PLATFORM={platform} disagree: "
                                     f"unset PYOPENGL_PLATFORM, or set it to {requested} too")
        _chosen = requested
        return _chosen
    if pinned is not None:
        _chosen = pinned
        return _chosen
    if platform and platform not in CANDIDATES:
        raise RenderBackendError(f"environment variable PYOPENGL_PLATFORM={platform!r}: offscreen rendering needs "
                                 f"{' or '.join(CANDIDATES)}; unset it, or set MUJOCO_GL and PYOPENGL_PLATFORM both to one of them")
    tried = {}
    for backend in (platform,) if platform else CANDIDATES:  # a platform PyOpenGL is told to use rules the others out
        why = _probe(backend)
        if why is None:
            _chosen = backend
            return backend
        tried[backend] = why
    raise RenderBackendError(_explain(tried, platform))


def create_context(width: int, height: int):
    """A current offscreen GL context of at least width x height pixels (object with make_current, free)."""
    backend = choose_backend()
    if backend in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    try:
        module = importlib.import_module(f"mujoco.{backend}")
        ctx = _glfw_context(module, width, height) if backend == "glfw" else module.GLContext(width, height)
        ctx.make_current()
    except RenderBackendError:  # _glfw_context's, which already names the backend and the reason
        raise
    except Exception as exc:  # PyOpenGL and the EGL/OSMesa loaders raise many error types
        raise RenderBackendError(_explain({backend: f"{type(exc).__name__}: {exc}"})) from exc
    return ctx


def _glfw_context(module, width: int, height: int):
    """mujoco.glfw's context of width x height pixels, or RenderBackendError with GLFW's own reason:
    without a display GLFW only warns (printed on stderr) and makes no window, which MuJoCo then
    takes for a context that cannot draw."""
    import glfw

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", glfw.GLFWError)
        ctx = module.GLContext(width, height)
        ctx.make_current()
        made = bool(glfw.get_current_context())
    if made:
        return ctx
    ctx.free()
    reasons = [re.sub(r"^\(\d+\) b?['\"]?|['\"]$", "", str(w.message)) for w in said if issubclass(w.category, glfw.GLFWError)]
    raise RenderBackendError(_explain({"glfw": reasons[0] if reasons else "GLFW made no window"}))
