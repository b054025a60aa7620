"""Optuna samplers: valid constructor arguments, merged policy kwargs, and -optimize on a shared sqlite storage."""

from __future__ import annotations

import inspect

import optuna
import pytest
import yaml
from huggingface_sb3 import EnvironmentName
from rl_zoo3.utils import get_latest_run_id

from sb3_ef.zoo import train
from sb3_ef.zoo.config import default_config_path, load_config
from sb3_ef.zoo.hyperparams_opt import CONVERTERS, SAMPLERS
from sb3_ef.zoo.registration import algorithm_classes
from tests.helpers.zoo import HYPERPARAMS, train_args

EF_KEYS = {"beta", "ef_horizon", "babbling_steps"}
LOG_NAME = "dmc-cartpole-swingup-v0"


@pytest.mark.parametrize("algo", sorted(SAMPLERS))
def test_samples_are_constructor_arguments_and_convert_back(algo):
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    trial = study.ask()
    base = {"net_arch": [32], "agent_dim": 32}
    sampled = SAMPLERS[algo](trial, 2, 1, {}, base_policy_kwargs=base)

    constructor = set(inspect.signature(algorithm_classes()[algo].__init__).parameters)
    assert set(sampled) <= constructor
    assert {"learning_rate", "batch_size"} <= set(sampled)
    assert (set(sampled) >= EF_KEYS) == algo.endswith("_ef")
    assert ("n_steps" in sampled and "exploration_std" in sampled) == algo.startswith("drqv2")
    assert ("horizon" in sampled) == algo.startswith("tdmpc2")
    if algo.endswith("_ef"):
        # agent_dim is tuned inside the entry's policy kwargs, which are kept.
        assert sampled["policy_kwargs"] == {"net_arch": [32], "agent_dim": trial.params["agent_dim"]}
    # rl-zoo3's --trial-id path converts the stored raw values: same arguments.
    assert CONVERTERS[algo](trial.params, base_policy_kwargs=base) == sampled


def test_optimize_continues_a_study_on_shared_sqlite_storage(tmp_path):
    """Two -optimize runs on one sqlite storage (as two machines would): the second adds to the first's study;
    a stored trial's parameters then train through --trial-id."""
    # A config file holding the small settings: rl-zoo3 applies --hyperparams after a stored trial's values,
    # so overrides given that way would hide the tuned ones.
    entry = {**load_config(default_config_path("drqv2_ef"))["default"], **HYPERPARAMS["drqv2_ef"]}
    entry["policy_kwargs"] = {**entry["policy_kwargs"], "features_dim": 128}  # > any sampled agent_dim
    conf = tmp_path / "tiny.yml"
    conf.write_text(yaml.safe_dump({"default": entry}))
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    args = train_args("drqv2_ef", "dmc/cartpole-swingup-v0", str(tmp_path / "logs"), n_timesteps=50)
    args = [*args[: args.index("--hyperparams")], "--conf-file", str(conf)]
    optimize = [
        *args, "-optimize", "--storage", storage, "--study-name", "tiny", "--n-trials", "1",
        "--n-evaluations", "1", "--eval-episodes", "1", "--pruner", "none", "--no-optim-plots",
    ]  # fmt: skip
    # Each worker needs its own --seed: the Optuna sampler is seeded with it.
    train.main([*optimize, "--seed", "1"])
    train.main([*optimize, "--seed", "2"])

    study = optuna.load_study(study_name="tiny", storage=storage)
    assert [trial.state for trial in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2
    assert study.trials[0].params != study.trials[1].params

    train.main([*args, "--storage", storage, "--study-name", "tiny", "--trial-id", "1"])
    log_path = tmp_path / "logs" / "drqv2_ef"
    run = get_latest_run_id(str(log_path), EnvironmentName("dmc/cartpole-swingup-v0"))
    model = algorithm_classes()["drqv2_ef"].load(log_path / f"{LOG_NAME}_{run}" / f"{LOG_NAME}.zip", device="cpu")
    params = study.trials[1].params
    assert model.batch_size == 2 ** params["batch_size_pow"]
    assert model.ef_horizon == params["ef_horizon"]
    assert model.policy.agent_dim == params["agent_dim"]
    assert model.policy.features_dim == 128  # the entry's other policy kwargs survive the tuned agent_dim
