"""``DreamerV3``: sheeprl's Dreamer-v3 (networks, replay buffer and training loop, in this process) behind SB3's
learn / predict / save / load, callbacks, parameters and env (the differences: docs/dreamerv3.md)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback
from stable_baselines3.common.logger import HumanOutputFormat, Logger
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.utils import get_system_info
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.interrupt import progress_bar_callback
from sb3_ef.common.precision import check_precision
from sb3_ef.common.validation import check_device
from sb3_ef.dreamerv3 import live
from sb3_ef.dreamerv3.callbacks import Evaluation, RunCallback, StopTraining, read_latest
from sb3_ef.dreamerv3.config import (
    SHEEPRL_VERSION,
    Recipe,
    Session,
    compose_config,
    fabric_device,
    require_sheeprl,
)
from sb3_ef.dreamerv3.env import NewestFrame, StepLocals, check_frame_size, task_id
from sb3_ef.dreamerv3.player import Player, forked_rng
from sb3_ef.dreamerv3.saving import PathOrFile, read_model, write_model
from sb3_ef.dreamerv3.training import resolved_config, run

#: The only policy: sheeprl's networks, sized by ``model_size``.
POLICY = "CnnPolicy"
#: The entries of sheeprl's state that get_parameters / set_parameters handle: the networks' and the return
#: normalisation's state dicts, then the optimisers'.
MODULES = ("world_model", "actor", "critic", "target_critic", "moments")
PARAMETERS = (*MODULES, "world_optimizer", "actor_optimizer", "critic_optimizer")
#: The settings a loaded model takes anew (load's custom_objects and keyword arguments); sheeprl's resume keeps the
#: saved run's configuration for the others.
LOAD_SETTINGS = ("learning_starts", "seed", "verbose")


class DreamerV3:
    """Dreamer-v3 (Hafner et al., 2023), trained by sheeprl on an sb3-ef pixel env.

    :param policy: ``"CnnPolicy"`` (the networks are sheeprl's).
    :param env: an env of stacked uint8 RGB frames (square, power-of-2 size), Box actions (or a ``DummyVecEnv`` of
        one); ``None`` to act only.
    :param model_size: sheeprl's preset ``XS``, ``S`` (the authors' DMC-vision model), ``M``, ``L`` or ``XL``.
    :param replay_ratio: gradient steps per agent step (the authors' ``train_ratio / (batch_size * sequence_length)``).
    :param batch_size: sequences per gradient step.
    :param sequence_length: steps per sequence.
    :param buffer_size: replay capacity in steps.
    :param learning_starts: random-action steps before training (sheeprl also waits for one whole sequence).
    :param sheeprl_overrides: other keys of sheeprl's configuration, dotted (``{"algo.horizon": 15}``) or nested.
    :param precision: ``"fp32"`` or ``"bf16"`` (Lightning Fabric's ``bf16-mixed``, docs/precision.md).
    :param work_dir: where sheeprl writes its runs, checkpoints and replay buffer (default: a new temporary folder).
    :param seed: the run's seed (of Python, NumPy, torch and the env); default a random one.
    :param device: ``auto``, ``cpu``, ``cuda`` or ``cuda:<index>`` (missing CUDA: the CPU, with a warning).
    :param verbose: 1 prints a line per evaluation (and SB3's callbacks' logs).
    """

    def __init__(
        self,
        policy: str,
        env: gym.Env | DummyVecEnv | None,
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
        self.work_dir = Path(work_dir) if work_dir is not None else Path(tempfile.mkdtemp(prefix="sb3_ef_dreamerv3_"))
        self.seed = int(np.random.randint(2**31 - 1)) if seed is None else int(seed)
        self.device, self.verbose, self.num_timesteps = device, verbose, 0
        self.logger = Logger(None, [HumanOutputFormat(sys.stdout)] if verbose >= 1 else [])  # SB3's callbacks log here
        self.resolved: Any = None  # the last run's resolved sheeprl configuration
        self._state: dict[str, Any] | None = None  # the newest weights (sheeprl's state without the replay buffer)
        self._checkpoint: str | None = None  # the newest checkpoint on disk
        self._buffer_in_checkpoint = False  # whether it holds the replay buffer
        self._state_on_disk = False  # whether it holds the newest weights
        self._player: Player | None = None
        self._saved_action_space: gym.spaces.Box | None = None
        self.env: gym.Env | None = None
        self._vec_env: DummyVecEnv | None = None
        if env is not None:
            self.set_env(env)

    @property
    def settings(self) -> dict[str, Any]:
        """The constructor arguments that rebuild this model (without env, work folder and device)."""
        return {"policy": POLICY, **dataclasses.asdict(self.recipe), "seed": self.seed, "verbose": self.verbose}

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """``(3, h, w)``: the frames Dreamer-v3 reads."""
        if self.env is None:
            raise ValueError("DreamerV3 has no env: pass one to set_env() to train")
        _, height, width = self.env.observation_space.shape  # type: ignore[misc]
        return FRAME_CHANNELS, height, width

    def get_env(self) -> DummyVecEnv | None:
        """The training env as the one-env ``DummyVecEnv`` SB3's callbacks read (``None`` without one)."""
        return self._vec_env

    def set_env(self, env: gym.Env | DummyVecEnv, force_reset: bool = True) -> None:
        """Train on ``env`` from the next ``learn``: its frames and actions must be those the weights were trained on.

        :param force_reset: ``True`` only: sheeprl starts every ``learn`` with a reset of the env.
        """
        if not force_reset:
            raise ValueError("DreamerV3 cannot keep the env's episode going (force_reset=False): sheeprl resets it")
        if isinstance(env, DummyVecEnv) and env.num_envs == 1:
            env = env.envs[0]
        if not isinstance(env, gym.Env):
            count = f" of {env.num_envs} envs" if hasattr(env, "num_envs") else ""
            raise ValueError(
                f"DreamerV3 takes one gymnasium env or a DummyVecEnv of one (sheeprl vectorises it itself), got a "
                f"{type(env).__name__}{count}"
            )
        self._check_frames(NewestFrame(env).observation_space.shape[1:], "the env")  # type: ignore[index]
        if self._has_weights and env.action_space.shape != self.action_space.shape:
            raise ValueError(
                f"DreamerV3 was trained with actions of shape {self.action_space.shape}, the env's are of shape "
                f"{env.action_space.shape}"
            )
        self.env, self._vec_env = env, DummyVecEnv([lambda: env])

    def get_vec_normalize_env(self) -> None:
        """``None``: DreamerV3 trains on the env's own observations and rewards (SB3's callbacks ask)."""
        return None

    def dump_logs(self) -> None:
        """Write the logger's values at the current step (SB3's ``LogEveryNTimesteps`` calls it)."""
        self.logger.record("time/total_timesteps", self.num_timesteps)
        self.logger.dump(step=self.num_timesteps)

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
        """Train ``total_timesteps`` steps, evaluating every ``evaluation.freq`` steps and writing sheeprl's checkpoint
        every ``checkpoint_freq`` steps and at the end (continue a trained model: ``reset_num_timesteps=False``).

        ``callback`` (SB3's: a ``BaseCallback``, a function ``(locals, globals) -> bool`` or a list) is called after
        each step's training; a ``False`` from it stops the run with that step's checkpoint written.
        """
        _check_positive("total_timesteps", total_timesteps)
        if checkpoint_freq is not None:
            _check_positive("checkpoint_freq", checkpoint_freq)
        if self.env is None:
            raise ValueError("DreamerV3 has no env to train on: pass env= to the constructor, set_env() or load()")
        if reset_num_timesteps and self._has_weights:
            raise ValueError(
                f"DreamerV3 has trained {self.num_timesteps} steps: continue with learn(n, reset_num_timesteps=False) "
                "(sheeprl's resume counts on from the checkpoint's step); a new run needs a new model"
            )
        (self.work_dir / "sheeprl" / "train").mkdir(parents=True, exist_ok=True)  # sheeprl's runs, version_<n>
        resume, with_buffer = self._resume_point() if self._has_weights else (None, False)
        start = self.num_timesteps if resume is not None else 0
        total = start + total_timesteps
        locals_: dict[str, Any] = {
            "self": self, "total_timesteps": total, "reset_num_timesteps": reset_num_timesteps,
            "progress_bar": progress_bar,
        }  # fmt: skip
        with progress_bar_callback(callback, progress_bar) as callbacks:
            steps = locals_["callback"] = _sb3_callback(callbacks)
            self.num_timesteps = start
            steps.init_callback(self)  # type: ignore[arg-type]  # SB3's callbacks read an algorithm's attributes
            steps.on_training_start(locals_, globals())
            callback_ = RunCallback(
                self.work_dir, self.settings, self.frame_shape, self.action_space, self._take_weights,
                self._take_checkpoint, steps.on_step, evaluation, keep_checkpoints, save_every=checkpoint_freq or total,
                total_steps=total,
            )  # fmt: skip
            env = StepLocals(self.env, locals_)
            with live.registered(env) as env_token, live.registered(callback_) as callback_token:
                session = Session(
                    env_token, callback_token, task_id(self.env), self.frame_shape[1], self.seed, total,
                    keep_checkpoints, str(self.work_dir), "train", self.device, resume,
                )  # fmt: skip
                self.resolved = resolved_config(self.cfg.copy(), session, with_buffer)
                callback_.config, callback_.start_step = self.resolved, start
                callback_.log_prefix = log_prefix if log_prefix is not None else ("" if self.verbose >= 1 else None)
                with contextlib.suppress(StopTraining):
                    run(self.resolved)
            steps.on_training_end()
        return self

    def _take_weights(self, state: dict[str, Any]) -> None:
        self._state, self._player, self._state_on_disk = state, None, False
        self.num_timesteps = int(state["iter_num"])

    def _take_checkpoint(self, path: str, with_buffer: bool) -> None:
        self._checkpoint, self._buffer_in_checkpoint, self._state_on_disk = path, with_buffer, True

    @property
    def _has_weights(self) -> bool:
        return self._state is not None or self._checkpoint is not None

    def _resume_point(self) -> tuple[str, bool]:
        """A checkpoint of the model's weights for sheeprl's resume, and whether it holds a replay buffer: the newest
        one written, or one written now with the newest one's buffer (after load, set_parameters or an exception)."""
        if self._state_on_disk:
            assert self._checkpoint is not None
            return self._checkpoint, self._buffer_in_checkpoint
        state = dict(self._weights())
        if self._checkpoint is not None and self._buffer_in_checkpoint:
            state["rb"] = th.load(self._checkpoint, map_location="cpu", weights_only=False)["rb"]
        folder = Path(tempfile.mkdtemp(prefix="state_", dir=self.work_dir))  # a sheeprl run folder: config, checkpoint
        (folder / "config.yaml").write_text(self._config_yaml())
        checkpoint = folder / "checkpoint" / f"ckpt_{self.num_timesteps}_0.ckpt"
        checkpoint.parent.mkdir()
        th.save(state, checkpoint)
        self._take_checkpoint(str(checkpoint), "rb" in state)
        return str(checkpoint), "rb" in state

    def _check_frames(self, frame_size: tuple[int, ...], given_by: str) -> None:
        """Refuse frames ``(h, w)`` Dreamer-v3 cannot read, or of another size than it trained on."""
        height, width = (int(size) for size in frame_size)
        check_frame_size(height, width)
        if not self._has_weights:
            return
        trained = int(self._config().env.screen_size)
        if (height, width) != (trained, trained):
            raise ValueError(
                f"DreamerV3 was trained on {trained}x{trained} frames, {given_by} gives {height}x{width}: "
                f"give it frames of the training's size (make_env(..., size={trained}))"
            )

    @classmethod
    def resume(cls, work_dir: str | os.PathLike, env: gym.Env, device: str = "auto") -> DreamerV3 | None:
        """The run in ``work_dir`` at its latest complete checkpoint, or ``None`` before its first."""
        latest = read_latest(work_dir)
        if latest is None:
            return None
        model = cls(env=env, work_dir=work_dir, device=device, **latest["settings"])
        model._take_checkpoint(latest["checkpoint"], latest["replay_buffer"])
        model.num_timesteps = int(latest["step"])
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

    def _config_yaml(self) -> str:
        from omegaconf import OmegaConf

        return OmegaConf.to_yaml(OmegaConf.create(dict(self._config().as_dict())))

    def get_parameters(self) -> dict[str, dict[str, Any]]:
        """The state dicts of sheeprl's networks, return normalisation and optimisers, by name (:data:`PARAMETERS`)."""
        state = self._weights()
        return {name: state[name] for name in PARAMETERS}

    def set_parameters(self, load_path_or_dict: PathOrFile | dict[str, Any], exact_match: bool = True) -> None:
        """Replace some of :meth:`get_parameters`'s state dicts (given as a dict, or those of a saved model); the
        next ``learn`` trains on from them.

        :param exact_match: every one of them, each whole (else the given entries only, as torch's
            ``strict=False``).
        """
        if isinstance(load_path_or_dict, dict):
            given = load_path_or_dict
        else:
            saved = th.load(io.BytesIO(read_model(load_path_or_dict)[2]), map_location="cpu", weights_only=False)
            given = {name: saved[name] for name in PARAMETERS}
        unknown = sorted(set(given) - set(PARAMETERS))
        if unknown:
            raise ValueError(f"set_parameters: {unknown} are not parameters of DreamerV3, expected {list(PARAMETERS)}")
        missing = [name for name in PARAMETERS if name not in given]
        if exact_match and missing:
            raise ValueError(f"set_parameters: {missing} are missing (exact_match=True expects {list(PARAMETERS)})")
        state = dict(self._weights())
        for name, values in given.items():
            state[name] = _loaded_state_dict(name, state[name], values, exact_match) if name in MODULES else values
        self._state, self._player, self._state_on_disk = state, None, False

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
        space = self.action_space
        info = {
            "algorithm": type(self).__name__,
            "sheeprl": SHEEPRL_VERSION,
            "settings": self.settings,
            "num_timesteps": self.num_timesteps,
            "action_space": {"low": space.low.tolist(), "high": space.high.tolist(), "dtype": str(space.dtype)},
            "system_info": get_system_info(print_info=False)[0],
        }
        weights = io.BytesIO()
        th.save(self._weights(), weights)
        write_model(path, info, self._config_yaml(), weights.getvalue())

    @classmethod
    def load(
        cls,
        path: PathOrFile,
        env: gym.Env | DummyVecEnv | None = None,
        device: str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        work_dir: str | os.PathLike | None = None,
        **kwargs: Any,
    ) -> DreamerV3:
        """A model :meth:`save` wrote; with ``env``, ``learn(n, reset_num_timesteps=False)`` continues it.

        :param custom_objects: new values of :data:`LOAD_SETTINGS` (the others are the saved run's), as ``kwargs``.
        :param print_system_info: print the versions of the saving system and of this one.
        :param force_reset: ``True`` only, with ``env``: sheeprl starts every ``learn`` with a reset of the env.
        """
        changed = {**(custom_objects or {}), **kwargs}
        fixed = sorted(set(changed) - set(LOAD_SETTINGS))
        if fixed:
            raise ValueError(
                f"DreamerV3.load: {fixed} cannot be changed (a loaded model trains on with the saved run's sheeprl "
                f"configuration); these can: {list(LOAD_SETTINGS)}"
            )
        from omegaconf import OmegaConf
        from sheeprl.utils.utils import dotdict

        info, config, weights = read_model(path)
        if print_system_info:
            print("== CURRENT SYSTEM INFO ==")
            get_system_info()
            print("== SAVED MODEL SYSTEM INFO ==")
            print("".join(f"- {key}: {value}\n" for key, value in info.get("system_info", {}).items()) or "(none)")
        model = cls(env=None, work_dir=work_dir, device=device, **{**info["settings"], **changed})
        space = info["action_space"]
        model._saved_action_space = gym.spaces.Box(
            np.array(space["low"], dtype=space["dtype"]), np.array(space["high"], dtype=space["dtype"])
        )
        model.num_timesteps = int(info["num_timesteps"])
        model._state = th.load(io.BytesIO(weights), map_location="cpu", weights_only=False)
        model.resolved = dotdict(OmegaConf.to_container(OmegaConf.create(config.decode()), resolve=True))
        if env is not None:
            model.set_env(env, force_reset)
        return model


def _check_positive(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")


def _loaded_state_dict(name: str, current: dict[str, Any], given: dict[str, Any], strict: bool) -> dict[str, Any]:
    """``current`` with the tensors of ``given`` in (all of them if ``strict``), each of its shape."""
    missing = [key for key in current if key not in given] if strict else []
    wrong = [key for key in given if key not in current or tuple(given[key].shape) != tuple(current[key].shape)]
    if missing or wrong:
        raise RuntimeError(f"set_parameters: {name} does not fit: missing {missing}, unexpected or resized {wrong}")
    return {
        key: given[key].detach().to(value.device, value.dtype).clone() if key in given else value
        for key, value in current.items()
    }


def _sb3_callback(callback: MaybeCallback) -> BaseCallback:
    """``learn``'s callback as one ``CallbackList``, a function ``(locals, globals) -> bool`` (or ``None``) in it as a
    ``ConvertCallback``, as SB3 takes them."""
    items = callback if isinstance(callback, list) else [callback]
    for item in items:
        if item is not None and not isinstance(item, BaseCallback) and not callable(item):
            raise ValueError(
                "callback must be an SB3 BaseCallback, a function (locals, globals) -> bool or a list of them, got "
                f"{type(item).__name__}"
            )
    return CallbackList([item if isinstance(item, BaseCallback) else ConvertCallback(item) for item in items])
