"""A tiny DAVIS 2017 folder for the Distracting Control tests: real JPEG files in DAVIS's layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sb3_ef.envs.distracting.davis import DAVIS_TRAIN_VIDEOS, DAVIS_VALIDATION_VIDEOS
from tests.envs.davis_files import write_video


@pytest.fixture(scope="session")
def davis_dir(tmp_path_factory) -> Path:
    """``DAVIS/JPEGImages/480p`` with the suite's first 4 training videos (what 'easy' draws from) and its first
    validation video, 4 frames each; returns the ``480p`` folder."""
    root = tmp_path_factory.mktemp("davis") / "DAVIS" / "JPEGImages" / "480p"
    rng = np.random.default_rng(0)
    for video in (*DAVIS_TRAIN_VIDEOS[:4], DAVIS_VALIDATION_VIDEOS[0]):
        write_video(root / video, rng)
    return root
