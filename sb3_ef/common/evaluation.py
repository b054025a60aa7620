"""Evaluations reseeded from the run's seed and the step, so a resumed run records the uninterrupted curve."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecEnv

#: Offset added to a run's seed for its evaluation episodes, so they differ from the training ones.
EVAL_SEED_OFFSET = 10_000


def evaluation_seed(seed: int, step: int) -> int:
    """The seed of the evaluation episodes at agent step ``step`` of a run trained with ``seed``."""
    return int(np.random.SeedSequence([seed + EVAL_SEED_OFFSET, step]).generate_state(1)[0])


class StepSeededEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` reseeding ``eval_env`` from the run's ``seed`` and the step before each evaluation."""

    def __init__(self, eval_env: VecEnv, seed: int, **kwargs: Any):
        super().__init__(eval_env, **kwargs)
        self.seed = seed

    @classmethod
    def replacing(cls, callback: EvalCallback, seed: int) -> StepSeededEvalCallback:
        """A step-seeded copy of an unused ``callback`` built elsewhere (rl-zoo3's)."""
        assert isinstance(callback.eval_env, VecEnv)  # EvalCallback wraps any env into one
        return cls(
            callback.eval_env,
            seed,
            callback_on_new_best=callback.callback_on_new_best,
            callback_after_eval=callback.callback,
            n_eval_episodes=callback.n_eval_episodes,
            eval_freq=callback.eval_freq,
            # EvalCallback appends "evaluations" to the folder it is given.
            log_path=None if callback.log_path is None else os.path.dirname(callback.log_path),
            best_model_save_path=callback.best_model_save_path,
            deterministic=callback.deterministic,
            render=callback.render,
            verbose=callback.verbose,
            warn=callback.warn,
        )

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self.eval_env.seed(evaluation_seed(self.seed, self.num_timesteps))
        return super()._on_step()
