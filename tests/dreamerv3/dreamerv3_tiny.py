"""The DreamerV3 tests' tiny model: the CPU-sized entry of zoo_configs/dreamerv3.yml (toy/agent-v0: 16x16 frames,
25-step episodes) with a shorter warm-up and the smallest batches."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback

from sb3_ef.zoo.config import default_config_path, load_config

ENTRY = load_config(default_config_path("dreamerv3"))["toy/agent-v0"]
TINY = {key: value for key, value in ENTRY.items() if key not in ("policy", "n_timesteps", "env_kwargs")} | {
    "buffer_size": 500,
    "learning_starts": 8,
    "batch_size": 2,
    "sequence_length": 4,
}


def toy(size: int = 16) -> gym.Env:
    return gym.make("toy/agent-v0", **{**ENTRY["env_kwargs"], "size": size})


def tiny(work_dir: Path, **kwargs: Any) -> Any:
    from sb3_ef.dreamerv3 import DreamerV3

    return DreamerV3("CnnPolicy", toy(), **{**TINY, **kwargs}, work_dir=work_dir, seed=0, device="cpu")


class Recorder(BaseCallback):
    """SB3's calls as a callback sees them: the step of each ``on_step``, the locals at episode ends, the starts and
    ends of training."""

    def __init__(self) -> None:
        super().__init__()
        self.steps: list[int] = []
        self.events: list[str] = []
        self.episode_ends: list[dict[str, Any]] = []

    def _on_training_start(self) -> None:
        self.events.append(f"start at {self.num_timesteps} of {self.locals['total_timesteps']}")

    def _on_step(self) -> bool:
        self.steps.append(self.num_timesteps)
        if self.locals["dones"][0]:
            self.episode_ends.append({key: self.locals[key] for key in ("new_obs", "rewards", "dones", "infos")})
        return True

    def _on_training_end(self) -> None:
        self.events.append("end")
