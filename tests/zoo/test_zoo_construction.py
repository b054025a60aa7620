"""Every zoo_configs entry builds its env and model through rl-zoo3's ExperimentManager (one per suite and
algorithm by default, all of them in the slow test)."""

from __future__ import annotations

import argparse
from typing import Any

import pytest
from rl_zoo3.exp_manager import ExperimentManager

from sb3_ef.zoo.config import ZOO_ALGORITHMS, default_config_path, load_config, select_entry
from sb3_ef.zoo.registration import algorithm_classes, register_algorithms
from tests.helpers.zoo import ENV_KWARGS, HYPERPARAMS

SAMPLE_IDS = ("dmc/walker-walk-v0", "metaworld/hammer-v0")


def build(algo: str, env_id: str, log_folder: str, hyperparams: dict[str, Any], env_kwargs: dict[str, Any]):
    """rl-zoo3's own path from YAML entry to model, as `train` takes it (without learning)."""
    register_algorithms()
    manager = ExperimentManager(
        argparse.Namespace(),
        algo,
        env_id,
        log_folder,
        eval_freq=-1,
        hyperparams=hyperparams,
        env_kwargs=env_kwargs,
        seed=0,
        verbose=0,
        device="cpu",
        config=str(default_config_path(algo)),
    )
    model, _ = manager.setup_experiment()
    return model


def check_entry(algo: str, env_id: str, model, overrides: dict[str, Any], size: int) -> None:
    entry = {**select_entry(load_config(default_config_path(algo)), env_id), **overrides}
    try:
        assert type(model) is algorithm_classes()[algo]
        assert model.observation_space.shape == (9, size, size)
        assert model.env.envs[0].unwrapped.spec.id == env_id
        for key in ("buffer_size", "batch_size", "learning_starts", "tau", "n_steps", "horizon", "beta", "ef_horizon"):
            if key in entry:
                assert getattr(model, key) == entry[key], key
        assert getattr(model, "replay_buffer", None) is not None or model.rollout_buffer is not None
    finally:
        model.env.close()


@pytest.mark.parametrize("env_id", SAMPLE_IDS)
@pytest.mark.parametrize("algo", ZOO_ALGORITHMS)
def test_sample_entries_build_env_and_model(algo, env_id, tmp_path):
    model = build(algo, env_id, str(tmp_path), HYPERPARAMS[algo], ENV_KWARGS[algo])
    check_entry(algo, env_id, model, HYPERPARAMS[algo], ENV_KWARGS[algo]["size"])


@pytest.mark.slow
@pytest.mark.parametrize("algo", ZOO_ALGORITHMS)
def test_all_entries_build_env_and_model_at_paper_sizes(algo, tmp_path):
    """Paper networks and frame sizes; only the replay buffer is shrunk (1M frames would be ~21 GB at 84x84)."""
    overrides = {"buffer_size": 1000}
    config = load_config(default_config_path(algo))
    for env_id, entry in config.items():
        if env_id in ("default", "atari"):  # the atari entry: test_atari_entries_build_ef_on_grey_frame_stacks
            continue
        size = 64 if algo.startswith("tdmpc2") else 100 if algo == "curl" else 84
        env_kwargs = {**entry.get("env_kwargs", {}), "size": size, "fast_render": True}
        if env_id.startswith("dmc-distracting/"):  # the background needs DAVIS's videos; tests/envs builds it
            env_kwargs["distraction"] = ["camera", "color"]
        model = build(algo, env_id, str(tmp_path), overrides, env_kwargs)
        check_entry(algo, env_id, model, overrides, size)


@pytest.mark.parametrize(("algo", "n_envs"), [("ppo_ef", 8), ("a2c_ef", 16)])
def test_atari_entries_build_ef_on_grey_frame_stacks(algo, n_envs, tmp_path):
    """rl-zoo3 picks the ``atari`` entry for an ALE id: its AtariWrapper and 4 stacked grey frames, EF on the newest."""
    pytest.importorskip("ale_py")
    model = build(algo, "BreakoutNoFrameskip-v4", str(tmp_path), {"ef_kwargs": {"decoder_channels": 8}}, {})
    try:
        assert type(model) is algorithm_classes()[algo]
        assert (model.n_envs, model.observation_space.shape, model.frame_shape) == (n_envs, (4, 84, 84), (1, 84, 84))
        assert (model.ef.action_dim, model.ef_horizon, model.beta) == (4, 10, 1.0)
    finally:
        model.env.close()
