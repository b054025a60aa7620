"""PPO-EF learns from pixels: the toy world's agent brought to the centre, which a policy blind to the image cannot."""

import pytest
from stable_baselines3.common.env_util import make_vec_env

from sb3_ef import PPOEF
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.learning import trained_and_random_returns


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20)


@pytest.mark.slow
def test_ppo_ef_learns_to_bring_the_agent_to_the_centre():
    """Reward: minus the agent's distance to the frame centre, so the policy must find the red square in the image.
    Random actions earn about -6.7 per 20-step episode; PPO-EF after 4096 steps about -1.0 (~1-2.5 min on 2 loaded
    cores)."""
    policy = {
        "net_arch": [64],
        "normalize_images": False,
        "features_extractor_class": DrQv2Encoder,
        "features_extractor_kwargs": {"features_dim": 64},
    }
    model = PPOEF(
        "CnnPolicy", make_vec_env(toy_env, n_envs=8, seed=0), n_steps=32, batch_size=64, n_epochs=4,
        learning_rate=1e-3, policy_kwargs=policy, ef_horizon=3, agent_dim=8,
        ef_kwargs={"rollout_hidden_dims": (32,), "decoder_channels": 16}, seed=0,
    )  # fmt: skip
    model.learn(4096)
    trained, baseline = trained_and_random_returns(model, toy_env)
    assert baseline < -4.0 and trained > baseline + 2.5
