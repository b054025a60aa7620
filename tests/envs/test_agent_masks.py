"""make_env(..., agent_masks=True) on a real DMC task: the masks in the infos, and the replay buffer storing one per
frame (SB3's TD3 collecting, so only step infos reach add()) and sampling each observation's masks."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import TD3
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.common.buffers import MASKS_INFO_KEY, SequenceReplayBuffer
from sb3_ef.envs import make_env
from sb3_ef.envs.pixel_env import AGENT_MASKS_INFO_KEY

SIZE = 64  # SB3's NatureCNN needs more than 36 pixels
STACK = 3


def test_infos_carry_the_masks_of_every_frame_and_the_env_says_so():
    env = make_env("dmc/cartpole-swingup", size=SIZE, frame_stack=STACK, seed=0, agent_masks=True)
    plain = make_env("dmc/cartpole-swingup", size=SIZE, seed=0)
    try:
        assert env.agent_masks and not plain.agent_masks
        assert DummyVecEnv([lambda: env]).get_attr("agent_masks") == [True]
        assert env.spec.kwargs["agent_masks"] is True and gym.make(env.spec).unwrapped.agent_masks
        _, info = env.reset(seed=1)
        masks = info[AGENT_MASKS_INFO_KEY]
        assert masks.shape == (STACK, SIZE, SIZE) and masks.dtype == bool
        assert (masks == env.agent_mask()).all() and 0 < masks[0].sum() < SIZE * SIZE  # the cart and pole
        previous = masks
        for _ in range(4):
            _, _, _, _, info = env.step(np.ones(1, np.float32))
            masks = info[AGENT_MASKS_INFO_KEY]
            assert masks.shape == (STACK + 1, SIZE, SIZE)
            np.testing.assert_array_equal(masks[:-1], previous)  # the observation the action was taken from
            np.testing.assert_array_equal(masks[-1], env.agent_mask())  # the new frame's
            previous = masks[1:]
        assert not np.array_equal(masks[0], masks[-1])  # the cart moved
        _, info = plain.reset(seed=1)
        assert AGENT_MASKS_INFO_KEY not in info
    finally:
        env.close()
        plain.close()


def test_make_env_refuses_a_non_boolean_agent_masks():
    with pytest.raises(ValueError, match="agent_masks must be True or False, got 'yes'"):
        make_env("dmc/cartpole-swingup", size=32, agent_masks="yes")


class FrameMaskLog(gym.Wrapper):
    """Records the env's own mask (``agent_mask()``, not the infos) of every frame it shows, keyed by the frame."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.masks: dict[bytes, np.ndarray] = {}

    def _log(self, obs: np.ndarray) -> None:
        self.masks[obs[-3:].tobytes()] = self.env.unwrapped.agent_mask()

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._log(obs)
        return obs, info

    def step(self, action):
        obs, *rest = self.env.step(action)
        self._log(obs)
        return obs, *rest


def test_sampled_masks_are_the_env_masks_of_the_observation_frames_and_survive_pickling():
    def make(seed: int):
        return lambda: FrameMaskLog(
            make_env(
                "dmc/cartpole-swingup", size=SIZE, frame_stack=STACK, seed=seed, agent_masks=True, episode_length=24
            )
        )

    env = DummyVecEnv([make(0), make(1)])  # 12 agent steps per episode: several first observations are stored
    try:
        model = TD3(
            "CnnPolicy",
            env,
            buffer_size=400,
            learning_starts=1000,  # collect only
            replay_buffer_class=SequenceReplayBuffer,
            replay_buffer_kwargs={"store_masks": True, "horizon": 2},
            seed=0,
            device="cpu",
        )
        model.learn(60)
        buffer = model.replay_buffer
        assert buffer.size() == 60
        logged = {key: mask for log in env.get_attr("masks") for key, mask in log.items()}
        batch = buffer.sample(256)
        assert batch.masks.shape == (256, STACK, SIZE, SIZE) and batch.masks.dtype == th.uint8
        observations, masks = batch.observations.numpy(), batch.masks.numpy()
        assert set(np.unique(masks)) == {0, 1}
        for obs, obs_masks in zip(observations, masks, strict=True):
            for j in range(STACK):
                np.testing.assert_array_equal(obs_masks[j], logged[obs[3 * j : 3 * j + 3].tobytes()])

        loaded = pickle.loads(pickle.dumps(buffer))
        buffer.seed(3)
        loaded.seed(3)
        expected, got = buffer.sample(64), loaded.sample(64)
        np.testing.assert_array_equal(got.masks.numpy(), expected.masks.numpy())
        np.testing.assert_array_equal(got.observations.numpy(), expected.observations.numpy())
    finally:
        env.close()


def test_the_buffer_reads_the_key_the_env_writes():
    assert MASKS_INFO_KEY == AGENT_MASKS_INFO_KEY
