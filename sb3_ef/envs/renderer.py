"""Square RGB and segmentation frames from one MuJoCo camera through ``mujoco.Renderer``; import after
``ensure_gl_backend``."""

from __future__ import annotations

import atexit
import os
import time
import weakref
from collections.abc import Callable
from typing import TypeVar

import mujoco
import numpy as np

#: Tries of an OpenGL context's creation or use, 0.5 s then 1 s apart: a machine under heavy load can refuse one.
GL_TRIES = 3
T = TypeVar("T")


def camera_id(model: mujoco.MjModel, camera: int | str) -> int:
    """Resolve a camera index or name to a valid index; raise ``ValueError`` naming the valid cameras."""
    names = [model.camera(index).name for index in range(model.ncam)]
    if isinstance(camera, str) and camera in names:
        return names.index(camera)
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool) and 0 <= camera < model.ncam:
        return int(camera)
    valid = ", ".join(f"{index} ({name!r})" for index, name in enumerate(names))
    raise ValueError(f"Unknown camera {camera!r}: this model's cameras are {valid}")


def _is_gl_failure(error: Exception) -> bool:
    """PyOpenGL's errors (``EGLError``, ...; not imported here), MuJoCo's fatal ones, its backends' context errors."""
    from_opengl = any(kind.__module__.startswith("OpenGL.") for kind in type(error).__mro__)
    return from_opengl or isinstance(error, mujoco.FatalError) or (
        isinstance(error, RuntimeError) and "context" in str(error)
    )


def _described(error: Exception) -> str:
    """The failure without ``str(error)``, which PyOpenGL's errors can fail to give ("<exception str() failed>")."""
    code, operation = vars(error).get("err"), getattr(getattr(error, "baseOperation", None), "__name__", None)
    details = [f"error {code:#x}" if isinstance(code, int) else None, f"in {operation}" if operation else None]
    details += [repr(error.args[0])] if error.args else []
    return " ".join([type(error).__name__, *filter(None, details)])


def with_gl_retries(what: str, call: Callable[[], T]) -> T:
    """``call()``, tried :data:`GL_TRIES` times while OpenGL fails; then a ``RuntimeError`` naming the failure."""
    attempt = 1
    while True:
        try:
            return call()
        except Exception as error:
            if not _is_gl_failure(error):
                raise
            if attempt == GL_TRIES:
                raise RuntimeError(
                    f"MuJoCo's OpenGL rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'glfw')}) failed to {what} "
                    f"{GL_TRIES} times: {_described(error)}. A machine under heavy load (or out of GPU memory) can "
                    "refuse an OpenGL context: run fewer processes at once, then resume the run"
                ) from error
        time.sleep(0.5 * attempt)
        attempt += 1


_LIVE_RENDERERS: weakref.WeakSet[FrameRenderer] = weakref.WeakSet()


def _close_live_renderers() -> None:
    for renderer in list(_LIVE_RENDERERS):
        renderer.close()


def _close_renderers_at_exit() -> None:
    """Re-register the exit hook as the newest, so that it runs before any ``eglTerminate`` (``atexit`` is LIFO)."""
    atexit.unregister(_close_live_renderers)
    atexit.register(_close_live_renderers)


class FrameRenderer:
    """Renders ``(size, size, 3)`` uint8 frames and agent masks of a model's state from one camera.

    :param fast: turn shadows, reflections and multisampling off (5-15x faster on a CPU renderer).
    :param flip: flip frames vertically (for cameras that render upside down).
    :param agent_geoms: boolean array over the model's geoms marking the agent's body.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        size: int,
        camera: int | str,
        fast: bool = False,
        flip: bool = False,
        agent_geoms: np.ndarray | None = None,
    ) -> None:
        self.camera = camera_id(model, camera)
        self.flip = flip
        self._model = model
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, size)
        model.vis.global_.offheight = max(model.vis.global_.offheight, size)
        if fast:
            model.vis.quality.shadowsize = 0
            model.vis.quality.offsamples = 0
        self._renderer = with_gl_retries("create a context", lambda: mujoco.Renderer(model, size, size))
        if fast:
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        # Index 0 stands for "no geom" (segmentation id -1), so geom g is looked up at g + 1.
        geoms = np.zeros(model.ngeom, bool) if agent_geoms is None else np.asarray(agent_geoms, bool)
        self._agent_lookup = np.concatenate([[False], geoms])
        # Frees the GL context at close(), at collection, or at exit through _close_renderers_at_exit.
        self._finalizer = weakref.finalize(self, self._renderer.close)
        self._finalizer.atexit = False
        _LIVE_RENDERERS.add(self)
        _close_renderers_at_exit()

    def _orient(self, image: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(image[::-1]) if self.flip else image

    def rgb(self, data: mujoco.MjData) -> np.ndarray:
        """The ``(size, size, 3)`` uint8 frame of the current state."""
        self._renderer.update_scene(data, camera=self.camera)
        return self._orient(with_gl_retries("render a frame", self._renderer.render))

    def geom_ids(self, data: mujoco.MjData) -> np.ndarray:
        """The ``(size, size)`` int array of the geom id seen at each pixel in the current state, -1 where none."""
        self._renderer.update_scene(data, camera=self.camera)
        self._renderer.enable_segmentation_rendering()
        try:
            segmentation = with_gl_retries("render a segmentation", self._renderer.render)
        finally:
            self._renderer.disable_segmentation_rendering()
        geom_ids = np.where(segmentation[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, segmentation[..., 0], -1)
        return self._orient(geom_ids)

    def agent_mask(self, data: mujoco.MjData) -> np.ndarray:
        """The ``(size, size)`` bool mask of pixels showing agent geoms in the current state."""
        return self._agent_lookup[self.geom_ids(data) + 1]

    def upload_texture(self, texture: int) -> None:
        """Send the model's changed ``texture`` to this renderer's OpenGL context (``mujoco.Renderer`` has no call)."""

        def upload() -> None:
            self._renderer._gl_context.make_current()
            mujoco.mjr_uploadTexture(self._model, self._renderer._mjr_context, texture)

        with_gl_retries("upload a texture", upload)

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        self._finalizer()
