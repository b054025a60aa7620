"""Resumable checkpoints (model, replay buffer, random states) with which a resumed run repeats the uninterrupted
one at episode boundaries (see docs/zoo.md)."""

from __future__ import annotations

import json
import os
import pickle
import random
import re
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.type_aliases import GymEnv

from sb3_ef.common.files import write_atomically
from sb3_ef.common.validation import is_intact

ModelType = TypeVar("ModelType", bound=BaseAlgorithm)

RNG_FORMAT = 1


@dataclass(frozen=True)
class Checkpoint:
    """The files of one checkpoint; ``replay_buffer_path`` and ``rng_path`` are ``None`` when not saved."""

    step: int
    model_path: Path
    replay_buffer_path: Path | None
    rng_path: Path | None


def _paths(folder: str | os.PathLike, name_prefix: str, step: int) -> tuple[Path, Path, Path]:
    """Where the model, replay buffer and random states of the checkpoint at ``step`` go."""

    def path(part: str, suffix: str) -> Path:
        return Path(folder, f"{name_prefix}{part}_{step}_steps.{suffix}")

    return path("", "zip"), path("_replay_buffer", "pkl"), path("_rng", "pkl")


def _checkpoint_step(file_name: str, name_prefix: str) -> int | None:
    match = re.fullmatch(rf"{re.escape(name_prefix)}_(\d+)_steps\.zip", file_name)
    return None if match is None else int(match.group(1))


def list_checkpoints(run_dir: str | os.PathLike, name_prefix: str = "rl_model") -> list[Checkpoint]:
    """The complete checkpoints (model zip written) in ``run_dir``, oldest first."""
    found = (_checkpoint_step(path.name, name_prefix) for path in Path(run_dir).glob("*.zip"))
    steps = sorted(step for step in found if step is not None)
    return [_existing(step, *_paths(run_dir, name_prefix, step)) for step in steps]


def _existing(step: int, model_path: Path, *others: Path) -> Checkpoint:
    """The checkpoint at ``step``, without the buffer and random-state files that do not exist."""
    buffer_path, rng_path = (path if path.is_file() else None for path in others)
    return Checkpoint(step, model_path, buffer_path, rng_path)


def latest_checkpoint(
    run_dir: str | os.PathLike, name_prefix: str = "rl_model", intact: bool = False
) -> Checkpoint | None:
    """The newest complete checkpoint in ``run_dir`` or ``None``; ``intact`` passes over damaged zips with a warning."""
    for checkpoint in reversed(list_checkpoints(run_dir, name_prefix)):
        if not intact or is_intact(checkpoint.model_path):
            return checkpoint
        warnings.warn(
            f"Checkpoint {checkpoint.model_path} is damaged (not a readable model zip): using an older one",
            stacklevel=2,
        )
    return None


def checkpoint_for(model_path: str | os.PathLike, name_prefix: str = "rl_model") -> Checkpoint:
    """The checkpoint a model zip belongs to; a final model's is the ``replay_buffer.pkl`` beside it (rl-zoo3's)."""
    path = Path(model_path)
    if not path.is_file():
        raise FileNotFoundError(f"No model zip at {path}")
    with zipfile.ZipFile(path) as archive:
        num_timesteps = int(json.loads(archive.read("data"))["num_timesteps"])
    step = _checkpoint_step(path.name, name_prefix)
    if step is not None:
        return _existing(num_timesteps, *_paths(path.parent, name_prefix, step))
    buffer_path = path.parent / "replay_buffer.pkl"
    return Checkpoint(num_timesteps, path, buffer_path if buffer_path.is_file() else None, None)


def _env_generators(model: BaseAlgorithm) -> list[Any] | None:
    """The bit-generator states of the envs' ``np_random``, or ``None`` when an env has none."""
    env = model.get_env()
    if env is None or not env.has_attr("np_random"):
        return None
    generators = env.get_attr("np_random")
    if not all(isinstance(generator, np.random.Generator) for generator in generators):
        return None
    return [generator.bit_generator.state for generator in generators]


def random_states(model: BaseAlgorithm, env_generators: list[Any] | None = None) -> dict[str, Any]:
    """The random states the learner owns (torch, NumPy, ``random``, action space and noise, envs), picklable."""
    return {
        "format": RNG_FORMAT,
        "num_timesteps": model.num_timesteps,
        "torch": th.get_rng_state(),
        "cuda": th.cuda.get_rng_state_all() if th.cuda.is_available() else None,
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "action_space": model.action_space.np_random.bit_generator.state,
        "action_noise": getattr(model, "action_noise", None),
        "env_generators": env_generators,
    }


