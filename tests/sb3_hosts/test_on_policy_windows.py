"""EF's windows on on-policy rollouts: cut across episode ends and env boundaries, minibatches as SB3's, actions as
EF reads them, discrete babbling."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.envs import FakeImageEnv
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from sb3_ef import PPOEF
from sb3_ef.common.buffers.rollout_windows import (
    RolloutRing,
    RolloutWindows,
    action_encoding_dim,
    encode_actions,
    rollout_minibatches,
)
from sb3_ef.ef.babbling import babble_env_actions
from tests.sb3_hosts.test_on_policy import EF, POLICY


def hand_built_windows() -> RolloutWindows:
    """4 steps of 2 envs, 2 stacked 1-channel frames of 4x4; the newest frame of observation t of env e is filled
    with 10 e + t, and so is its action. Env 0's episodes start at steps 0 and 2; env 1's last step ends its episode."""
    newest = np.array([[10 * env + step for env in range(2)] for step in range(5)], dtype=np.float32)
    frames = np.broadcast_to(newest[:, :, None, None, None], (5, 2, 1, 4, 4))
    observations = np.concatenate([np.zeros_like(frames), frames], axis=2)  # (5, 2, 2, 4, 4): older frame zeros
    actions = th.as_tensor(newest[:4, :, None])
    episode_starts = np.array([[1, 0], [0, 0], [1, 0], [0, 0]], dtype=np.float32)
    return RolloutWindows(observations[:4], actions, episode_starts, observations[4], np.array([0, 1]), 1, 3)


@pytest.mark.parametrize(
    ("env", "step", "frames", "mask"),  # frames: the steps whose newest frame each target is
    [
        (0, 0, [1, 2, 3], [True, False, False]),  # step 1 ends env 0's first episode
        (0, 2, [3, 4, 4], [True, True, False]),  # the observation after the rollout, then past it
        (1, 1, [2, 3, 4], [True, True, False]),  # the rollout's last step ends env 1's episode
        (1, 3, [4, 4, 4], [False, False, False]),
    ],
)
def test_windows_stop_at_episode_ends_and_the_rollouts_end(env, step, frames, mask):
    window = hand_built_windows()(np.array([env * 4 + step]))  # SB3's flat index: env * n_steps + step
    assert window.observations.dtype == th.uint8 and window.observations.shape == (1, 2, 4, 4)
    assert int(window.observations[0, -1, 0, 0]) == 10 * env + step
    assert window.future_frames.shape == (1, 3, 1, 4, 4)
    assert window.future_frames[0, :, 0, 0, 0].tolist() == [10 * env + f for f in frames]
    assert window.future_mask[0].tolist() == mask
    actions = [10 * env + min(step + i, 3) for i in range(3)]
    assert window.future_actions[0, :, 0].tolist() == actions


def test_a_ring_cuts_windows_from_one_rollout_into_the_next():
    """The hand-built rollout split in two rollouts of 2 steps: the ring joins them again."""
    whole = hand_built_windows()
    ring = RolloutRing(2)
    for part in (slice(0, 2), slice(2, 4)):
        ring.add(whole.observations[part].numpy(), whole.actions[part], whole.continues.new_zeros(2, 2).numpy(), "cpu")
    starts = np.array([[1, 0], [0, 0], [1, 0], [0, 0]], dtype=np.float32)
    ring.rollouts[0] = (*ring.rollouts[0][:2], th.as_tensor(starts[:2]))
    ring.rollouts[1] = (*ring.rollouts[1][:2], th.as_tensor(starts[2:]))
    joined = ring.windows(whole.frames[-1:].expand(1, 2, 1, 4, 4)[0].numpy().repeat(2, axis=1), np.array([0, 1]), 1, 3)
    for index in range(8):
        expected, window = whole(np.array([index])), joined(np.array([index]))
        assert th.equal(window.future_mask, expected.future_mask)
        assert th.equal(window.future_frames[window.future_mask], expected.future_frames[expected.future_mask])


def test_valid_windows_follow_the_frame_stack_of_a_real_rollout():
    """In SB3's VecFrameStack the frame stack slides inside an episode and restarts with zeros at a reset: every valid
    step t+i of a window has observation t+i's newest frame one slot back in observation t+i+1, and its target is
    the newest frame of that observation."""
    env = VecFrameStack(DummyVecEnv([lambda: FakeImageEnv(screen_height=32, screen_width=32)] * 2), 2)
    model = PPOEF("CnnPolicy", env, n_steps=16, batch_size=32, policy_kwargs=dict(POLICY), seed=0, ef_rollouts=1, **EF)
    model.learn(32)  # two rollouts; FakeImageEnv's episodes last 10 steps
    buffer = model.rollout_buffer  # train() read (flattened) the last rollout: collect one more and cut it
    model.collect_rollouts(model.env, model._init_callback(None), buffer, model.n_steps)
    observations = np.concatenate([buffer.observations, model._last_obs[None]]).astype(np.uint8)
    window = model._rollout_windows()(np.arange(32))
    checked = 0
    for index in range(32):
        env_index, step = divmod(index, 16)
        for i in range(EF["ef_horizon"]):
            if not window.future_mask[index, i]:
                break
            following = observations[step + i + 1, env_index]
            assert np.array_equal(following[:1], observations[step + i, env_index][1:])
            assert np.array_equal(window.future_frames[index, i].numpy(), following[1:])
            checked += 1
    assert checked > 32  # most windows are valid; some stop at a reset
    assert not window.future_mask.all()


def test_minibatches_are_sb3s_own_with_their_indices():
    buffer = RolloutBuffer(4, spaces.Box(0, 255, (1, 2, 2), np.uint8), spaces.Discrete(3), n_envs=3)
    for step in range(4):
        observation = np.full((3, 1, 2, 2), step, np.float32) + 10 * np.arange(3)[:, None, None, None]
        buffer.add(observation, np.zeros((3, 1)), np.zeros(3), np.zeros(3), th.zeros(3), th.zeros(3))
    flat = buffer.swap_and_flatten(buffer.observations.copy())
    np.random.seed(0)
    batches = list(rollout_minibatches(buffer, 5))
    np.random.seed(0)
    expected = np.random.permutation(12)
    assert np.array_equal(np.concatenate([indices for indices, _ in batches]), expected)
    assert [len(indices) for indices, _ in batches] == [5, 5, 2]
    for indices, samples in batches:
        assert np.array_equal(samples.observations.numpy(), flat[indices])
        assert np.array_equal(samples.observations[:, 0, 0, 0].numpy(), 10 * (indices // 4) + indices % 4)


@pytest.mark.parametrize(
    ("space", "actions", "encoded"),
    [
        (spaces.Discrete(3), [[2.0], [0.0]], [[0, 0, 1], [1, 0, 0]]),
        (spaces.MultiDiscrete([2, 3]), [[1.0, 2.0]], [[0, 1, 0, 0, 1]]),
        (spaces.MultiBinary(2), [[1.0, 0.0]], [[1, 0]]),
        (spaces.Box(-2.0, 2.0, (2,)), [[-5.0, 1.0]], [[-1.0, 0.5]]),  # clipped as the env ran it, then in [-1, 1]
    ],
)
def test_actions_are_encoded_one_hot_or_scaled(space, actions, encoded):
    result = encode_actions(th.tensor(actions), space)
    assert result.dtype == th.float32 and result.shape[-1] == action_encoding_dim(space)
    assert result.tolist() == encoded


@pytest.mark.parametrize(
    "space", [spaces.Box(-np.inf, np.inf, (2,)), spaces.Dict({"a": spaces.Discrete(2)}), spaces.Tuple([])]
)
def test_spaces_ef_cannot_encode_are_named(space):
    with pytest.raises(ValueError, match=r"Box \(finite bounds\), Discrete, MultiDiscrete or MultiBinary space"):
        action_encoding_dim(space)


@pytest.mark.parametrize(
    "space", [spaces.Discrete(4), spaces.MultiDiscrete([2, 5]), spaces.MultiBinary(3), spaces.Box(-2.0, 3.0, (2,))]
)
def test_discrete_babbling_is_uniform_over_the_space(space):
    actions = babble_env_actions(np.random.default_rng(0), space, 4000)
    assert all(space.contains(action) for action in actions[:50])
    if isinstance(space, spaces.Discrete):
        counts = np.bincount(actions, minlength=4) / len(actions)
        np.testing.assert_allclose(counts, 0.25, atol=0.03)
    elif isinstance(space, spaces.Box):  # "sign" babbling: the bounds
        assert set(np.unique(actions)) == {-2.0, 3.0}
