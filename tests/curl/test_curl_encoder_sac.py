"""CURLEncoder as the features extractor of SB3's SAC: it trains and acts on whole frames through its centre crop."""

from __future__ import annotations

import torch as th
from stable_baselines3 import SAC

from sb3_ef.curl import CURLEncoder
from sb3_ef.envs.toy import ToyAgentEnv


def test_sac_with_the_curl_encoder_learns_and_acts_on_centre_crops():
    env = ToyAgentEnv(size=40, frame_stack=3, max_episode_steps=10)
    policy_kwargs = {
        "features_extractor_class": CURLEncoder,
        "features_extractor_kwargs": {"features_dim": 16, "crop_size": 32},
        "normalize_images": False,
        "net_arch": [32, 32],
    }
    model = SAC("CnnPolicy", env, buffer_size=64, learning_starts=8, batch_size=8, policy_kwargs=policy_kwargs, seed=0)
    encoder = model.critic.features_extractor
    before = [parameter.clone() for parameter in encoder.parameters()]
    model.learn(total_timesteps=16)
    assert isinstance(encoder, CURLEncoder) and encoder.crop_size == 32
    assert any(not th.equal(old, new) for old, new in zip(before, encoder.parameters(), strict=True))
    observation, _ = env.reset(seed=1)
    frames = th.as_tensor(observation)[None]
    with th.no_grad():
        assert th.equal(encoder(frames), encoder(frames[:, :, 4:36, 4:36]))
    action, _ = model.predict(observation, deterministic=True)
    assert action.shape == (2,)
