"""SequenceReplayBuffer(store_masks=True): one bit-packed mask per stored frame, each observation's masks sampled.

The encoded streams of test_buffers.py get a mask per frame derived from the frame itself, passed as an env made with
``make_env(..., agent_masks=True)`` passes them: the step info holds the masks of obs's frames and of the new frame.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from gymnasium import spaces
from test_buffers import ACTION_DIM, FRAME, GAMMA, STORAGES, Streams, check_against_reference, make_buffer

from sb3_ef.common.buffers import MASKS_INFO_KEY, SequenceReplayBuffer


def mask_of(frame: np.ndarray) -> np.ndarray:
    """A 0/1 pattern that only this frame (its env, episode and step) has."""
    return np.random.default_rng(frame[:, 0, 0].tolist()).integers(0, 2, frame.shape[1:], dtype=np.uint8)


def with_masks(obs, next_obs, infos, frame_shape=FRAME):
    """``infos`` with the masks an env with agent masks sends: those of obs's k frames, then the new frame's."""
    for env, info in enumerate(infos):
        frames = np.concatenate([obs[env], next_obs[env, -3:]]).reshape(-1, *frame_shape)
        info[MASKS_INFO_KEY] = np.stack([mask_of(frame) for frame in frames]).astype(bool)
    return infos


class MaskingEnvs:
    """Passes a stream's steps on to a buffer with the masks added to the infos."""

    def __init__(self, buffer: SequenceReplayBuffer):
        self.buffer = buffer

    def add(self, obs, next_obs, action, reward, done, infos):
        self.buffer.add(obs, next_obs, action, reward, done, with_masks(obs, next_obs, infos))


def assert_masks_match(buffer: SequenceReplayBuffer, batch_size: int = 200) -> None:
    batch = buffer.sample(batch_size)
    observations, masks = batch.observations.cpu().numpy(), batch.masks.cpu().numpy()
    assert masks.shape == (batch_size, 3, *FRAME[1:]) and masks.dtype == np.uint8
    for obs, obs_masks in zip(observations, masks, strict=True):
        for j, frame in enumerate(obs.reshape(3, *FRAME)):
            np.testing.assert_array_equal(obs_masks[j], mask_of(frame))


@pytest.mark.parametrize("storage", STORAGES)
def test_each_observation_gets_the_masks_of_its_frames_while_rings_wrap(storage):
    buffer = make_buffer(2, 3, 16, storage, n_steps=3, gamma=GAMMA, horizon=4, store_masks=True)
    streams = Streams(2, 3, 5, "distinct", True, seed=4)  # short episodes, cut ones included: many first observations
    for _ in range(6):
        for _ in range(9):
            streams.step(MaskingEnvs(buffer))
        assert_masks_match(buffer)
        check_against_reference(buffer, streams)  # masks change nothing else
    loaded = pickle.loads(pickle.dumps(buffer))
    for _ in range(9):
        streams.step(MaskingEnvs(buffer), MaskingEnvs(loaded))
    assert_masks_match(loaded)
    buffer.seed(1)
    loaded.seed(1)
    np.testing.assert_array_equal(loaded.sample(32).masks.cpu(), buffer.sample(32).masks.cpu())


def test_masks_of_an_odd_frame_size_and_their_bytes():
    """3x5 frames: 15 mask bits take 2 bytes per frame; sampled masks keep the frame's height and width."""
    space = spaces.Box(0, 255, (6, 3, 5), np.uint8)
    actions = spaces.Box(-1, 1, (ACTION_DIM,), np.float32)
    buffer = SequenceReplayBuffer(40, space, actions, device="cpu", horizon=2, store_masks=True)
    plain = SequenceReplayBuffer(40, space, actions, device="cpu", horizon=2)
    assert buffer.nbytes - plain.nbytes == 2 * (40 + 1)  # one packed mask per frame slot, and the zero row
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (1, 6, 3, 5), dtype=np.uint8)
    for _ in range(12):
        next_obs = np.concatenate([obs[:, 3:], rng.integers(0, 256, (1, 3, 3, 5), dtype=np.uint8)], axis=1)
        infos = with_masks(obs, next_obs, [{}], frame_shape=(3, 3, 5))
        buffer.add(obs, next_obs, np.zeros((1, ACTION_DIM)), np.zeros(1), np.zeros(1, bool), infos)
        obs = next_obs
    batch = buffer.sample(50)
    assert batch.masks.shape == (50, 2, 3, 5)
    for obs, masks in zip(batch.observations.numpy(), batch.masks.numpy(), strict=True):
        for j in range(2):
            np.testing.assert_array_equal(masks[j], mask_of(obs[3 * j : 3 * j + 3]))


def step(n_envs: int = 2):
    obs = np.zeros((n_envs, 9, 4, 4), np.uint8)
    return obs, obs.copy(), np.zeros((n_envs, ACTION_DIM), np.float32), np.zeros(n_envs, np.float32), np.zeros(n_envs)


def test_missing_or_misshapen_masks_are_refused_and_nothing_is_stored():
    buffer = make_buffer(2, 3, 30, store_masks=True)
    with pytest.raises(ValueError, match=r"infos\[1\]\['agent_masks'\].*make_env\(\.\.\., agent_masks=True\)"):
        buffer.add(*step(), [{MASKS_INFO_KEY: np.zeros((4, 4, 4), bool)}, {}])
    with pytest.raises(ValueError, match=r"infos\[0\]\['agent_masks'\] of shape \(4, 4, 4\).*got shape \(3, 4, 4\)"):
        buffer.add(*step(), [{MASKS_INFO_KEY: np.zeros((3, 4, 4), bool)}] * 2)
    assert buffer.size() == 0 and (buffer._rings.head == -1).all()
    plain = make_buffer(2, 3, 30)  # without store_masks infos are not read, and batches have no masks
    plain.add(*step(), [{}, {}])
    assert plain.sample(4).masks is None
