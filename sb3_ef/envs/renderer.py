"""Square RGB and segmentation frames from one MuJoCo camera through ``mujoco.Renderer``; import after
``ensure_gl_backend``."""

from __future__ import annotations

import atexit
import weakref

import mujoco
import numpy as np


def camera_id(model: mujoco.MjModel, camera: int | str) -> int:
    """Resolve a camera index or name to a valid index; raise ``ValueError`` naming the valid cameras."""
    names = [model.camera(index).name for index in range(model.ncam)]
    if isinstance(camera, str) and camera in names:
        return names.index(camera)
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool) and 0 <= camera < model.ncam:
        return int(camera)
    valid = ", ".join(f"{index} ({name!r})" for index, name in enumerate(names))
    raise ValueError(f"Unknown camera {camera!r}: this model's cameras are {valid}")


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
        self._renderer = mujoco.Renderer(model, size, size)
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
        return self._orient(self._renderer.render())

    def geom_ids(self, data: mujoco.MjData) -> np.ndarray:
        """The ``(size, size)`` int array of the geom id seen at each pixel in the current state, -1 where none."""
        self._renderer.update_scene(data, camera=self.camera)
        self._renderer.enable_segmentation_rendering()
        try:
            segmentation = self._renderer.render()
        finally:
            self._renderer.disable_segmentation_rendering()
        geom_ids = np.where(segmentation[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, segmentation[..., 0], -1)
        return self._orient(geom_ids)

    def agent_mask(self, data: mujoco.MjData) -> np.ndarray:
        """The ``(size, size)`` bool mask of pixels showing agent geoms in the current state."""
        return self._agent_lookup[self.geom_ids(data) + 1]

    def upload_texture(self, texture: int) -> None:
        """Send the model's changed ``texture`` to this renderer's OpenGL context (``mujoco.Renderer`` has no call)."""
        self._renderer._gl_context.make_current()
        mujoco.mjr_uploadTexture(self._model, self._renderer._mjr_context, texture)

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        self._finalizer()
