"""Choice of MuJoCo's headless OpenGL backend, each candidate tried in a subprocess (a failure can abort it)."""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys
import warnings

#: Backends tried in order when ``MUJOCO_GL`` is unset, with what to install when they are missing.
GL_BACKENDS: dict[str, str] = {
    "egl": "libEGL with a working driver (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri)",
    "osmesa": "OSMesa (Debian/Ubuntu: apt install libosmesa6)",
}

#: The shared library each backend loads (``ctypes.util.find_library`` names), checked when MUJOCO_GL is set.
GL_LIBRARIES: dict[str, str] = {"egl": "EGL", "osmesa": "OSMesa"}


class RenderingBackendError(RuntimeError):
    """No usable headless OpenGL backend: the message says what to install or set."""


_PROBE = "import mujoco; context = mujoco.GLContext(8, 8); context.make_current(); context.free()"


def _backend_works(backend: str) -> tuple[bool, str]:
    """Create and free a tiny MuJoCo GL context with ``backend`` in a fresh interpreter."""
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        result = subprocess.run(
            [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120, check=False
        )
    except subprocess.TimeoutExpired:
        return False, "timed out"
    lines = result.stderr.strip().splitlines()
    return result.returncode == 0, lines[-1] if lines else f"exit code {result.returncode}"


def ensure_gl_backend(candidates: dict[str, str] | None = None) -> str:
    """The ``MUJOCO_GL`` backend in use, else the first of ``candidates`` that works, set; else what to install."""
    chosen = os.environ.get("MUJOCO_GL")
    if chosen:
        library = GL_LIBRARIES.get(chosen)
        if library is not None and ctypes.util.find_library(library) is None:
            raise RenderingBackendError(
                f"MUJOCO_GL={chosen} needs the {library} library, which is not installed: install "
                f"{GL_BACKENDS[chosen]}, or set MUJOCO_GL to another backend (egl, osmesa, glfw with a display)"
            )
        return chosen
    if "mujoco" in sys.modules:
        warnings.warn(
            "mujoco was imported before MUJOCO_GL was set, so its default (GLFW, needs a display) is in use; "
            "set MUJOCO_GL=egl (or osmesa) before importing mujoco for headless rendering."
        )
        return "glfw"
    failures = []
    for backend, hint in (GL_BACKENDS if candidates is None else candidates).items():
        works, reason = _backend_works(backend)
        if works:
            os.environ["MUJOCO_GL"] = backend
            return backend
        failures.append(f"{backend}: {reason} (needs {hint})")
    raise RenderingBackendError(
        "No headless OpenGL backend works for MuJoCo rendering. Tried MUJOCO_GL="
        + "; ".join(failures)
        + ". Install one of them, or set MUJOCO_GL yourself."
    )
