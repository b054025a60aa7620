"""Optuna samplers for rl-zoo3's ``-optimize``: EF's and each host's hyperparameters, mapped by one converter."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import optuna

from sb3_ef.drqv2.policies import DrQv2Policy
from sb3_ef.tdmpc2.policies import TDMPC2Policy

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
    """Map raw trial values (``trial.params``) to constructor kwargs; each conversion applies when sampled."""
    hyperparams = dict(params)
    if "batch_size_pow" in hyperparams:
        hyperparams["batch_size"] = 2 ** hyperparams.pop("batch_size_pow")
    if "std_final" in hyperparams:
        final, duration = hyperparams.pop("std_final"), hyperparams.pop("std_duration")
        hyperparams["exploration_std"] = f"linear(1.0,{final},{duration})"
    if "agent_dim" in hyperparams:
        hyperparams["policy_kwargs"] = {**(base_policy_kwargs or {}), "agent_dim": hyperparams.pop("agent_dim")}
    return hyperparams


def _policy_default(policy_class: type, name: str) -> Any:
    return inspect.signature(policy_class).parameters[name].default


def _drqv2_feature_dim(policy_kwargs: Params) -> int | None:
    """Size of DrQv2-EF's features (its projection); ``None``: DrQ-v2's unprojected conv output, always larger."""
    return policy_kwargs.get("features_dim", _policy_default(DrQv2Policy, "features_dim"))


def _tdmpc2_feature_dim(policy_kwargs: Params) -> int:
    """Size of TD-MPC2's latent: 16 per conv channel (its encoder maps 64x64 frames to a 4x4 grid)."""
    return 16 * policy_kwargs.get("num_channels", _policy_default(TDMPC2Policy, "num_channels"))


def _prune_if_no_scene_features(trial: optuna.Trial, feature_dim: int | None) -> None:
    """Prune a trial whose ``agent_dim`` takes every feature: rl-zoo3 would stop the study on the build error."""
    agent_dim = trial.params["agent_dim"]
    if feature_dim is not None and agent_dim >= feature_dim:
        raise optuna.TrialPruned(
            f"agent_dim={agent_dim} leaves no scene features: the encoder gives {feature_dim} features"
        )


def _sampler(
    suggest_host: Callable[[optuna.Trial], None],
    babbling_choices: list[int] | None,
    feature_dim: Callable[[Params], int | None] | None = None,
) -> Callable[..., Params]:
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
        if feature_dim is not None:
            _prune_if_no_scene_features(trial, feature_dim(base_policy_kwargs or {}))
        return convert_params(trial.params, base_policy_kwargs)

    return sample


#: The Optuna sampler of each registry key ``sb3-ef optimize`` tunes; a key without one is refused. Babbling choices
#: around the paper's defaults: 12500 agent steps for DrQv2-EF, 1250 for TD-MPC2-EF.
SAMPLERS: dict[str, Callable[..., Params]] = {
    "drqv2_ef": _sampler(_suggest_drqv2, [0, 5_000, 12_500, 25_000], _drqv2_feature_dim),
    "drqv2": _sampler(_suggest_drqv2, None),
    "tdmpc2_ef": _sampler(_suggest_tdmpc2, [0, 625, 1_250, 2_500], _tdmpc2_feature_dim),
    "tdmpc2": _sampler(_suggest_tdmpc2, None),
}

CONVERTERS: dict[str, Callable[..., Params]] = dict.fromkeys(SAMPLERS, convert_params)
