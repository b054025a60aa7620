"""Background distraction: a DAVIS video on the skybox, drawn per episode, played back and forth when dynamic."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from sb3_ef.envs.distracting.davis import video_textures
from sb3_ef.envs.renderer import FrameRenderer


class BackgroundDistraction:
    """Shows DAVIS video frames on the skybox (no geom: agent masks never see it) and a ``ground_alpha`` floor.

    :param videos: folders of JPEG frames (:func:`~sb3_ef.envs.distracting.davis.video_folders`), decoded here (once
        per folder and texture size for every process: :func:`~sb3_ef.envs.distracting.davis.video_textures`).
    :param texture_side: side of the sky's face in texels, at most (and by default) the model's; smaller uploads faster.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        videos: tuple[Path, ...],
        dynamic: bool,
        ground_alpha: float,
        texture_side: int | None = None,
    ) -> None:
        self._texture = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, "skybox")
        self._ground = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, "grid")
        if self._texture < 0 or self._ground < 0:
            raise ValueError("The background distraction needs the 'skybox' texture and 'grid' material of DMC models")
        self.videos, self.dynamic, self.ground_alpha = videos, dynamic, ground_alpha
        self._side = int(model.tex_width[self._texture])
        if texture_side is not None:
            self._side = min(self._side, texture_side)
        model.tex_width[self._texture] = self._side
        model.tex_height[self._texture] = self._side  # one square face, shown on all six
        self._start = int(model.tex_adr[self._texture])
        self._textures = [video_textures(video, self._side) for video in videos]  # memory-mapped
        self._frames = self._textures[0][:0]
        self._index, self._direction = 0, 1
        self._shown: int | None = None  # the frame in the model's texture (and on the renderer)

    @property
    def frame(self) -> int:
        """Index of the frame shown, among the episode's frames (all of the video's when dynamic)."""
        return self._index

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Draw the episode's video (and frame, or start frame and direction)."""
        model.mat_rgba[self._ground, 3] = self.ground_alpha
        frames = self._textures[int(rng.integers(len(self._textures)))]
        if not self.dynamic:
            frame = int(rng.integers(len(frames)))
            frames = frames[frame : frame + 1]
        self._frames = frames
        self._index = int(rng.integers(len(frames)))
        self._direction = int(rng.choice([-1, 1]))
        self._shown = None

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """One frame on (dynamic), turning at either end of the video."""
        if not self.dynamic:
            return
        self._index += self._direction
        if self._index <= 0:
            self._index, self._direction = 0, abs(self._direction)
        if self._index >= len(self._frames):  # as in the suite's code, the last frame is shown twice as it turns
            self._index, self._direction = len(self._frames) - 1, -abs(self._direction)

    def show(self, model: mujoco.MjModel, renderer: FrameRenderer) -> None:
        """Put the current frame into the skybox texture and upload it to the renderer, if it changed."""
        if self._shown == self._index:
            return
        model.tex_data[self._start : self._start + self._frames.shape[1]] = self._frames[self._index]
        renderer.upload_texture(self._texture)
        self._shown = self._index
