"""OpenGL backend choice: set when MUJOCO_GL is unset, a clear error when nothing works."""

import ctypes.util
import os
import subprocess
import sys

import pytest

from sb3_ef.envs import make_env
from sb3_ef.envs.backend import GL_BACKENDS, RenderingBackendError, ensure_gl_backend

CHILD = """
import os
import numpy as np
from sb3_ef.envs import make_env
env = make_env("dmc/cartpole-swingup", size=32)
obs, _ = env.reset(seed=0)
env.close()
print(os.environ["MUJOCO_GL"], obs.std())
"""


def test_backend_is_chosen_when_unset():
    env = {key: value for key, value in os.environ.items() if key not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    result = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    backend, spread = result.stdout.split()
    assert backend in GL_BACKENDS
    assert float(spread) > 5, "the chosen backend must render a real frame"


def test_set_backend_is_respected(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    assert ensure_gl_backend() == "glfw"


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is not None, reason="OSMesa is installed here")
def test_set_backend_without_its_library_names_what_to_install(monkeypatch):
    """Without this check, make_env fails with an AttributeError inside PyOpenGL."""
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    with pytest.raises(RenderingBackendError, match=r"MUJOCO_GL=osmesa needs the OSMesa library.*libosmesa6"):
        make_env("dmc/cartpole-swingup", size=32)


def test_no_working_backend_names_what_to_install(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.delitem(sys.modules, "mujoco", raising=False)
    with pytest.raises(RuntimeError, match=r"Tried MUJOCO_GL=no-such-gl: .*needs libNoSuchGL"):
        ensure_gl_backend({"no-such-gl": "libNoSuchGL"})
    assert "MUJOCO_GL" not in os.environ


def test_mujoco_imported_first_warns(monkeypatch):
    import mujoco  # noqa: F401

    monkeypatch.delenv("MUJOCO_GL")
    with pytest.warns(UserWarning, match="set MUJOCO_GL=egl"):
        assert ensure_gl_backend() == "glfw"
