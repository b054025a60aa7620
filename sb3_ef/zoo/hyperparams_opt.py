"""Optuna samplers for rl-zoo3's ``-optimize``: Ego-Foresight's hyperparameters and each host's main ones.

Each algorithm has a *sampler* (``trial -> constructor kwargs``, rl-zoo3's ``HYPERPARAMS_SAMPLER`` signature) and
a *converter* (``trial.params -> constructor kwargs``, used by rl-zoo3 when ``--trial-id`` loads a stored trial).
The sampler only suggests raw values and hands them to the converter, so both always agree.

EF parameters: ``beta`` (loss weight), ``agent_dim`` (size of h_a, a policy argument), ``ef_horizon`` and
``babbling_steps``. Hosts: learning rate and batch size for both; DrQ-v2's n-step return and exploration-std
schedule; TD-MPC2's planning / world-model horizon.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import optuna

Params = dict[str, Any]


def _suggest_common(trial: optuna.Trial) -> None:
    trial.suggest_float("learning_rate", 1e-5, 1e-3, log=True)
    trial.suggest_int("batch_size_pow", 5, 9)


def _suggest_ef(trial: optuna.Trial, babbling_choices: list[int]) -> None:
    trial.suggest_float("beta", 0.01, 10.0, log=True)
    trial.suggest_categorical("agent_dim", [8, 16, 32, 64])
    trial.suggest_categorical("ef_horizon", [3, 5, 10, 15])
    trial.suggest_categorical("babbling_steps", babbling_choices)


def _suggest_drqv2(trial: optuna.Trial) -> None:
    _suggest_common(trial)
    trial.suggest_categorical("n_steps", [1, 3, 5])
    trial.suggest_categorical("std_final", [0.05, 0.1, 0.2])
    trial.suggest_categorical("std_duration", [100_000, 250_000, 500_000])


def _suggest_tdmpc2(trial: optuna.Trial) -> None:
    _suggest_common(trial)
    trial.suggest_int("horizon", 1, 5)


def convert_params(params: Params, base_policy_kwargs: Params | None = None) -> Params:
    """Map raw trial values (``trial.params``) to constructor kwargs, for any of the four algorithms: each
    conversion applies only when its raw values were sampled."""
    hyperparams = dict(params)
    if "batch_size_pow" in hyperparams:
        hyperparams["batch_size"] = 2 ** hyperparams.pop("batch_size_pow")
    if "std_final" in hyperparams:
        final, duration = hyperparams.pop("std_final"), hyperparams.pop("std_duration")
        hyperparams["exploration_std"] = f"linear(1.0,{final},{duration})"
    if "agent_dim" in hyperparams:
        hyperparams["policy_kwargs"] = {**(base_policy_kwargs or {}), "agent_dim": hyperparams.pop("agent_dim")}
    return hyperparams


def _sampler(suggest_host: Callable[[optuna.Trial], None], babbling_choices: list[int] | None) -> Callable[..., Params]:
    def sample(
        trial: optuna.Trial,
        n_actions: int,
        n_envs: int,
        additional_args: dict,
        base_policy_kwargs: Params | None = None,
    ) -> Params:
        suggest_host(trial)
        if babbling_choices is not None:
            _suggest_ef(trial, babbling_choices)
        return convert_params(trial.params, base_policy_kwargs)

    return sample


# Babbling choices around the paper's defaults: 12500 agent steps for DrQv2-EF, 1250 for TD-MPC2-EF.
sample_drqv2_ef_params = _sampler(_suggest_drqv2, [0, 5_000, 12_500, 25_000])
sample_drqv2_params = _sampler(_suggest_drqv2, None)
sample_tdmpc2_ef_params = _sampler(_suggest_tdmpc2, [0, 625, 1_250, 2_500])
sample_tdmpc2_params = _sampler(_suggest_tdmpc2, None)

SAMPLERS: dict[str, Callable[..., Params]] = {
    "drqv2_ef": sample_drqv2_ef_params,
    "drqv2": sample_drqv2_params,
    "tdmpc2_ef": sample_tdmpc2_ef_params,
    "tdmpc2": sample_tdmpc2_params,
}

CONVERTERS: dict[str, Callable[..., Params]] = dict.fromkeys(SAMPLERS, convert_params)
