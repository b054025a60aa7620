"""Motor babbling: random actions at the start of training, so that Ego-Foresight sees varied movements.

:class:`MotorBabblingCallback` babbles for a fixed number of steps or, with ``steps="adaptive"``, until EF's
prediction of held-out babbling episodes stops improving. It works on any SB3 off-policy algorithm with a ``Box``
action space. SB3 gives callbacks no hook before an action is chosen, so while training runs the callback shadows
the model's ``_sample_action`` (and, with ``in_eval``, ``predict``) on the instance: every off-policy algorithm
chooses its rollout actions in ``_sample_action``, which returns the action the env executes and the ``[-1, 1]``
action stored in the replay buffer; the shadow returns a babbling action as both (the stored one, and its
unscaled form for the env). The callback's state (generators, end, plateau) lives on the model and is saved with
it (docs/ef.md, "Motor babbling").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.preprocessing import maybe_transpose
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.utils import is_vectorized_observation
from stable_baselines3.common.vec_env import VecEnv

BABBLING_MODES = ("sign", "clamped_uniform")
#: The model attribute holding the babbling state (saved with the model, so that a resumed run continues it).
STATE_ATTRIBUTE = "_motor_babbling"
#: Frame channels of the stacked observations (RGB).
_CHANNELS = 3


def check_babbling(babbling_steps: int, mode: str) -> None:
    """Check the hosts' ``babbling_steps`` and ``babbling_mode`` (and the offline collector's mode)."""
    if babbling_steps < 0:
        raise ValueError(f"babbling_steps must be >= 0, got {babbling_steps}")
    if mode not in BABBLING_MODES:
        raise ValueError(f"babbling_mode must be one of {BABBLING_MODES}, got {mode!r}")


def babble(rng: np.random.Generator, shape: tuple[int, ...], mode: str = "sign") -> np.ndarray:
    """Babbling actions of ``shape`` in [-1, 1], float32.

    ``"sign"`` draws each component as -1 or +1 (the paper); ``"clamped_uniform"`` draws uniform(-4, 4) clamped to
    [-1, 1] (the authors' code: about 75% of the components at +-1).
    """
    if mode == "sign":
        return np.where(rng.random(shape) < 0.5, -1.0, 1.0).astype(np.float32)
    return np.clip(rng.uniform(-4.0, 4.0, shape), -1.0, 1.0).astype(np.float32)


@dataclass
class Plateau:
    """The plateau rule of adaptive babbling: a score (an error, lower is better) improves when it falls below
    ``best * (1 - min_delta)``; the scores have plateaued once ``patience`` evaluations in a row did not improve."""

    patience: int
    min_delta: float
    best: float = math.inf
    stale: int = 0

    def update(self, score: float) -> bool:
        """Take one evaluation's score; return whether the scores have plateaued."""
        if score < self.best * (1.0 - self.min_delta):
            self.best, self.stale = score, 0
        else:
            self.stale += 1
        return self.plateaued

    @property
    def plateaued(self) -> bool:
        return self.stale >= self.patience


@dataclass
class BabblingState:
    """What a resumed run needs to continue babbling exactly; kept on the model as ``_motor_babbling``.

    ``rng`` draws the rollout's babbling actions, ``eval_rng`` those of ``predict`` (``in_eval``), ``holdout_seed``
    seeds the held-out episodes of adaptive babbling. ``end_step`` / ``end_reason`` are set when babbling ends
    (``"steps"``, ``"plateau"`` or ``"max_steps"``); ``scores`` holds adaptive babbling's ``(step, score)``
    evaluations, ``next_evaluation`` the step of the next one.
    """

    rng: np.random.Generator
    eval_rng: np.random.Generator
    holdout_seed: int
    end_step: int | None = None
    end_reason: str | None = None
    plateau: Plateau | None = None
    scores: list[tuple[int, float]] = field(default_factory=list)
    next_evaluation: int = 0

    @classmethod
    def seeded(cls, seed: int | None) -> BabblingState:
        """Generators spawned from ``seed`` (fresh entropy when ``None``): the same seed babbles the same."""
        children = np.random.SeedSequence(None if seed is None else seed % 2**32).spawn(3)
        return cls(
            np.random.default_rng(children[0]),
            np.random.default_rng(children[1]),
            int(children[2].generate_state(1)[0]),
        )

    def restart(self) -> None:
        """A run that starts again from step 0 babbles again (its generators continue)."""
        self.end_step, self.end_reason, self.plateau, self.scores, self.next_evaluation = None, None, None, [], 0


@dataclass
class HeldOutWindows:
    """Babbling windows recorded in an env that training never sees: context observation at t, the H buffer
    actions from t, the H frames t+1..t+H and, when the env provides them, the agent masks of the newest context
    frame and of the H frames (index 0 = newest context frame)."""

    observations: np.ndarray  # (N, 3 * stack, h, w) uint8
    actions: np.ndarray  # (N, H, action_dim) float32 in [-1, 1]
    targets: np.ndarray  # (N, H, 3, h, w) uint8
    masks: np.ndarray | None  # (N, H + 1, h, w) bool


def record_held_out_windows(
    env: gym.Env, horizon: int, steps: int, windows: int, rng: np.random.Generator, mode: str
) -> HeldOutWindows:
    """Babble ``steps`` steps in ``env`` (a new episode, reset with a seed from ``rng``, whenever one ends) and keep
    ``windows`` windows of ``horizon`` steps spread evenly over them."""
    box = env.action_space
    assert isinstance(box, spaces.Box)
    agent_mask = getattr(env.unwrapped, "agent_mask", None)
    episodes: list[tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]] = []
    done = True
    for _ in range(steps):
        if done:
            observation, _ = env.reset(seed=int(rng.integers(2**31)))
            episodes.append(([observation], [], [] if agent_mask is None else [agent_mask()]))
        observations, actions, masks = episodes[-1]
        action = babble(rng, box.shape, mode)
        observation, _, terminated, truncated, _ = env.step(box.low + (action + 1.0) * (box.high - box.low) / 2.0)
        observations.append(observation)
        actions.append(action)
        if agent_mask is not None:
            masks.append(agent_mask())
        done = terminated or truncated
    starts = [(e, t) for e, (_, actions, _) in enumerate(episodes) for t in range(len(actions) - horizon + 1)]
    if not starts:
        raise ValueError(
            f"Adaptive babbling needs held-out episodes longer than the EF horizon {horizon}: holdout_steps={steps} "
            f"gave episodes of at most {max(len(actions) for _, actions, _ in episodes)} steps"
        )
    picks = [starts[i] for i in np.linspace(0, len(starts) - 1, min(windows, len(starts))).round().astype(int)]
    return HeldOutWindows(
        observations=np.stack([episodes[e][0][t] for e, t in picks]),
        actions=np.stack([np.stack(episodes[e][1][t : t + horizon]) for e, t in picks]),
        targets=np.stack(
            [np.stack([frames[-_CHANNELS:] for frames in episodes[e][0][t + 1 : t + horizon + 1]]) for e, t in picks]
        ),
        masks=None
        if agent_mask is None
        else np.stack([np.stack(episodes[e][2][t : t + horizon + 1]) for e, t in picks]),
    )


