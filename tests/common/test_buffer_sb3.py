"""SequenceReplayBuffer as SB3's replay_buffer_class: a real TD3 run on a tiny frame-stacking image env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import TD3
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from sb3_ef import DrQv2EF
from sb3_ef.common.buffers import SequenceReplayBuffer, storage
from sb3_ef.envs.toy import ToyAgentEnv

FRAME_STACK = 2
SIZE = 8


class TinyImageEnv(gym.Env):
    """Random 3x8x8 frames stacked oldest first (reset repeats the first frame); remembers every emitted obs."""

    def __init__(self):
        self.observation_space = spaces.Box(0, 255, (3 * FRAME_STACK, SIZE, SIZE), np.uint8)
        self.action_space = spaces.Box(-1, 1, (2,), np.float32)
        self.emitted: set[bytes] = set()

    def _emit(self, frame: np.ndarray | None = None) -> np.ndarray:
        new = self.np_random.integers(0, 256, (3, SIZE, SIZE), dtype=np.uint8)
        self.obs = np.concatenate([new] * FRAME_STACK) if frame is None else np.concatenate([self.obs[3:], new])
        self.emitted.add(self.obs.tobytes())
        return self.obs.copy()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self._emit(), {}

    def step(self, action):
        terminated = bool(self.np_random.random() < 0.1)
        return self._emit(self.obs), -float(np.square(action).sum()), terminated, False, {}


class TinyCnn(BaseFeaturesExtractor):
    def __init__(self, observation_space: spaces.Box, features_dim: int = 16):
        super().__init__(observation_space, features_dim)
        channels = observation_space.shape[0]
        self.net = th.nn.Sequential(
            th.nn.Conv2d(channels, 4, 3, stride=2), th.nn.ReLU(), th.nn.Flatten(), th.nn.LazyLinear(features_dim)
        )
        self.net(th.zeros(1, *observation_space.shape))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations)


def make_td3(seed: int = 0) -> TD3:
    env = make_vec_env(
        TinyImageEnv, n_envs=2, seed=seed, wrapper_class=gym.wrappers.TimeLimit, wrapper_kwargs={"max_episode_steps": 6}
    )
    return TD3(
        "CnnPolicy",
        env,
        buffer_size=400,
        learning_starts=10,
        batch_size=8,
        train_freq=1,
        seed=seed,
        device="cpu",
        replay_buffer_class=SequenceReplayBuffer,
        replay_buffer_kwargs={"n_steps": 3, "horizon": 4},
        policy_kwargs={"features_extractor_class": TinyCnn, "net_arch": [8]},
    )


def emitted(model: TD3) -> set[bytes]:
    return set().union(*model.get_env().get_attr("emitted"))


def test_td3_learns_from_sequence_buffer(tmp_path):
    model = make_td3()
    model.learn(30)
    model.learn(20)  # resets the envs mid-episode without a done: the buffer must start new episodes
    buffer = model.replay_buffer
    assert isinstance(buffer, SequenceReplayBuffer)
    assert buffer.size() == 30 + 20  # one transition per env step, counted over both learn() calls
    assert model._n_updates > 0

    batch = buffer.sample(64)
    seen = emitted(model)
    for obs, next_obs in zip(batch.observations.numpy(), batch.next_observations.numpy(), strict=True):
        assert obs.tobytes() in seen and next_obs.tobytes() in seen
    # SB3's ReplayBuffer arrays: 25 add() calls of 2 envs; row pos - 1 holds the last call's steps.
    assert buffer.observations.shape == (200, 2, 3 * FRAME_STACK, SIZE, SIZE) and buffer.actions.shape == (200, 2, 2)
    assert all(obs.tobytes() in seen for obs in buffer.observations[buffer.pos - 1])
    assert buffer.pos == 25 and buffer.rewards[: buffer.pos].shape == (25, 2) and buffer.dones.dtype == np.float32

    model.save_replay_buffer(tmp_path / "buffer")
    other = make_td3(seed=1)
    other.load_replay_buffer(tmp_path / "buffer")
    expected = buffer.sample(16)  # the pickle carries the sampling generator: both draw the same batch
    got = other.replay_buffer.sample(16)
    for name, value in expected._asdict().items():
        assert (getattr(got, name) is None) if value is None else th.equal(getattr(got, name), value), name


def test_a_model_whose_buffer_does_not_fit_in_ram_loads_and_acts(tmp_path, monkeypatch):
    """SB3's load rebuilds the saved 1M-frame buffer (3.1 GB at 32x32): it is only reserved by the first add()."""
    monkeypatch.setattr(storage, "available_host_memory", lambda: 10**8)  # 0.1 GB of RAM left
    env = ToyAgentEnv(size=32, max_episode_steps=10)
    policy_kwargs = {"net_arch": [16], "trunk_dim": 8, "features_dim": 32, "agent_dim": 4}
    policy_kwargs["ef_kwargs"] = {"rollout_hidden_dims": (8,), "decoder_channels": 4}
    model = DrQv2EF(
        "CnnPolicy", env, buffer_size=1_000_000, learning_starts=4, ef_horizon=3, policy_kwargs=policy_kwargs, seed=0
    )
    assert model.replay_buffer.nbytes > 3 * 10**9
    model.save(tmp_path / "model.zip")

    loaded = DrQv2EF.load(tmp_path / "model.zip", env=env, device="cpu")
    obs, _ = env.reset(seed=1)
    action, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_allclose(action, model.predict(obs, deterministic=True)[0])
    assert loaded.replay_buffer.buffer_size == 1_000_000
    with pytest.raises(MemoryError, match=r"needs 3\.\d\d GB .* but only 0\.10 GB of RAM are available"):
        loaded.learn(2)  # training refuses at the first add(), before any frame is stored
    assert loaded.replay_buffer.size() == 0
