"""experiments/2026-cpu-grid/ef_gradients.py diagnoses every checkpoint of a run folder, in step order."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch as th

from sb3_ef.common.checkpoints import ResumableCheckpointCallback
from sb3_ef.drqv2 import DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv

SCRIPT = Path(__file__).resolve().parents[1] / "ef_gradients.py"


def load_script():
    spec = importlib.util.spec_from_file_location("ef_gradients", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_majority_share_per_column():
    script = load_script()
    # column 0: 3 of 4 positive -> 0.75; column 1: 2 of 4 -> 0.5
    values = th.tensor([[1.0, -1.0], [0.5, 1.0], [-1.0, 1.0], [1.0, -0.2]])
    assert script.majority_share(values) == pytest.approx(0.625)
    assert script.majority_share(th.ones(5, 1)) == 1.0


def test_every_checkpoint_is_diagnosed(tmp_path):
    script = load_script()
    tiny = {"net_arch": [16], "trunk_dim": 8, "features_dim": 16, "agent_dim": 4,
            "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}  # fmt: skip
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32, max_episode_steps=10), buffer_size=200, batch_size=8,
                    learning_starts=20, train_freq=1, ef_horizon=3, babbling_steps=0, policy_kwargs=tiny,
                    seed=0)  # fmt: skip
    model.learn(70, callback=ResumableCheckpointCallback(30, str(tmp_path)))  # writes at 30 and 60
    (tmp_path / "rl_model_90_steps.zip").write_bytes(b"")  # no replay buffer beside it: not a pair
    pairs = script.checkpoint_pairs(str(tmp_path))
    assert [Path(model_path).name for model_path, _ in pairs] == ["rl_model_30_steps.zip", "rl_model_60_steps.zip"]
    row = script.diagnose("drqv2_ef", *pairs[-1], batch_size=8, seed=0)
    assert row["step"] == 60
    assert row["encoder_grad_norm_critic"] > 0 and row["encoder_grad_norm_ef"] > 0 and row["beta_ef_loss"] > 0
    assert 0.5 <= row["action_majority"] <= 1 and 0.5 <= row["critic_majority"] <= 1
    assert row["feature_spread"] > 0 and row["action_std"] >= 0
    with pytest.raises(FileNotFoundError, match=r"No rl_model_<N>_steps\.zip"):
        script.checkpoint_pairs(str(tmp_path / "nothing"))
