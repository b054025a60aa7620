"""``DreamerV3``: sheeprl's Dreamer-v3 (networks, replay buffer and training loop, in this process) behind SB3's
learn / predict / save / load. A callback returning ``False`` stops the run with the newest evaluation's weights."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ProgressBarCallback
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.precision import check_precision
from sb3_ef.common.validation import check_device
from sb3_ef.dreamerv3 import live
from sb3_ef.dreamerv3.callbacks import Evaluation, RunCallback, read_latest
from sb3_ef.dreamerv3.config import (
    SHEEPRL_VERSION,
    Recipe,
    Session,
    compose_config,
    fabric_device,
    require_sheeprl,
)
from sb3_ef.dreamerv3.env import NewestFrame, StepCallbacks, StopTraining, check_frame_size, task_id
from sb3_ef.dreamerv3.player import Player, forked_rng
from sb3_ef.dreamerv3.saving import PathOrFile, read_model, write_model
from sb3_ef.dreamerv3.training import resolved_config, run

#: The only policy: sheeprl's networks, sized by ``model_size``.
POLICY = "CnnPolicy"


class DreamerV3:
    """Dreamer-v3 (Hafner et al., 2023), trained by sheeprl on an sb3-ef pixel env.

    :param policy: ``"CnnPolicy"`` (the networks are sheeprl's).
    :param env: an env of stacked uint8 RGB frames (square, power-of-2 size), Box actions; ``None`` to act only.
    :param model_size: sheeprl's preset ``XS``, ``S`` (the authors' DMC-vision model), ``M``, ``L`` or ``XL``.
    :param replay_ratio: gradient steps per agent step (the authors' ``train_ratio / (batch_size * sequence_length)``).
    :param batch_size: sequences per gradient step.
    :param sequence_length: steps per sequence.
    :param buffer_size: replay capacity in steps.
    :param learning_starts: random-action steps before training (sheeprl also waits for one whole sequence).
    :param sheeprl_overrides: other keys of sheeprl's configuration, dotted (``{"algo.horizon": 15}``).
    :param precision: ``"fp32"`` or ``"bf16"`` (Lightning Fabric's ``bf16-mixed``, docs/precision.md).
    :param work_dir: where sheeprl writes its runs, checkpoints and replay buffer (default: a new temporary folder).
    :param seed: the run's seed (of Python, NumPy, torch and the env); default a random one.
    :param device: ``auto``, ``cpu``, ``cuda`` or ``cuda:<index>`` (missing CUDA: the CPU, with a warning).
    :param verbose: 1 prints a line per evaluation.
    """

    def __init__(
        self,
        policy: str,
        env: gym.Env | None,
        model_size: str = "S",
        replay_ratio: float = 0.5,
        batch_size: int = 16,
        sequence_length: int = 64,
        buffer_size: int = 1_000_000,
        learning_starts: int = 1024,
        sheeprl_overrides: dict[str, Any] | None = None,
        precision: str = "fp32",
        work_dir: str | os.PathLike | None = None,
        seed: int | None = None,
        device: str = "auto",
        verbose: int = 0,
    ):
        if policy != POLICY:
            raise ValueError(
                f"DreamerV3's policy is {POLICY!r} (sheeprl's networks, sized by model_size), got {policy!r}"
            )
        self.recipe = Recipe(
            model_size, replay_ratio, batch_size, sequence_length, buffer_size, learning_starts,
            {} if sheeprl_overrides is None else sheeprl_overrides, precision,
        )  # fmt: skip
        fabric_device(device)  # checks the device string
        check_precision(precision, device)
        check_device(device)  # warns when CUDA is asked for and not there
        if device.startswith("cuda") and not th.cuda.is_available():
            device = "cpu"
        require_sheeprl()
        self.cfg = compose_config(self.recipe)  # checks every override key now
        self.env = None if env is None else self._checked_env(env)
        self.work_dir = Path(work_dir) if work_dir is not None else Path(tempfile.mkdtemp(prefix="sb3_ef_dreamerv3_"))
        self.seed = int(np.random.randint(2**31 - 1)) if seed is None else int(seed)
        self.device, self.verbose, self.num_timesteps = device, verbose, 0
        self.resolved: Any = None  # the last run's resolved sheeprl configuration
        self._state: dict[str, Any] | None = None  # the newest weights (a checkpoint's state, no replay buffer)
        self._checkpoint: str | None = None  # the newest checkpoint on disk, with its replay buffer
        self._buffer_in_checkpoint = True
        self._player: Player | None = None
        self._saved_action_space: gym.spaces.Box | None = None

    @staticmethod
    def _checked_env(env: Any) -> gym.Env:
        if not isinstance(env, gym.Env):
            raise ValueError(
                f"DreamerV3 takes one gymnasium env (sheeprl vectorises it itself), got {type(env).__name__}; "
                "rl-zoo3's `sb3-ef train` gives a VecEnv: run dreamerv3 through `sb3-ef benchmark` instead"
            )
        NewestFrame(env)  # checks the frames and actions
        return env

    @property
    def settings(self) -> dict[str, Any]:
        """The constructor arguments that rebuild this model (without env, work folder and device)."""
        return {"policy": POLICY, **dataclasses.asdict(self.recipe), "seed": self.seed, "verbose": self.verbose}

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """``(3, h, w)``: the frames Dreamer-v3 reads."""
        if self.env is None:
            raise ValueError("DreamerV3 has no env: pass one to load() to train")
        _, height, width = self.env.observation_space.shape  # type: ignore[misc]
        return FRAME_CHANNELS, height, width

    def learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
        evaluation: Evaluation | None = None,
        checkpoint_freq: int | None = None,
        keep_checkpoints: int | None = None,
        log_prefix: str | None = None,
    ) -> DreamerV3:
        """Train ``total_timesteps`` steps, evaluating and checkpointing (resume: ``reset_num_timesteps=False``)."""
        if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, int) or total_timesteps < 1:
            raise ValueError(f"total_timesteps must be a positive integer, got {total_timesteps!r}")
        if self.env is None:
            raise ValueError("DreamerV3 has no env to train on: pass env= to the constructor or to load()")
        self._check_frames(self.frame_shape[1:], "the env")
        if reset_num_timesteps and self._checkpoint is not None:
            raise ValueError(
                f"DreamerV3 has trained {self.num_timesteps} steps: continue with learn(n, reset_num_timesteps=False) "
                "(sheeprl's resume counts on from the checkpoint's step); a new run needs a new model"
            )
        resume = None if reset_num_timesteps else self._checkpoint
        start = self.num_timesteps if resume is not None else 0
        total = start + total_timesteps
        every = self._checkpoint_every(total, evaluation, checkpoint_freq)
        callback_ = RunCallback(
            self.work_dir, self.settings, self.frame_shape, self.action_space, evaluation, keep_checkpoints,
            save_every=checkpoint_freq or total, total_steps=total, on_weights=self._take_weights,
        )  # fmt: skip
        steps = _sb3_callback(callback, progress_bar)
        self.num_timesteps, env = start, self.env
        if steps is not None:
            steps.init_callback(self)  # type: ignore[arg-type]  # SB3's callbacks read an algorithm's attributes
            locals_: dict[str, Any] = {"self": self, "total_timesteps": total, "callback": steps}
            steps.on_training_start(locals_, globals())
            env = StepCallbacks(self.env, self, steps, locals_)
        (self.work_dir / "sheeprl" / "train").mkdir(parents=True, exist_ok=True)  # sheeprl's runs, version_<n>
        with live.registered(env) as env_token, live.registered(callback_) as callback_token:
            session = Session(
                env_token, callback_token, task_id(self.env), self.frame_shape[1], self.seed, total, every,
                keep_checkpoints, str(self.work_dir), "train", self.device, resume,
            )  # fmt: skip
            self.resolved = resolved_config(self.cfg.copy(), session, self._buffer_in_checkpoint)
            callback_.config, callback_.start_step = self.resolved, start
            callback_.log_prefix = log_prefix if log_prefix is not None else ("" if self.verbose >= 1 else None)
            with contextlib.suppress(StopTraining):  # the model keeps the newest weights sheeprl handed over
                run(self.resolved)
        if steps is not None:
            steps.on_training_end()
        if self._state is None:
            raise RuntimeError(f"DreamerV3 stopped at step {self.num_timesteps}, before sheeprl's first checkpoint")
        self.num_timesteps = int(self._state["iter_num"])
        if callback_.last_checkpoint is not None:
            self._checkpoint, self._buffer_in_checkpoint = callback_.last_checkpoint, True
        return self

    def _take_weights(self, state: dict[str, Any]) -> None:
        self._state, self._player = state, None

    def _check_frames(self, frame_size: tuple[int, ...], given_by: str) -> None:
        """Refuse frames ``(h, w)`` Dreamer-v3 cannot read, or of another size than it trained on."""
        height, width = (int(size) for size in frame_size)
        check_frame_size(height, width)
        if self._state is None and self._checkpoint is None:
            return
        trained = int(self._config().env.screen_size)
        if (height, width) != (trained, trained):
            raise ValueError(
                f"DreamerV3 was trained on {trained}x{trained} frames, {given_by} gives {height}x{width}: "
                f"give it frames of the training's size (make_env(..., size={trained}))"
            )

    @staticmethod
    def _checkpoint_every(total: int, evaluation: Evaluation | None, checkpoint_freq: int | None) -> int:
        """sheeprl's ``checkpoint.every``: the evaluations happen at its calls."""
        if checkpoint_freq is not None:
            if isinstance(checkpoint_freq, bool) or not isinstance(checkpoint_freq, int) or checkpoint_freq < 1:
                raise ValueError(f"checkpoint_freq must be a positive integer, got {checkpoint_freq!r}")
            if evaluation is not None and checkpoint_freq % evaluation.freq:
                raise ValueError(
                    f"checkpoint_freq ({checkpoint_freq}) must be a multiple of evaluation.freq ({evaluation.freq})"
                )
        if evaluation is not None:
            return evaluation.freq
        return checkpoint_freq or total

    @classmethod
    def resume(cls, work_dir: str | os.PathLike, env: gym.Env, device: str = "auto") -> DreamerV3 | None:
        """The run in ``work_dir`` at its latest complete checkpoint, or ``None`` before its first."""
        latest = read_latest(work_dir)
        if latest is None:
            return None
        model = cls(env=env, work_dir=work_dir, device=device, **latest["settings"])
        model._checkpoint, model.num_timesteps = latest["checkpoint"], int(latest["step"])
        return model

    def _weights(self) -> dict[str, Any]:
        if self._state is None:
            if self._checkpoint is None:
                raise ValueError("DreamerV3 has no weights yet: call learn() or load() first")
            self._state = th.load(self._checkpoint, map_location="cpu", weights_only=False)
            self._state.pop("rb", None)
        return self._state

    def _config(self) -> Any:
        if self.resolved is None:
            if self._checkpoint is None:
                raise ValueError("DreamerV3 has no weights yet: call learn() or load() first")
            from omegaconf import OmegaConf
            from sheeprl.utils import fs
            from sheeprl.utils.utils import dotdict

            stored = fs.load_yaml(fs.run_config(self._checkpoint))
            self.resolved = dotdict(OmegaConf.to_container(stored, resolve=True))
        return self.resolved

    @property
    def action_space(self) -> gym.spaces.Box:
        """The env's action space (the actions :meth:`predict` returns)."""
        if self.env is not None:
            return self.env.action_space  # type: ignore[return-value]
        if self._saved_action_space is None:
            raise ValueError("DreamerV3 has no env and no saved action space: pass env=")
        return self._saved_action_space

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """The action(s) for stacked uint8 frames and the player's memory, to pass back as ``state``."""
        batch = np.asarray(observation)
        single = batch.ndim == 3
        batch = batch[np.newaxis] if single else batch
        if batch.ndim != 4 or batch.dtype != np.uint8 or batch.shape[1] % FRAME_CHANNELS:
            raise ValueError(
                "DreamerV3.predict expects stacked uint8 RGB frames of shape (3 * k, h, w) or (n, 3 * k, h, w), got "
                f"an array of shape {batch.shape} and dtype {batch.dtype}"
            )
        frames = batch[:, -FRAME_CHANNELS:]
        player = self._acting_player(len(frames), frames.shape[1:])
        if state is None:
            player.reset()
        else:
            player.set_recurrent_state(state)
        if episode_start is not None:
            starts = np.flatnonzero(np.asarray(episode_start, dtype=bool).reshape(-1))
            if len(starts):
                player.reset(starts.tolist())
        actions = player.act(frames, greedy=deterministic)
        return (actions[0] if single else actions), player.recurrent_state()

    def _acting_player(self, n_envs: int, frame_shape: tuple[int, ...]) -> Player:
        self._check_frames(frame_shape[1:], "the observation")
        player = self._player
        if player is None or player.frame_shape != frame_shape:
            from lightning.fabric import Fabric

            config = self._config()
            accelerator, devices = fabric_device(self.device)
            fabric = Fabric(accelerator=accelerator, devices=devices, precision=config.fabric.precision)
            shape = (FRAME_CHANNELS, int(frame_shape[1]), int(frame_shape[2]))
            with forked_rng(fabric.device):  # building draws initial weights: predict's samples stay the same
                player = Player(fabric, config, shape, self.action_space, self._weights(), n_envs)
            self._player = player
        if player.player.num_envs != n_envs:
            player.player.num_envs = n_envs
            player.reset()
        return player

    def save(self, path: PathOrFile) -> None:
        """Write settings, configuration, weights and optimiser states (no replay buffer) to one zip, atomically."""
        config = self._config()
        space = self.action_space
        info = {
            "algorithm": type(self).__name__,
            "sheeprl": SHEEPRL_VERSION,
            "settings": self.settings,
            "num_timesteps": self.num_timesteps,
            "action_space": {"low": space.low.tolist(), "high": space.high.tolist(), "dtype": str(space.dtype)},
        }
        weights = io.BytesIO()
        th.save(self._weights(), weights)
        from omegaconf import OmegaConf

        write_model(path, info, OmegaConf.to_yaml(OmegaConf.create(dict(config.as_dict()))), weights.getvalue())

    @classmethod
    def load(
        cls,
        path: PathOrFile,
        env: gym.Env | None = None,
        device: str = "auto",
        work_dir: str | os.PathLike | None = None,
    ) -> DreamerV3:
        """A model :meth:`save` wrote; with ``env``, ``learn(n, reset_num_timesteps=False)`` continues it."""
        from omegaconf import OmegaConf
        from sheeprl.utils.utils import dotdict

        from sb3_ef.common.files import write_atomically

        info, config, weights = read_model(path)
        model = cls(env=env, work_dir=work_dir, device=device, **info["settings"])
        space = info["action_space"]
        model._saved_action_space = gym.spaces.Box(
            np.array(space["low"], dtype=space["dtype"]), np.array(space["high"], dtype=space["dtype"])
        )
        # A sheeprl run folder for sheeprl's resume: config.yaml beside checkpoint/
        step = int(info["num_timesteps"])
        folder = model.work_dir / "loaded"
        (folder / "checkpoint").mkdir(parents=True, exist_ok=True)
        write_atomically(folder / "config.yaml", lambda file: file.write(config))
        checkpoint = folder / "checkpoint" / f"ckpt_{step}_0.ckpt"
        write_atomically(checkpoint, lambda file: file.write(weights))
        model._checkpoint, model._buffer_in_checkpoint, model.num_timesteps = str(checkpoint), False, step
        model._state = th.load(io.BytesIO(weights), map_location="cpu", weights_only=False)
        model.resolved = dotdict(OmegaConf.to_container(OmegaConf.create(config.decode()), resolve=True))
        if model.env is not None:
            model._check_frames(model.frame_shape[1:], "the env")
        return model


def _sb3_callback(callback: MaybeCallback, progress_bar: bool) -> BaseCallback | None:
    """SB3's callbacks as one, with SB3's progress bar when ``progress_bar``."""
    given = list(callback) if isinstance(callback, list) else ([] if callback is None else [callback])
    callbacks: list[BaseCallback] = []
    for one in given:
        if not isinstance(one, BaseCallback):
            raise ValueError(f"callback must be an SB3 BaseCallback or a list of them, got {type(one).__name__}")
        callbacks.append(one)
    if progress_bar:
        callbacks.append(ProgressBarCallback())
    if not callbacks:
        return None
    return callbacks[0] if len(callbacks) == 1 else CallbackList(callbacks)
