"""Streamed windows: the same draws as in memory when the dataset fits, a bounded pool with fair draws when not."""

from __future__ import annotations

import numpy as np
import torch as th

from sb3_ef.offline.episodes import write_episode
from sb3_ef.offline.readers import FolderDataset
from sb3_ef.offline.streaming import EpisodeList, StreamingWindowSampler, episode_bytes, window_batches
from sb3_ef.offline.windows import WindowSampler
from tests.helpers.offline import square_episode


def data(count=6):
    return [square_episode(steps=10 + 2 * seed, seed=seed) for seed in range(count)]


def test_a_dataset_that_fits_gives_the_windows_of_the_in_memory_sampler():
    episodes = data()
    streamed = StreamingWindowSampler(EpisodeList(episodes), range(6), 2, 3, cache_mb=100, seed=5)
    in_memory = WindowSampler(episodes, 2, 3, seed=5)
    assert not streamed.streaming
    for _ in range(3):
        a, b = streamed.sample(8), in_memory.sample(8)
        assert th.equal(a.observations, b.observations) and th.equal(a.actions, b.actions)


def test_a_larger_dataset_is_streamed_through_a_bounded_pool_with_fair_draws(tmp_path):
    episodes = data()
    for index, episode in enumerate(episodes):
        write_episode(tmp_path / f"episode_{index}.npz", episode)
    dataset = FolderDataset(tmp_path)
    sizes = [episode_bytes(episode) for episode in episodes]
    cache_mb = 2.5 * np.mean(sizes) / 2**20  # the pool is sized by the mean episode: two fit
    sampler = StreamingWindowSampler(dataset, range(6), 2, 3, cache_mb=cache_mb, seed=0)
    assert sampler.streaming and sampler.pool_size == 2
    draws = np.zeros(6)
    for _ in range(1500):
        batch = sampler.sample(4)
        assert sampler.resident_bytes <= 2 * max(sizes) and batch.observations.shape == (4, 6, 32, 32)
        for slot, index in enumerate(sampler.pool):  # the pool holds the episodes it names, decoded from disk
            assert np.array_equal(sampler.sampler.episodes[slot].frames, episodes[index].frames)
            draws[index] += 1
    assert sampler.loaded > 1000  # episodes are swapped in and out, not kept
    counts = sampler.counts / sampler.counts.sum()
    share = draws / draws.sum()
    np.testing.assert_allclose(share, counts, atol=0.05)  # pool time follows each episode's window count


def test_windows_decoded_in_worker_processes_are_real_windows(tmp_path):
    episodes = data(count=3)
    for index, episode in enumerate(episodes):
        write_episode(tmp_path / f"episode_{index}.npz", episode)
    dataset = FolderDataset(tmp_path)
    batches = window_batches(dataset, [0, 1, 2], dataset.lengths(), 2, 3, batch_size=4, cache_mb=100, workers=2)
    frames = [episode.frames for episode in episodes]
    for _ in range(3):
        batch = next(batches)
        for observation, future in zip(batch.observations.numpy(), batch.frames.numpy(), strict=True):
            last = observation[-3:]
            found = [
                (e, t)
                for e, f in enumerate(frames)
                for t in range(len(f) - 3)
                if np.array_equal(f[t], last) and np.array_equal(f[t + 1 : t + 4], future)
            ]
            assert found, "a window that is no slice of any episode"


def test_pretrain_streams_a_folder_through_a_worker_process(tmp_path):
    from sb3_ef.offline.model import load_pretrained
    from tests.helpers.offline import tiny_pretrain

    for index, episode in enumerate(data(count=4)):
        write_episode(tmp_path / "data" / f"episode_{index}.npz", episode)
    # a cache below one episode: the pool holds one episode at a time, decoded in the worker
    tiny_pretrain(tmp_path / "data", tmp_path / "run", context=2, steps=3, cache_mb=0.01, workers=1)
    model, checkpoint = load_pretrained(tmp_path / "run" / "model.pt")
    assert checkpoint["step"] == 3 and model.config.frame_shape == (3, 32, 32)
