"""Small synthetic robot videos for the offline tests: a red square moved by 2-D actions over a fixed scene."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_ef.offline.episodes import Episode, make_episode
from sb3_ef.offline.model import OfflineEF
from sb3_ef.offline.pretrain import pretrain

#: A DrQ-v2-encoder model small enough for a few CPU updates per second at 32x32.
TINY_DRQV2: dict[str, Any] = {"encoder": "drqv2", "agent_dim": 8, "encoder_kwargs": {"features_dim": 64}}


def square_episode(steps: int = 20, size: int = 32, seed: int = 0, speed: float = 2.0) -> Episode:
    """Frames (steps + 1, 3, size, size) of a red 6x6 square that moves ``speed`` pixels per unit action, a static
    blue block, and the square's masks."""
    rng = np.random.default_rng(seed)
    actions = rng.choice([-1.0, 1.0], size=(steps, 2)).astype(np.float32)
    frames = np.zeros((steps + 1, 3, size, size), dtype=np.uint8)
    masks = np.zeros((steps + 1, size, size), dtype=bool)
    position = rng.uniform(8, size - 8, 2)
    for t in range(steps + 1):
        x, y = position.astype(int)
        frames[t, 2, 2:8, 2:8] = 180
        frames[t, 0, y - 3 : y + 3, x - 3 : x + 3] = 255
        masks[t, y - 3 : y + 3, x - 3 : x + 3] = True
        if t < steps:
            position = np.clip(position + speed * actions[t], 4, size - 4)
    return make_episode(frames, actions, masks, source=f"square episode {seed}")


def tiny_pretrain(dataset: Any, out_dir: Any, **overrides: Any) -> tuple[OfflineEF, dict]:
    """A couple of updates of the tiny DrQ-v2-encoder model, one held-out episode, no progress bar or TensorBoard."""
    arguments = dict(horizon=3, steps=2, batch_size=4, holdout=1, progress_bar=False, tensorboard=False, **TINY_DRQV2)
    return pretrain(dataset, out_dir, **{**arguments, **overrides})
