"""TensorBoard view of what Ego-Foresight learned, logged during training through SB3's logger."""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Image
from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.analysis.prediction import ForesightModel
from sb3_ef.analysis.report import foresight_report, record_rollout
from sb3_ef.common.acting import EpisodeActor
from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.ef.probe import fit_probe

_NOT_TEXT = ("stdout", "log", "json", "csv")


class ForesightLoggerCallback(BaseCallback):
    """Every ``log_freq`` calls, log EF's open-loop prediction and saliency on ``eval_env`` (docs/analysis.md).

    :param eval_env: a single gymnasium env with the training env's observations (e.g. ``make_env(...)``).
    :param seed: reset seed, so every log starts from the same state (None: a fresh state each time).
    :param probe_steps: steps latent EF's probe decoder is fitted before each log (:func:`~sb3_ef.ef.probe.fit_probe`).
    """

    def __init__(
        self,
        eval_env: gym.Env,
        log_freq: int = 10_000,
        steps: int | None = None,
        seed: int | None = 0,
        deterministic: bool = True,
        threshold_rule: str = "mean_std",
        num_std: float = 1.0,
        fraction: float = 0.1,
        patch_size: int = 4,
        probe_steps: int = 200,
        verbose: int = 0,
    ):
        super().__init__(verbose=verbose)
        if isinstance(eval_env, VecEnv) or not isinstance(eval_env, gym.Env):
            raise TypeError(
                f"Expected a single gymnasium.Env (e.g. sb3_ef.make_env(...)), got {type(eval_env).__name__}"
            )
        if log_freq < 1 or (steps is not None and steps < 1) or probe_steps < 1:
            raise ValueError(
                f"log_freq, steps and probe_steps must be >= 1, got log_freq={log_freq}, steps={steps}, "
                f"probe_steps={probe_steps}"
            )
        self.probe_steps = probe_steps
        self.eval_env, self.log_freq, self.steps, self.seed = eval_env, log_freq, steps, seed
        self.deterministic, self.patch_size = deterministic, patch_size
        self.threshold_kwargs: dict[str, Any] = {
            "threshold_rule": threshold_rule,
            "num_std": num_std,
            "fraction": fraction,
        }

    def _init_callback(self) -> None:
        if getattr(self.model, "ef", None) is None:
            raise ValueError(
                f"ForesightLoggerCallback needs a model with Ego-Foresight; {type(self.model).__name__}.ef is None"
            )
        model = cast(ForesightModel, self.model)
        expected = tuple(model.frame_shape[1:])
        received = tuple(self.eval_env.observation_space.shape or ())[1:]
        if expected != received:
            raise ValueError(f"eval_env frames are {received}, the model predicts {expected} frames")
        if model.ef.target == "latent" and not isinstance(getattr(model, "replay_buffer", None), SequenceReplayBuffer):
            raise ValueError(
                "ForesightLoggerCallback draws latent EF's frames through its probe decoder, fitted on the model's "
                f"SequenceReplayBuffer; {type(model).__name__} keeps none (it learns from rollouts): log its pixel EF "
                "(ef_kwargs target='pixel')"
            )

    def _on_step(self) -> bool:
        if self.n_calls % self.log_freq == 0:
            self.log_foresight()
        return True

    def log_foresight(self) -> dict[str, float]:
        """Play, predict, compute saliency, log images and scores now; return the logged scalars."""
        model = cast(ForesightModel, self.model)  # the EF contract, checked in _init_callback
        if model.ef.target == "latent":
            fit_probe(self.model, steps=self.probe_steps, seed=self.n_calls)
        actor = EpisodeActor(self.model, self.deterministic)
        rollout = record_rollout(
            self.eval_env,
            lambda observation, _: actor(observation),
            steps=self.steps or model.ef.horizon,
            seed=self.seed,
            frame_channels=model.frame_shape[0],
        )
        report = foresight_report(model, rollout, patch_size=self.patch_size, **self.threshold_kwargs)
        self.logger.record("foresight/prediction", Image(report.prediction_image(), "HWC"), exclude=_NOT_TEXT)
        self.logger.record("foresight/saliency", Image(report.saliency_image(), "HWC"), exclude=_NOT_TEXT)
        scalars = {f"foresight/{name}": value for name, value in report.scalars().items()}
        for key, value in scalars.items():
            self.logger.record(key, value)
        self.logger.dump(self.num_timesteps)
        return scalars
