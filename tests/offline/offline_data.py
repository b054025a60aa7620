"""Small synthetic robot videos for the offline tests: a red square moved by 2-D actions over a fixed scene."""

from __future__ import annotations

import numpy as np

from sb3_ef.offline.episodes import Episode, make_episode


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
