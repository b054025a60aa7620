"""The Distracting Control Suite's settings, the numbers of its reference code (docs/envs.md); no MuJoCo import."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sb3_ef.common.validation import check_choice, did_you_mean

#: The distractions, in the order they are applied at each reset and step (the reference code's order).
DISTRACTIONS: tuple[str, ...] = ("background", "camera", "color")

#: Difficulty names and the scale ``s`` of the colour and camera ranges.
DIFFICULTY_SCALES: dict[str, float] = {"easy": 0.1, "medium": 0.2, "hard": 0.3}

#: Background videos per difficulty: the first n of the video list (``None``: all of them).
DIFFICULTY_VIDEOS: dict[str, int | None] = {"easy": 4, "medium": 8, "hard": None}

#: Alpha of the floor (material ``grid``) under the background distraction: opaque where it carries the task.
GROUND_PLANE_ALPHA = {"ball_in_cup": 0.3, "cartpole": 0.3, "cheetah": 1.0, "finger": 0.3, "reacher": 0.0, "walker": 1.0}


@dataclass(frozen=True)
class ColorSettings:
    """Colour distraction: every material's RGB within ``max_delta`` of its own, drifting by ``step_std`` per step."""

    max_delta: float
    step_std: float


@dataclass(frozen=True)
class CameraSettings:
    """Camera distraction ranges; ``upper_quadrant`` keeps the camera above the ground on the front, without roll."""

    horizontal_delta: float
    vertical_delta: float
    roll_delta: float
    velocity_std: float
    max_velocity: float
    roll_std: float
    max_roll_velocity: float
    max_zoom_in: float
    max_zoom_out: float
    upper_quadrant: bool


def check_difficulty(difficulty: str) -> float:
    """The scale of ``difficulty``; ``ValueError`` naming the difficulties for another value."""
    check_choice("difficulty", difficulty, DIFFICULTY_SCALES)
    return DIFFICULTY_SCALES[difficulty]


def color_settings(difficulty: str, dynamic: bool) -> ColorSettings:
    """The suite's colour distraction: ``max_delta = s``, ``step_std = 0.03 s`` when dynamic."""
    scale = check_difficulty(difficulty)
    return ColorSettings(max_delta=scale, step_std=0.03 * scale if dynamic else 0.0)


def camera_settings(domain: str, difficulty: str, dynamic: bool) -> CameraSettings:
    """The suite's camera distraction ranges at scale ``s``."""
    scale = check_difficulty(difficulty)
    angle = np.pi / 2 * scale
    return CameraSettings(
        horizontal_delta=angle,
        vertical_delta=angle,
        roll_delta=angle,
        velocity_std=0.1 * scale if dynamic else 0.0,
        max_velocity=0.4 * scale if dynamic else 0.0,
        roll_std=np.pi / 300 * scale if dynamic else 0.0,
        max_roll_velocity=np.pi / 50 * scale if dynamic else 0.0,
        max_zoom_in=0.5 * scale,
        max_zoom_out=1.5 * scale,
        upper_quadrant=domain != "reacher",
    )


def parse_distractions(distraction: str | Sequence[str]) -> tuple[str, ...]:
    """The distractions named by ``distraction`` (one name or a non-empty list, no repeats), in application order."""
    names = [distraction] if isinstance(distraction, str) else distraction
    if not isinstance(names, Sequence) or not names:
        raise ValueError(
            f"distraction must be one of {', '.join(map(repr, DISTRACTIONS))} or a non-empty list of them, "
            f"got {distraction!r}"
        )
    for name in names:
        if name not in DISTRACTIONS:
            hint = did_you_mean(name, DISTRACTIONS) if isinstance(name, str) else ""
            raise ValueError(
                f"Unknown distraction {name!r}{hint}; expected {', '.join(map(repr, DISTRACTIONS))} or a list of them"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"distraction names a distraction twice: {list(names)!r}")
    return tuple(name for name in DISTRACTIONS if name in names)