def restore_random_states(model: BaseAlgorithm, states: dict[str, Any]) -> None:
    """Set the generators of :func:`random_states` back; the envs' take effect at the reset ``learn`` then does."""
    if states.get("format") != RNG_FORMAT:
        raise ValueError(f"Random-state file format {states.get('format')!r} is not supported: expected {RNG_FORMAT}")
    if states["num_timesteps"] != model.num_timesteps:
        raise ValueError(
            f"Random states were saved at step {states['num_timesteps']} but the model is at step "
            f"{model.num_timesteps}: the files come from different checkpoints"
        )
    env = model.get_env()
    saved_generators = states["env_generators"]
    if env is not None and saved_generators is not None and len(saved_generators) != env.num_envs:
        raise ValueError(f"The checkpoint was saved with {len(saved_generators)} envs, got {env.num_envs}")
    if env is not None:
        # Consume the seeds loading left pending, so that ``learn``'s reset draws from the restored generators.
        env.reset()
        if saved_generators is not None:
            generators = env.get_attr("np_random")
            for index, (generator, state) in enumerate(zip(generators, saved_generators, strict=True)):
                generator.bit_generator.state = state
                env.set_attr("np_random", generator, indices=[index])
    model._last_obs = None
    th.set_rng_state(states["torch"])
    if states["cuda"] is not None and th.cuda.is_available():
        th.cuda.set_rng_state_all(states["cuda"])
    np.random.set_state(states["numpy"])
    random.setstate(states["python"])
    model.action_space.np_random.bit_generator.state = states["action_space"]
    if hasattr(model, "action_noise"):
        model.action_noise = states["action_noise"]


class ResumableCheckpointCallback(BaseCallback):
    """Save a resumable checkpoint every ``save_freq`` calls (``save_freq * n_envs`` timesteps, on ``num_timesteps``).

    :param save_replay_buffer: also save the replay buffer (off-policy algorithms).
    :param keep: how many of the newest checkpoints to keep; ``None`` keeps them all.
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str,
        name_prefix: str = "rl_model",
        save_replay_buffer: bool = True,
        keep: int | None = 2,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        if save_freq < 1:
            raise ValueError(f"save_freq must be >= 1, got {save_freq}")
        if keep is not None and keep < 1:
            raise ValueError(f"keep must be >= 1 (the newest checkpoint) or None (all), got {keep}")
        self.save_freq, self.save_path, self.name_prefix = save_freq, save_path, name_prefix
        self.save_replay_buffer, self.keep = save_replay_buffer, keep
        self._period = self._next_save = save_freq
        self._env_generators: dict[int, list[Any] | None] = {}

    def _init_callback(self) -> None:
        os.makedirs(self.save_path, exist_ok=True)
        self._period = self.save_freq * self.training_env.num_envs
        self._next_save = (self.num_timesteps // self._period + 1) * self._period
        self._env_generators = {}

    def _on_step(self) -> bool:
        # The envs' generators before the step that reaches the next checkpoint (and its reset).
        if self.num_timesteps + self.training_env.num_envs >= self._next_save:
            self._env_generators[self.num_timesteps] = _env_generators(self.model)
        return True

    def _on_rollout_start(self) -> None:
        if self.num_timesteps >= self._next_save:
            self.save()
            self._env_generators = {}
            self._next_save = (self.num_timesteps // self._period + 1) * self._period

    def save(self) -> Checkpoint:
        """Write the checkpoint of the current step (buffer, random states, then the model zip), then prune."""
        model_path, buffer_path, rng_path = _paths(self.save_path, self.name_prefix, self.num_timesteps)
        before = self.num_timesteps - self.training_env.num_envs
        states = random_states(self.model, self._env_generators.get(before))
        saved_buffer = None
        if self.save_replay_buffer and isinstance(self.model, OffPolicyAlgorithm):
            saved_buffer = buffer_path
            write_atomically(buffer_path, self.model.save_replay_buffer)
        write_atomically(rng_path, lambda file: pickle.dump(states, file, protocol=pickle.HIGHEST_PROTOCOL))
        write_atomically(model_path, self.model.save)
        if self.verbose >= 1:
            print(f"Saving checkpoint to {model_path}")
        self._prune()
        return Checkpoint(self.num_timesteps, model_path, saved_buffer, rng_path)

    def _prune(self) -> None:
        if self.keep is None:
            return
        for old in list_checkpoints(self.save_path, self.name_prefix)[: -self.keep]:
            for path in (old.replay_buffer_path, old.rng_path, old.model_path):
                if path is not None:
                    path.unlink(missing_ok=True)


def load_checkpoint(
    algo_class: type[ModelType], checkpoint: Checkpoint, env: GymEnv | None, **kwargs: Any
) -> ModelType:
    """Load ``checkpoint``'s model, buffer and random states, for ``learn(n, reset_num_timesteps=False)``."""
    model = algo_class.load(checkpoint.model_path, env=env, **kwargs)
    if checkpoint.replay_buffer_path is not None:
        if not isinstance(model, OffPolicyAlgorithm):
            raise TypeError(f"{algo_class.__name__} has no replay buffer to load {checkpoint.replay_buffer_path} into")
        model.load_replay_buffer(checkpoint.replay_buffer_path)
    if checkpoint.rng_path is not None:
        with open(checkpoint.rng_path, "rb") as file:
            restore_random_states(model, pickle.load(file))
    else:
        model._last_obs = None  # the saved observation belongs to the old envs
    return model
