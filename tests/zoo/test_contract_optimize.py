"""-optimize prunes the trials whose sampled agent_dim leaves no scene features, and the study goes on."""

from __future__ import annotations

import optuna
import pytest
import yaml

from sb3_ef.zoo import train
from sb3_ef.zoo.config import default_config_path, load_config
from sb3_ef.zoo.hyperparams_opt import SAMPLERS
from tests.helpers.zoo import HYPERPARAMS, train_args

# Encoder feature sizes of the entries below: DrQv2-EF's projection, TD-MPC2's latent (16 per conv channel).
CASES = {"drqv2_ef": {"features_dim": 16}, "tdmpc2_ef": {"num_channels": 1}}


@pytest.mark.parametrize(("algo", "policy_kwargs"), CASES.items())
def test_a_trial_with_agent_dim_not_below_the_features_is_pruned(algo, policy_kwargs):
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for agent_dim in (16, 8):
        study.enqueue_trial({"agent_dim": agent_dim})
    pruned = study.ask()
    with pytest.raises(optuna.TrialPruned, match="agent_dim=16 leaves no scene features: the encoder gives 16"):
        SAMPLERS[algo](pruned, 2, 1, {}, base_policy_kwargs=policy_kwargs)
    kept = SAMPLERS[algo](study.ask(), 2, 1, {}, base_policy_kwargs=policy_kwargs)
    assert kept["policy_kwargs"] == {**policy_kwargs, "agent_dim": 8}


def test_defaults_of_the_policies_bound_agent_dim():
    # Without policy_kwargs: DrQv2-EF's 2048 features and TD-MPC2's 512-dim latent take every choice of agent_dim.
    for algo in CASES:
        study = optuna.create_study()
        study.enqueue_trial({"agent_dim": 64})
        assert SAMPLERS[algo](study.ask(), 2, 1, {})["policy_kwargs"] == {"agent_dim": 64}


@pytest.mark.slow
def test_optimize_goes_on_after_a_pruned_trial(tmp_path):
    entry = {**load_config(default_config_path("drqv2_ef"))["default"], **HYPERPARAMS["drqv2_ef"]}
    entry["policy_kwargs"] = {**entry["policy_kwargs"], "features_dim": 16}
    conf = tmp_path / "tiny.yml"
    conf.write_text(yaml.safe_dump({"default": entry}))
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    study = optuna.create_study(study_name="tiny", storage=storage, direction="maximize")
    study.enqueue_trial({"agent_dim": 16})  # as many as the features: the model cannot be built
    study.enqueue_trial({"agent_dim": 8})
    args = train_args("drqv2_ef", "dmc/cartpole-swingup-v0", str(tmp_path / "logs"), n_timesteps=50)
    args = [*args[: args.index("--hyperparams")], "--conf-file", str(conf)]
    train.main([
        *args, "-optimize", "--storage", storage, "--study-name", "tiny", "--n-trials", "2",
        "--n-evaluations", "1", "--eval-episodes", "1", "--pruner", "none", "--no-optim-plots",
    ])  # fmt: skip

    trials = optuna.load_study(study_name="tiny", storage=storage).trials
    assert [trial.params["agent_dim"] for trial in trials] == [16, 8]
    assert [trial.state for trial in trials] == [optuna.trial.TrialState.PRUNED, optuna.trial.TrialState.COMPLETE]