def foresight_error_ratio(
    model: Any, windows: HeldOutWindows, agent_pixels: bool = True, batch_size: int = 16
) -> float:
    """EF's open-loop prediction error on ``windows`` over the error of copying the newest context frame: squared
    error per pixel, over the agent's pixels (where the agent is in the newest context frame or in frame t+k) when
    ``agent_pixels`` and the windows have masks, else over all pixels; averaged over k = 1..H for the model and the
    copy, then divided."""
    horizon = windows.actions.shape[1]
    sums = np.zeros((3, horizon))  # model error, copy error, pixels, per k
    policy = model.policy
    training = policy.training
    policy.set_training_mode(False)
    try:
        with th.no_grad():
            for start in range(0, len(windows.actions), batch_size):
                rows = slice(start, start + batch_size)
                observations = th.as_tensor(windows.observations[rows], device=model.device)
                predicted = model.ef.predict(
                    model.encode(observations), th.as_tensor(windows.actions[rows], device=model.device)
                ).float()
                truth = th.as_tensor(windows.targets[rows], device=model.device).float() / 255.0
                last = observations[:, None, -_CHANNELS:].float() / 255.0
                errors = [(frames - truth).pow(2).mean(dim=2) for frames in (predicted, last)]
                if windows.masks is None or not agent_pixels:
                    weight = th.ones_like(errors[0])
                else:
                    masks = th.as_tensor(windows.masks[rows], device=model.device)
                    weight = (masks[:, 1:] | masks[:, :1]).float()
                for row, value in enumerate((*(error * weight for error in errors), weight)):
                    sums[row] += value.sum(dim=(0, 2, 3)).cpu().numpy()
    finally:
        policy.set_training_mode(training)
    pixels = np.maximum(sums[2], 1.0)
    return float((sums[0] / pixels).mean() / max((sums[1] / pixels).mean(), 1e-12))


