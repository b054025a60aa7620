"""Renderer: camera resolution errors, OpenGL failures retried then named, and a clean interpreter exit (no EGL
tracebacks)."""

import os
import subprocess
import sys

import mujoco
import pytest

from sb3_ef.envs.renderer import GL_TRIES, camera_id, with_gl_retries

TWO_CAMERAS = """
<mujoco><worldbody>
  <camera name="front" pos="0 -1 0" xyaxes="1 0 0 0 0 1"/>
  <camera name="top" pos="0 0 1"/>
  <geom type="sphere" size="0.1"/>
</worldbody></mujoco>
"""

EXIT_CHILD = """
import weakref
import numpy as np
# Like many libraries (tempfile, multiprocessing), register weakref's exit hook before MuJoCo registers EGL's.
weakref.finalize(weakref.WeakSet(), print)
from sb3_ef.envs import make_env
closed = make_env({first!r}, size=32)
left_open = make_env({second!r}, size=32)
for env in (closed, left_open):
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, np.float32))
    env.agent_mask()
closed.close()
print("ok")
"""


def test_camera_by_index_or_name():
    model = mujoco.MjModel.from_xml_string(TWO_CAMERAS)
    assert camera_id(model, "top") == 1
    assert camera_id(model, 0) == 0


@pytest.mark.parametrize("camera", [2, -1, "side", True, 1.0])
def test_unknown_camera_lists_valid_ones(camera):
    model = mujoco.MjModel.from_xml_string(TWO_CAMERAS)
    with pytest.raises(ValueError, match=r"cameras are 0 \('front'\), 1 \('top'\)"):
        camera_id(model, camera)


class Unprintable:
    def __repr__(self) -> str:
        raise RuntimeError("no repr")


@pytest.mark.skipif(os.environ.get("MUJOCO_GL") != "egl", reason="an EGL context")
def test_an_egl_failure_is_retried_and_a_lasting_one_named():
    from OpenGL.EGL import eglMakeCurrent
    from OpenGL.raw.EGL._errors import EGLError

    # EGL_BAD_ALLOC as a crashed resume raised it: its str() fails ("<exception str() failed>" in the traceback)
    failure = EGLError(err=0x3003, baseOperation=eglMakeCurrent, cArguments=(Unprintable(),))
    with pytest.raises(RuntimeError, match="no repr"):
        str(failure)
    model = mujoco.MjModel.from_xml_string(TWO_CAMERAS)
    tries = []

    def create() -> mujoco.Renderer:
        tries.append(len(tries))
        if len(tries) < GL_TRIES:
            raise failure
        return mujoco.Renderer(model, 16, 16)

    renderer = with_gl_retries("create a context", create)
    renderer.update_scene(mujoco.MjData(model))
    assert renderer.render().shape == (16, 16, 3) and len(tries) == GL_TRIES
    renderer.close()

    def fail() -> None:
        raise failure

    message = r"MUJOCO_GL=egl\) failed to render a frame 3 times: EGLError error 0x3003 in eglMakeCurrent\. A machine"
    with pytest.raises(RuntimeError, match=message):
        with_gl_retries("render a frame", fail)
    with pytest.raises(ValueError, match="not OpenGL's"):  # other errors pass at once
        with_gl_retries("render a frame", lambda: int("not OpenGL's"))


# Either order: the suite made second imports dm_control's renderer (and its exit hook) after ours was registered.
@pytest.mark.parametrize("first, second", [("dmc/cartpole-swingup", "metaworld/door-open"),
                                           ("metaworld/door-open", "dmc/cartpole-swingup")])  # fmt: skip
def test_interpreter_exit_prints_no_egl_traceback(first, second):
    result = subprocess.run(
        [sys.executable, "-c", EXIT_CHILD.format(first=first, second=second)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "MUJOCO_GL": "egl"},
    )
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr
    assert "EGLError" not in result.stderr
    assert "Traceback" not in result.stderr
