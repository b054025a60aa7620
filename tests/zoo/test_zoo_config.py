"""zoo_configs/*.yml: paper tasks and hyperparameters, every entry's keys and env id, and clear config errors."""

from __future__ import annotations

import pytest

from sb3_ef.envs.tasks import DMC_PAPER_TASKS, METAWORLD_PAPER_TASKS
from sb3_ef.zoo.config import (
    PAPER_ALGORITHMS,
    default_config_path,
    load_config,
    select_entry,
    validate_config,
)
from sb3_ef.zoo.registration import algorithm_classes
from sb3_ef.zoo.train import prepare

PAPER_IDS = {f"dmc/{task}-v0" for task in DMC_PAPER_TASKS} | {f"metaworld/{task}-v0" for task in METAWORLD_PAPER_TASKS}


@pytest.fixture(scope="module")
def classes() -> dict[str, type]:
    return algorithm_classes()


@pytest.mark.parametrize("algo", PAPER_ALGORITHMS)
def test_every_entry_is_valid_and_the_paper_tasks_present(algo, classes):
    config = load_config(default_config_path(algo))
    assert set(config) >= PAPER_IDS | {"default"}
    assert len(PAPER_IDS) == 12 + 16
    validate_config(algo, classes[algo], config, source=f"{algo}.yml")


@pytest.mark.parametrize("algo", ["drqv2_ef", "drqv2"])
def test_drqv2_paper_hyperparameters(algo):
    config = load_config(default_config_path(algo))
    for env_id in ("dmc/walker-walk-v0", "dmc/walker-run-v0"):
        assert (config[env_id]["n_steps"], config[env_id]["batch_size"]) == (1, 512)
    assert config["dmc/finger-spin-v0"]["exploration_std"] == "linear(1.0,0.1,100000)"
    assert config["dmc/walker-walk-v0"]["exploration_std"] == "linear(1.0,0.1,100000)"
    assert config["dmc/cheetah-run-v0"]["exploration_std"] == "linear(1.0,0.1,500000)"
    assert config["dmc/cheetah-run-v0"]["n_steps"] == 3
    for task in METAWORLD_PAPER_TASKS:
        entry = config[f"metaworld/{task}-v0"]
        assert entry["buffer_size"] == 250_000
        assert entry["n_timesteps"] * 2 == 2_500_000  # frames at action repeat 2
        assert entry["exploration_std"] == "linear(1.0,0.1,500000)"


@pytest.mark.parametrize("algo", ["tdmpc2_ef", "tdmpc2"])
def test_tdmpc2_entries_use_64_pixel_frames(algo):
    config = load_config(default_config_path(algo))
    assert all(entry["env_kwargs"]["size"] == 64 for entry in config.values())


def test_ef_entries_follow_the_paper():
    drqv2_ef = select_entry(load_config(default_config_path("drqv2_ef")), "dmc/cheetah-run-v0")
    assert (drqv2_ef["beta"], drqv2_ef["ef_horizon"], drqv2_ef["babbling_steps"]) == (1.0, 10, 12_500)
    tdmpc2_ef = select_entry(load_config(default_config_path("tdmpc2_ef")), "dmc/cheetah-run-v0")
    assert (tdmpc2_ef["beta"], tdmpc2_ef["ef_horizon"], tdmpc2_ef["babbling_steps"]) == (1.0, 10, 1_250)


def test_unknown_env_falls_back_to_default():
    config = load_config(default_config_path("drqv2_ef"))
    assert select_entry(config, "dmc/hopper-hop-v0") == config["default"]
    with pytest.raises(ValueError, match="no 'default' entry"):
        select_entry({"dmc/cheetah-run-v0": {}}, "dmc/hopper-hop-v0")


ENTRY = {"policy": "CnnPolicy", "n_timesteps": 100}


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"dmc/cheetah-run-v0": {**ENTRY, "learning_rat": 1e-4}}, r"'dmc/cheetah-run-v0'.*unknown key 'learning_rat'"),
        ({"default": {**ENTRY, "frame_stack": 3}}, r"'frame_stack' is not supported.*env_kwargs"),
        ({"default": {**ENTRY, "seed": 3}}, r"unknown key 'seed'"),
        ({"dmc/cheetah-walk-v0": ENTRY}, r"env id 'dmc/cheetah-walk-v0' is not registered"),
        ({"default": {"policy": "CnnPolicy"}}, r"missing required key 'n_timesteps'"),
    ],
)
def test_bad_entries_are_named(config, message, classes):
    with pytest.raises(ValueError, match=message):
        validate_config("drqv2_ef", classes["drqv2_ef"], config)


@pytest.mark.parametrize(
    "callback",
    ["rl_zoo3.callbacks.ParallelTrainCallback", [{"rl_zoo3.callbacks.ParallelTrainCallback": {"gradient_steps": 8}}]],
)
def test_parallel_training_is_refused_at_once_with_the_reason_and_what_to_do(callback, classes):
    """rl-zoo3's ParallelTrainCallback reloads the model as SAC or TQC and trains that copy, without EF."""
    with pytest.raises(ValueError, match=r"ParallelTrainCallback is not supported.*without the auxiliary.*train_freq"):
        validate_config("sac_ef", classes["sac_ef"], {"default": {**ENTRY, "callback": callback}})
    with pytest.raises(ValueError, match=r"--hyperparams: callback ParallelTrainCallback"):
        prepare(["--algo", "sac_ef", "--env", "dmc/cheetah-run-v0", "-params", f"callback:{callback!r}"])


def test_plain_host_rejects_ef_keys(classes):
    with pytest.raises(ValueError, match="unknown key 'beta' for drqv2"):
        validate_config("drqv2", classes["drqv2"], {"default": {**ENTRY, "beta": 1.0}})


def test_bad_files_and_algorithms(tmp_path):
    with pytest.raises(ValueError, match="No default zoo config for algorithm 'ppo'"):
        default_config_path("ppo")
    path = tmp_path / "bad.yml"
    path.write_text("- just\n- a list\n")
    with pytest.raises(ValueError, match="expected a mapping of env id"):
        load_config(path)