class MotorBabblingCallback(BaseCallback):
    """Motor babbling at the start of training: the rollout actions are random while babbling is active.

    ``model.learn(n, callback=MotorBabblingCallback(...))``, alone or in a ``CallbackList``, on any SB3
    off-policy algorithm with a ``Box`` action space (SAC, TD3, DDPG, sb3-contrib's TQC, every sb3-ef host). The
    babbled actions are what the env executes and what the replay buffer stores. Logged: ``rollout/babbling``
    (1 for a babbling step, 0 after) at every rollout step, ``babbling/end_step`` and ``babbling/end_reason``
    when it ends and, adaptive, ``babbling/score`` at each evaluation.

    Fixed: active while ``num_timesteps < steps``. Adaptive (``steps="adaptive"``): every ``eval_freq`` steps
    once updates have begun (``num_timesteps >= learning_starts``), a score is computed (lower is better) and fed
    to the :class:`Plateau` rule; babbling ends at the first step at or after ``min_steps`` at which the scores
    have plateaued, and at ``max_steps`` at the latest. The default score is EF's prediction error on held-out
    babbling episodes of ``eval_env`` relative to copying the last frame (:func:`foresight_error_ratio`), which
    needs a model with Ego-Foresight; ``criterion(model) -> float`` replaces it (any model).

    :param steps: steps (``num_timesteps``) of babbling, or ``"adaptive"``.
    :param mode: ``"sign"`` (each component -1 or +1, the paper) or ``"clamped_uniform"`` (uniform(-4, 4) clamped
        to [-1, 1], the EF authors' code).
    :param in_eval: while babbling is active, the model's ``predict`` (e.g. an ``EvalCallback``'s evaluation
        during training) babbles too, from a separate generator (the EF authors' Meta-World protocol).
    :param seed: seed of the babbling generators; ``None`` takes the model's ``seed``. A model that already holds
        a babbling state (a loaded checkpoint, an earlier ``learn``) continues it instead.
    :param min_steps: adaptive: babbling never ends before this step (default 0).
    :param max_steps: adaptive: babbling always ends at this step.
    :param patience: adaptive: evaluations in a row without improvement that make a plateau (default 3).
    :param min_delta: adaptive: relative improvement of the best score that counts (default 0.01: 1% lower).
    :param eval_freq: adaptive: steps between two evaluations (default 1000).
    :param eval_env: adaptive: a single env like the training one (same observations), in which
        ``holdout_steps`` babbling steps are recorded at the start of training; EF is scored on
        ``holdout_windows`` windows of them (never stored in the replay buffer).
    :param criterion: adaptive: ``criterion(model) -> float``, a non-negative score, lower is better; instead of
        ``eval_env``.
    :param holdout_steps: adaptive with ``eval_env``: babbling steps recorded in it (default 200).
    :param holdout_windows: adaptive with ``eval_env``: windows scored at each evaluation (default 64).
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

    # ------------------------------------------------------------------ state
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
            if getattr(getattr(model, "ef", None), "skip_channels", 0):
                raise ValueError("Adaptive babbling scores EF without U-Net skips (skip_channels=0)")
            expected, received = model.observation_space.shape, self.eval_env.observation_space.shape  # type: ignore[union-attr]
            if expected != received:
                raise ValueError(f"eval_env observations must have the model's shape {expected}, got {received}")

    # -------------------------------------------------------------- training
    def _on_training_start(self) -> None:
        model = self.model
        state = getattr(model, STATE_ATTRIBUTE, None)
        if state is None:
            state = BabblingState.seeded(model.seed if self.seed is None else self.seed)
            setattr(model, STATE_ATTRIBUTE, state)
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
        """Adaptive babbling's score of the model now (the criterion, or EF's held-out error ratio)."""
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

    # ------------------------------------------------------- model shadows
    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """The model's ``_sample_action`` while training: babbling actions while active, else the model's own."""
        active = self._update_end()
        self.logger.record("rollout/babbling", float(active))
        if not active:
            return self._shadowed["_sample_action"](learning_starts, action_noise, n_envs)
        buffer_action = babble(self.state.rng, (n_envs, *self.model.action_space.shape), self.mode)  # type: ignore[misc]
        return self.model.policy.unscale_action(buffer_action), buffer_action

    def _predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The model's ``predict`` while training with ``in_eval``: babbling actions while active."""
        if not self.active:
            return self._shadowed["predict"](observation, state, episode_start, deterministic)
        assert isinstance(observation, np.ndarray)  # image Boxes
        # Transposed first, as SB3's predict does (an env of channels-last frames gives channels-last observations).
        vectorized = is_vectorized_observation(
            maybe_transpose(observation, self.model.observation_space), self.model.observation_space
        )
        n_envs = len(observation) if vectorized else 1
        buffer_action = babble(self.state.eval_rng, (n_envs, *self.model.action_space.shape), self.mode)  # type: ignore[misc]
        actions = self.model.policy.unscale_action(buffer_action)
        return (actions if vectorized else actions[0]), state

    def _excluded_save_params(self) -> list[str]:
        """The model's, plus the shadows (a save during training stores the model, not this callback)."""
        return [*self._shadowed["_excluded_save_params"](), *self._shadowed]

    def _install(self) -> None:
        """Shadow the model's methods on the instance, for this ``learn``; a shadow left by a ``learn`` that
        raised is removed first, a second babbling callback in the same ``learn`` is refused."""
        model = self.model
        owner = getattr(vars(model).get("_sample_action"), "__self__", None)
        if isinstance(owner, MotorBabblingCallback):
            if owner._learn_start == model.start_time:
                raise ValueError(
                    "Two MotorBabblingCallbacks in one learn(): a host built with babbling_steps > 0 adds one "
                    "itself (build it with babbling_steps=0 to pass your own)"
                )
            owner._uninstall()
        methods = {"_sample_action": self._sample_action, "_excluded_save_params": self._excluded_save_params}
        if self.in_eval:
            methods["predict"] = self._predict
        self._shadowed = {name: getattr(model, name) for name in methods}
        self._instance_attributes = {name: vars(model)[name] for name in methods if name in vars(model)}
        vars(model).update(methods)
        self._learn_start = model.start_time

    def _uninstall(self) -> None:
        model = self.model
        for name in self._shadowed:
            vars(model).pop(name, None)
        vars(model).update(self._instance_attributes)
        self._shadowed, self._instance_attributes, self._learn_start = {}, {}, None


def with_babbling(babbling: MotorBabblingCallback, callback: MaybeCallback) -> list[BaseCallback]:
    """``babbling`` first, then the caller's ``callback`` (``None``, one callback, a list or a function)."""
    if callback is None:
        return [babbling]
    if isinstance(callback, list):
        return [babbling, *callback]
    if not isinstance(callback, BaseCallback):
        callback = ConvertCallback(callback)
    return [babbling, callback]
