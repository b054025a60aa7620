"""ShiftedSequenceReplayBuffer: the context and its future frames move together, the next observations apart."""

import numpy as np
import pytest
import torch as th

from sb3_ef import SACEF
from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.sb3_hosts import ShiftedSequenceReplayBuffer


def _shift(image: th.Tensor, dy: int, dx: int) -> th.Tensor:
    """Replicate-pad shift of a (C, h, w) image by (dy, dx) pixels."""
    height, width = image.shape[-2:]
    rows = (th.arange(height) + dy).clamp(0, height - 1)
    cols = (th.arange(width) + dx).clamp(0, width - 1)
    return image[:, rows][:, :, cols]


def _offsets(shifted: th.Tensor, original: th.Tensor, pad: int) -> set[tuple[int, int]]:
    return {
        (dy, dx)
        for dy in range(-pad, pad + 1)
        for dx in range(-pad, pad + 1)
        if th.equal(shifted, _shift(original, dy, dx))
    }


def test_samples_share_one_shift_between_context_and_future_frames():
    env = ToyAgentEnv(size=16, max_episode_steps=50)  # one episode, no reset needed
    buffers = [
        SequenceReplayBuffer(50, env.observation_space, env.action_space, horizon=3),
        ShiftedSequenceReplayBuffer(50, env.observation_space, env.action_space, horizon=3, shift_pad=2),
    ]
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        next_obs, reward, terminated, _, info = env.step(action)
        for buffer in buffers:
            buffer.add(obs[None], next_obs[None], action[None], np.array([reward]), np.array([terminated]), [info])
        obs = next_obs
    np.random.seed(1)
    plain = buffers[0].sample(6)
    np.random.seed(1)
    shifted = buffers[1].sample(6)
    assert th.equal(plain.actions, shifted.actions)  # the same transitions, only shifted
    for sample in range(6):
        common = _offsets(shifted.observations[sample], plain.observations[sample], pad=2)
        for step in range(3):
            common &= _offsets(shifted.future_frames[sample, step], plain.future_frames[sample, step], pad=2)
        assert common, f"no single shift explains sample {sample}"
        assert _offsets(shifted.next_observations[sample], plain.next_observations[sample], pad=2)


def test_a_host_trains_with_it():
    env = ToyAgentEnv(size=32, max_episode_steps=20)
    model = SACEF(
        "CnnPolicy", env, buffer_size=100, learning_starts=10, batch_size=4, ef_horizon=3, agent_dim=8,
        replay_buffer_class=ShiftedSequenceReplayBuffer, replay_buffer_kwargs={"shift_pad": 2},
        ef_kwargs={"rollout_hidden_dims": (8,), "decoder_channels": 4},
        policy_kwargs={"net_arch": [8], "normalize_images": False, "features_extractor_class": DrQv2Encoder,
                       "features_extractor_kwargs": {"features_dim": 16}},
    )  # fmt: skip
    assert isinstance(model.replay_buffer, ShiftedSequenceReplayBuffer) and model.replay_buffer.shift_pad == 2
    model.learn(12)
    assert np.isfinite(model.logger.name_to_value["train/ef_loss"])


def test_negative_pad_is_rejected():
    env = ToyAgentEnv(size=16)
    with pytest.raises(ValueError, match="shift_pad must be >= 0, got -1"):
        ShiftedSequenceReplayBuffer(10, env.observation_space, env.action_space, shift_pad=-1)
