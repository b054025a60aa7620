"""The motor babbling callback, its state saved with the model (docs/ef.md, "Motor babbling")."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from functools import partial
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.preprocessing import maybe_transpose
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.utils import is_vectorized_observation
from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.common.exploration import (
    ActionOverrideMixin,
    Observation,
    Prediction,
    PredictState,
    overridden_predict,
    overridden_sample_action,
)
from sb3_ef.ef.babbling.actions import BABBLING_MODES, babble
from sb3_ef.ef.babbling.held_out import HeldOutWindows, foresight_error_ratio, record_held_out_windows
from sb3_ef.ef.babbling.state import STATE_ATTRIBUTE, BabblingState, Plateau


class MotorBabblingCallback(BaseCallback):
    """Motor babbling on any SB3 off-policy algorithm with a ``Box`` action space: the env executes and the buffer
    stores random actions; adaptive babbling ends at a plateau of a score (docs/ef.md, "Adaptive babbling").

    :param steps: steps (``num_timesteps``) of babbling, or ``"adaptive"``.
    :param mode: ``"sign"`` (each component +-1, the paper) or ``"clamped_uniform"`` (the EF authors' code).
    :param in_eval: ``predict`` babbles too while active, from its own generator (the EF authors' Meta-World protocol).
    :param seed: seed of the babbling generators (``None``: the model's); a model's saved babbling state continues.
    :param min_steps: adaptive: babbling never ends before this step.
    :param max_steps: adaptive: babbling always ends at this step.
    :param patience: adaptive: evaluations in a row without improvement that make a plateau.
    :param min_delta: adaptive: relative improvement of the best score that counts.
    :param eval_freq: adaptive: steps between two evaluations.
    :param eval_env: adaptive: a single env like the training one, where held-out babbling episodes are recorded.
    :param criterion: adaptive: ``criterion(model) -> float``, non-negative, lower is better; instead of ``eval_env``.
    :param holdout_steps: adaptive with ``eval_env``: babbling steps recorded in it.
    :param holdout_windows: adaptive with ``eval_env``: windows scored at each evaluation.
    :param verbose: 1 to print when babbling ends.
    """

    def __init__(
        self,
        steps: int | str,
        mode: str = "sign",
        in_eval: bool = False,
        seed: int | None = None,
        *,
        min_steps: int | None = None,
        max_steps: int | None = None,
        patience: int | None = None,
        min_delta: float | None = None,
        eval_freq: int | None = None,
        eval_env: gym.Env | None = None,
        criterion: Callable[[BaseAlgorithm], float] | None = None,
        holdout_steps: int | None = None,
        holdout_windows: int | None = None,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        adaptive_arguments: dict[str, Any] = {
            "min_steps": min_steps, "max_steps": max_steps, "patience": patience, "min_delta": min_delta,
            "eval_freq": eval_freq, "eval_env": eval_env, "criterion": criterion, "holdout_steps": holdout_steps,
            "holdout_windows": holdout_windows,
        }  # fmt: skip
        self.adaptive = steps == "adaptive"
        if self.adaptive:
            self._check_adaptive(**adaptive_arguments)
        elif isinstance(steps, bool) or not isinstance(steps, int | np.integer):
            raise ValueError(f"steps must be an int >= 0 or 'adaptive', got {steps!r}")
        elif steps < 0:
            raise ValueError(f"steps must be an int >= 0 or 'adaptive', got {steps}")
        else:
            given = sorted(name for name, value in adaptive_arguments.items() if value is not None)
            if given:
                raise ValueError(f"{given} apply to steps='adaptive' only, got steps={steps}")
        if mode not in BABBLING_MODES:
            raise ValueError(f"mode must be one of {BABBLING_MODES}, got {mode!r}")
        self.steps = steps
        self.mode = mode
        self.in_eval = in_eval
        self.seed = seed
        self.min_steps = min_steps or 0
        self.max_steps = max_steps if self.adaptive else int(steps)
        self.patience = patience or 3
        self.min_delta = 0.01 if min_delta is None else min_delta
        self.eval_freq = eval_freq or 1000
        self.eval_env = eval_env
        self.criterion = criterion
        self.holdout_steps = holdout_steps or 200
        self.holdout_windows = holdout_windows or 64
        self.held_out: HeldOutWindows | None = None
        #: Warn when a fresh babbling state starts past ``steps`` (the hosts' own callback does not).
        self.warn_if_late = True
        self._shadowed: dict[str, Any] = {}
        self._instance_attributes: dict[str, Any] = {}
        self._learn_start: float | None = None

    @staticmethod
    def _check_adaptive(
        min_steps: int | None,
        max_steps: int | None,
        patience: int | None,
        min_delta: float | None,
        eval_freq: int | None,
        eval_env: gym.Env | None,
        criterion: Callable[[BaseAlgorithm], float] | None,
        holdout_steps: int | None,
        holdout_windows: int | None,
    ) -> None:
        if max_steps is None or max_steps < 1:
            raise ValueError(f"adaptive babbling needs max_steps >= 1 (it always ends there), got {max_steps}")
        if min_steps is not None and not 0 <= min_steps <= max_steps:
            raise ValueError(f"min_steps must lie in [0, max_steps={max_steps}], got {min_steps}")
        for name, value in (
            ("patience", patience), ("eval_freq", eval_freq), ("holdout_steps", holdout_steps),
            ("holdout_windows", holdout_windows),
        ):  # fmt: skip
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if min_delta is not None and not 0.0 <= min_delta < 1.0:
            raise ValueError(f"min_delta must lie in [0, 1), got {min_delta}")
        if (eval_env is None) == (criterion is None):
            raise ValueError(
                "adaptive babbling needs exactly one of eval_env (EF is scored on held-out babbling episodes of it) "
                f"and criterion (a function of the model), got eval_env={eval_env!r}, criterion={criterion!r}"
            )
        if eval_env is not None and (isinstance(eval_env, VecEnv) or not isinstance(eval_env, gym.Env)):
            raise TypeError(f"eval_env must be a single gymnasium.Env, got {type(eval_env).__name__}")
        if criterion is not None and not callable(criterion):
            raise TypeError(f"criterion must be a function of the model returning a float, got {criterion!r}")

    @property
    def state(self) -> BabblingState:
        """The babbling state on the model (set at the start of training)."""
        return getattr(self.model, STATE_ATTRIBUTE)

    @property
    def active(self) -> bool:
        """Whether the rollout actions are babbling actions now."""
        state = self.state
        return state.end_step is None and self.model.num_timesteps < self.max_steps  # type: ignore[operator]

    @property
    def end_step(self) -> int | None:
        return self.state.end_step

    @property
    def end_reason(self) -> str | None:
        return self.state.end_reason

    @property
    def scores(self) -> list[tuple[int, float]]:
        """Adaptive babbling's evaluations so far, ``(step, score)``."""
        return self.state.scores

    def _init_callback(self) -> None:
        model = self.model
        if not isinstance(model, OffPolicyAlgorithm):
            raise TypeError(
                "MotorBabblingCallback needs an off-policy algorithm (it replaces the actions of "
                f"OffPolicyAlgorithm._sample_action), got {type(model).__name__}"
            )
        if not isinstance(model.action_space, spaces.Box):
            raise TypeError(f"MotorBabblingCallback needs a Box action space, got {model.action_space}")
        if self.adaptive and self.criterion is None:
            if getattr(model, "ef", None) is None:
                raise ValueError(
                    "Adaptive babbling without a criterion scores Ego-Foresight's predictions, but "
                    f"{type(model).__name__} has no EF module: pass criterion=<function of the model>"
                )
            if getattr(getattr(model, "ef", None), "target", "pixel") == "latent":
                raise ValueError(
                    "Adaptive babbling without a criterion scores EF's decoded frames, and latent EF "
                    "(ef_kwargs target='latent') decodes none while it trains: pass criterion=<function of the model>"
                )
            if getattr(getattr(model, "ef", None), "skip_channels", 0):
                raise ValueError("Adaptive babbling scores EF without U-Net skips (skip_channels=0)")
            expected, received = model.observation_space.shape, self.eval_env.observation_space.shape  # type: ignore[union-attr]
            if expected != received:
                raise ValueError(f"eval_env observations must have the model's shape {expected}, got {received}")

    def _on_training_start(self) -> None:
        model = self.model
        state = getattr(model, STATE_ATTRIBUTE, None)
        if state is None:
            state = BabblingState.seeded(model.seed if self.seed is None else self.seed)
            setattr(model, STATE_ATTRIBUTE, state)
            if self.warn_if_late and not self.adaptive and 0 < self.max_steps <= model.num_timesteps:  # type: ignore[operator]
                warnings.warn(
                    f"MotorBabblingCallback(steps={self.steps}) will not babble: it babbles while num_timesteps < "
                    f"{self.steps}, and this learn starts at step {model.num_timesteps} (reset_num_timesteps=False); "
                    f"pass steps={model.num_timesteps + int(self.steps)} to babble {self.steps} more steps",
                    stacklevel=2,
                )
        elif model.num_timesteps == 0:
            state.restart()
        if self.adaptive and state.plateau is None:
            state.plateau = Plateau(self.patience, self.min_delta)
        if self.adaptive and self.eval_env is not None and state.end_step is None and self.held_out is None:
            self.held_out = record_held_out_windows(
                self.eval_env,
                cast(Any, model).ef.horizon,
                self.holdout_steps,
                self.holdout_windows,
                np.random.default_rng(state.holdout_seed),
                self.mode,
            )
        self._install()

    def _on_rollout_start(self) -> None:
        model, state = self.model, self.state
        if not self.adaptive or not self.active or model.num_timesteps < state.next_evaluation:
            return
        if model.num_timesteps < model.learning_starts:  # type: ignore[attr-defined]
            return  # no update yet: nothing to score
        score = self.score()
        assert state.plateau is not None
        state.plateau.update(score)
        state.scores.append((model.num_timesteps, score))
        state.next_evaluation = (model.num_timesteps // self.eval_freq + 1) * self.eval_freq
        self.logger.record("babbling/score", score)

    def score(self) -> float:
        """Adaptive babbling's score of the model now."""
        if self.criterion is not None:
            score = float(self.criterion(self.model))
        else:
            assert self.held_out is not None
            score = foresight_error_ratio(self.model, self.held_out)
        if not (math.isfinite(score) and score >= 0.0):
            raise ValueError(f"Adaptive babbling expects a finite score >= 0 (an error), got {score}")
        return score

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._uninstall()

    def _end(self, reason: str) -> None:
        state = self.state
        state.end_step, state.end_reason = self.model.num_timesteps, reason
        self.logger.record("babbling/end_step", state.end_step)
        self.logger.record("babbling/end_reason", reason)
        if self.verbose >= 1:
            print(f"Motor babbling ended at step {state.end_step} ({reason})")

    def _update_end(self) -> bool:
        """End babbling when its rule says so; return whether it is active."""
        state, step = self.state, self.model.num_timesteps
        if state.end_step is not None:
            return False
        if step >= self.max_steps:  # type: ignore[operator]
            self._end("max_steps" if self.adaptive else "steps")
        elif self.adaptive and step >= self.min_steps and state.plateau is not None and state.plateau.plateaued:
            self._end("plateau")
        return state.end_step is None

    def rollout_action(self, n_envs: int) -> np.ndarray | None:
        """Babbling buffer actions while active, else ``None`` (the model's own choice)."""
        active = self._update_end()
        self.logger.record("rollout/babbling", float(active))
        if not active:
            return None
        return babble(self.state.rng, (n_envs, *self.model.action_space.shape), self.mode)  # type: ignore[misc]

    def evaluation_action(self, observation: Observation, state: PredictState) -> Prediction | None:
        """With ``in_eval``, babbling env actions for ``predict`` while active, else ``None``."""
        if not (self.in_eval and self.active):
            return None
        assert isinstance(observation, np.ndarray)  # image Boxes
        # Transposed first, as SB3's predict does for channels-last frames.
        vectorized = is_vectorized_observation(
            maybe_transpose(observation, self.model.observation_space), self.model.observation_space
        )
        n_envs = len(observation) if vectorized else 1
        buffer_action = babble(self.state.eval_rng, (n_envs, *self.model.action_space.shape), self.mode)  # type: ignore[misc]
        actions = self.model.policy.unscale_action(buffer_action)
        return (actions if vectorized else actions[0]), state

    def _install(self) -> None:
        """Take the model's actions over for this ``learn`` (docs/ef.md, "How the callback takes the actions over")."""
        model = self.model
        if isinstance(model, ActionOverrideMixin):
            owner = model.action_override
        else:
            shadow = vars(model).get("_sample_action")
            owner = shadow.args[0] if isinstance(shadow, partial) else None
        if isinstance(owner, MotorBabblingCallback):
            if owner._learn_start == model.start_time:
                raise ValueError(
                    "Two MotorBabblingCallbacks in one learn(): a host built with babbling_steps > 0 adds one "
                    "itself (build it with babbling_steps=0 to pass your own)"
                )
            owner._uninstall()
        self._learn_start = model.start_time
        if isinstance(model, ActionOverrideMixin):
            model.action_override = self
            return
        methods: dict[str, Any] = {
            "_sample_action": partial(overridden_sample_action, self, model.policy, model._sample_action),  # type: ignore[attr-defined]
            "_excluded_save_params": self._excluded_save_params,
        }
        if self.in_eval:
            methods["predict"] = partial(overridden_predict, self, model.predict)
        self._shadowed = {name: getattr(model, name) for name in methods}
        self._instance_attributes = {name: vars(model)[name] for name in methods if name in vars(model)}
        vars(model).update(methods)

    def _uninstall(self) -> None:
        model = self.model
        if isinstance(model, ActionOverrideMixin):
            if model.action_override is self:
                model.action_override = None
        else:
            for name in self._shadowed:
                vars(model).pop(name, None)
            vars(model).update(self._instance_attributes)
        self._shadowed, self._instance_attributes, self._learn_start = {}, {}, None

    def _excluded_save_params(self) -> list[str]:
        """The model's, plus the shadows (a save during training stores the model, not this callback)."""
        return [*self._shadowed["_excluded_save_params"](), *self._shadowed]


def with_babbling(babbling: MotorBabblingCallback, callback: MaybeCallback) -> list[BaseCallback]:
    """``babbling`` first, then the caller's ``callback`` (``None``, one callback, a list or a function)."""
    if callback is None:
        return [babbling]
    if isinstance(callback, list):
        return [babbling, *callback]
    if not isinstance(callback, BaseCallback):
        callback = ConvertCallback(callback)
    return [babbling, callback]
