"""Small video folders in DAVIS 2017's layout (real JPEG files) for the Distracting Control tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

#: Frames per test video and their size (DAVIS's are 854 x 480; the env resizes any size to the sky texture).
FRAMES, HEIGHT, WIDTH = 4, 32, 48


def write_video(folder: Path, rng: np.random.Generator, frames: int = FRAMES) -> None:
    """JPEG frames ``00000.jpg, ...`` of smooth random colour fields (JPEG keeps them apart)."""
    folder.mkdir(parents=True)
    for index in range(frames):
        coarse = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
        image = Image.fromarray(coarse).resize((WIDTH, HEIGHT), Image.Resampling.BILINEAR)
        image.save(folder / f"{index:05d}.jpg", quality=95)
