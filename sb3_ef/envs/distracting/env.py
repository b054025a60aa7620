"""Distracting Control Suite tasks: DMC pixel envs whose background, colours and camera change (docs/envs.md)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, Protocol

import mujoco
import numpy as np

from sb3_ef.envs.distracting.background import BackgroundDistraction
from sb3_ef.envs.distracting.camera import CameraDistraction
from sb3_ef.envs.distracting.color import ColorDistraction
from sb3_ef.envs.distracting.davis import video_folders
from sb3_ef.envs.distracting.settings import (
    DISTRACTIONS,
    GROUND_PLANE_ALPHA,
    camera_settings,
    check_difficulty,
    color_settings,
    parse_distractions,
)
from sb3_ef.envs.dmc import DMCPixelEnv
from sb3_ef.envs.tasks import DISTRACTING_TASKS

#: With ``fast_render``, the background's texture face has this many texels per frame pixel (capped at the model's).
FAST_TEXELS_PER_PIXEL = 4


class Distraction(Protocol):
    """What the env calls on each distraction: at every reset, then after every simulator step."""

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None: ...

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None: ...


class DistractingDMCPixelEnv(DMCPixelEnv):
    """A Distracting Control task; the other arguments are :class:`~sb3_ef.envs.dmc.DMCPixelEnv`'s.

    :param distraction: ``"background"``, ``"camera"``, ``"color"`` or a list of them (default: all three).
    :param difficulty: ``"easy"``, ``"medium"`` or ``"hard"`` (ranges scaled by 0.1, 0.2, 0.3).
    :param dynamic: distractions move within the episode (the video plays, colours and camera drift).
    :param background_dir: DAVIS 2017's ``DAVIS/JPEGImages/480p`` folder (default ``$SB3_EF_DAVIS_DIR``).
    :param background_videos: ``"train"`` (the suite's 60 videos), ``"val"`` (its 30) or a list of video folders.
    """

    def __init__(
        self,
        task: str,
        distraction: str | Sequence[str] = DISTRACTIONS,
        difficulty: str = "easy",
        dynamic: bool = False,
        background_dir: str | os.PathLike[str] | None = None,
        background_videos: str | Sequence[str] = "train",
        **options: Any,
    ) -> None:
        domain = DISTRACTING_TASKS[task][0]
        self.distractions = parse_distractions(distraction)
        check_difficulty(difficulty)
        if not isinstance(dynamic, (bool, np.bool_)):
            raise ValueError(f"dynamic must be True or False, got {dynamic!r}")
        self.difficulty, self.dynamic = difficulty, bool(dynamic)
        videos = None
        if "background" in self.distractions:
            videos = video_folders(background_dir, background_videos, difficulty)
        elif background_dir is not None or background_videos != "train":
            raise ValueError(
                f"background_dir and background_videos are options of the 'background' distraction, which "
                f"distraction={list(self.distractions)} leaves out"
            )
        super().__init__(task, **options)
        model = self._physics()[0]
        self._background: BackgroundDistraction | None = None
        self._active: list[Distraction] = []
        try:
            if videos is not None:
                side = FAST_TEXELS_PER_PIXEL * self.size if self.fast_render else None
                self._background = BackgroundDistraction(
                    model, videos, self.dynamic, GROUND_PLANE_ALPHA[domain], texture_side=side
                )
                self._active.append(self._background)
            if "camera" in self.distractions:
                self._active.append(CameraDistraction(model, self.camera, camera_settings(domain, difficulty, dynamic)))
            if "color" in self.distractions:
                self._active.append(ColorDistraction(model, color_settings(difficulty, dynamic)))
        except Exception:
            self.close()
            self._env.close()
            raise
        self._distraction_random = np.random.default_rng(0)

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, Any]:
        info = super()._reset_sim(seed, options)
        self._distraction_random = np.random.default_rng(self._simulator_seed())
        model, data = self._physics()
        for distraction in self._active:
            distraction.reset(model, data, self._distraction_random)
        return info

    def _step_sim(self, action: np.ndarray) -> tuple[float, bool, dict[str, Any]]:
        result = super()._step_sim(action)
        model, data = self._physics()
        for distraction in self._active:
            distraction.step(model, data, self._distraction_random)
        return result

    def _render_frame(self) -> np.ndarray:
        if self._background is not None:
            self._background.show(self._physics()[0], self._frame_renderer())
        return super()._render_frame()
