"""SequenceReplayBuffer against a brute-force reference fed random multi-env episode streams, for every storage kind.

Every frame's pixels encode (env, episode, step), so a sampled observation names the transition it must be, and
every field of the sample is compared with what the simulated envs emitted.
"""

from __future__ import annotations

import pickle
import tempfile
from dataclasses import dataclass, field

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sb3_ef.common.buffers import SequenceReplayBuffer

FRAME = (3, 4, 4)
ACTION_DIM = 2
GAMMA = 0.9
STEP_OFFSET = 8  # pixel value of step s is s + STEP_OFFSET, so pre-reset frames (s <= 0) stay positive

_CUDA = pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")
# Every way of storing the buffer: the same layout, rules and samples hold for each.
STORAGE_KINDS = {
    "cpu": {"storage_device": "cpu"},
    "memmap": {"storage_device": "cpu", "memmap_dir": tempfile.gettempdir()},
    "cpu-prefetch": {"storage_device": "cpu", "prefetch": True},
    "cuda": {"storage_device": "cuda", "device": "cuda"},
    "host-to-cuda": {"storage_device": "cpu", "device": "cuda"},  # pinned outputs, copies, prefetch on by default
}
STORAGES = [pytest.param(name, marks=[_CUDA] if "cuda" in name else [], id=name) for name in STORAGE_KINDS]


def encode(env: int, episode: int, step: int) -> np.ndarray:
    """A frame whose channels hold env, episode and step (mod 256: the reference checks stay below that)."""
    frame = np.empty(FRAME, dtype=np.uint8)
    frame[0], frame[1], frame[2] = env + 1, (episode + 1) % 256, (step + STEP_OFFSET) % 256
    return frame


def decode(frame: np.ndarray) -> tuple[int, int, int]:
    return int(frame[0, 0, 0]) - 1, int(frame[1, 0, 0]) - 1, int(frame[2, 0, 0]) - STEP_OFFSET


@dataclass
class Step:
    obs: np.ndarray
    action: np.ndarray
    reward: float
    done: bool  # what `dones` must report for this step
    next_obs: np.ndarray


@dataclass
class Episode:
    first_frame: int  # position of its first frame in the env's frame log
    steps: list[Step] = field(default_factory=list)


class Streams:
    """n_envs simulated envs stepping in lockstep, as a VecEnv does, recorded into a brute-force reference.

    Episodes have random lengths and end by termination, time-limit truncation, or a "cut" (the env is reset
    without a done, as a new ``learn()`` call does). Resets pad the stack with repeats, zeros or distinct frames.
    """

    def __init__(self, n_envs: int, frame_stack: int, max_len: int, padding: str, handle_timeout: bool, seed: int):
        self.n_envs, self.frame_stack, self.max_len = n_envs, frame_stack, max_len
        self.padding, self.handle_timeout = padding, handle_timeout
        self.rng = np.random.default_rng(seed)
        self.episodes: list[list[Episode]] = [[] for _ in range(n_envs)]
        self.n_frames = [0] * n_envs  # frames the buffer has written per env
        self.obs = np.stack([self._reset(env) for env in range(n_envs)])

    def _reset(self, env: int) -> np.ndarray:
        episode = len(self.episodes[env])
        self.episodes[env].append(Episode(first_frame=-1))  # its frames are written at its first step
        self.length = getattr(self, "length", {})
        self.length[env] = (int(self.rng.integers(1, self.max_len + 1)), str(self.rng.choice(["term", "trunc", "cut"])))
        first = encode(env, episode, 0)
        if self.padding == "repeat":
            pads = [first] * (self.frame_stack - 1)
        elif self.padding == "zeros":
            pads = [np.zeros_like(first)] * (self.frame_stack - 1)
        else:
            pads = [encode(env, episode, s) for s in range(1 - self.frame_stack, 0)]
        return np.concatenate([*pads, first])

    def step(self, *buffers: SequenceReplayBuffer) -> None:
        next_obs = np.empty_like(self.obs)
        actions = self.rng.uniform(-1, 1, (self.n_envs, ACTION_DIM)).astype(np.float32)
        rewards = self.rng.normal(size=self.n_envs).astype(np.float32)
        dones = np.zeros(self.n_envs, dtype=bool)
        infos: list[dict] = [{} for _ in range(self.n_envs)]
        resets = []
        for env in range(self.n_envs):
            episode = self.episodes[env][-1]
            t = len(episode.steps)
            if t == 0:
                episode.first_frame = self.n_frames[env]
                self.n_frames[env] += self.frame_stack
            next_obs[env] = np.concatenate([self.obs[env, 3:], encode(env, len(self.episodes[env]) - 1, t + 1)])
            length, end = self.length[env]
            last = t + 1 == length
            dones[env] = last and end != "cut"
            if last and end == "trunc":
                infos[env]["TimeLimit.truncated"] = True
            true_done = dones[env] and not (end == "trunc" and self.handle_timeout)
            episode.steps.append(
                Step(self.obs[env].copy(), actions[env], float(rewards[env]), true_done, next_obs[env].copy())
            )
            self.n_frames[env] += 1
            if last:
                resets.append(env)
        for buffer in buffers:
            buffer.add(self.obs, next_obs, actions, rewards, dones, infos)
        self.obs = next_obs.copy()
        for env in resets:
            self.obs[env] = self._reset(env)

    def stored(self, capacity: int) -> dict[tuple[int, int, int], tuple[Episode, int]]:
        """Transitions whose whole stacked observation is among the last ``capacity`` frames of their env."""
        result = {}
        for env, episodes in enumerate(self.episodes):
            oldest = self.n_frames[env] - capacity
            for index, episode in enumerate(episodes):
                for t in range(len(episode.steps)):
                    if episode.first_frame + t >= oldest:
                        result[(env, index, t)] = (episode, t)
        return result


def expected_sample(episode: Episode, t: int, n_steps: int, horizon: int) -> dict[str, np.ndarray]:
    """Every field of a sample, summed and windowed directly from the recorded episode."""
    steps = episode.steps
    m = min(n_steps, len(steps) - t)
    future = [steps[t + i] if t + i < len(steps) else None for i in range(horizon)]
    return {
        "observations": steps[t].obs,
        "actions": steps[t].action,
        "next_observations": steps[t + m - 1].next_obs,
        "dones": np.array([float(steps[t + m - 1].done)]),
        "rewards": np.array([sum(GAMMA**j * steps[t + j].reward for j in range(m))]),
        "discounts": np.array([GAMMA**m]),
        "future_actions": np.stack([s.action if s else np.zeros(ACTION_DIM) for s in future]),
        "future_frames": np.stack([s.next_obs[-3:] if s else np.zeros(FRAME) for s in future]),
        "future_rewards": np.array([s.reward if s else 0.0 for s in future]),
        "future_mask": np.array([s is not None for s in future]),
    }


def make_buffer(n_envs: int, frame_stack: int, capacity: int, storage: str = "cpu", **kwargs) -> SequenceReplayBuffer:
    obs_space = spaces.Box(0, 255, (3 * frame_stack, *FRAME[1:]), np.uint8)
    action_space = spaces.Box(-1, 1, (ACTION_DIM,), np.float32)
    kwargs = {"device": "cpu", **STORAGE_KINDS[storage], **kwargs}
    return SequenceReplayBuffer(capacity * n_envs, obs_space, action_space, n_envs=n_envs, **kwargs)


def check_against_reference(buffer: SequenceReplayBuffer, streams: Streams) -> None:
    stored = streams.stored(buffer.buffer_size)
    assert buffer.size() == len(stored)
    buffer.sample(1)  # with prefetch, a pending batch of another size is dropped: the next one is drawn now
    batch = buffer.sample(20 * len(stored) + 100)
    newest = batch.observations[:, -3:].cpu().numpy()
    seen = set()
    for i in range(len(newest)):
        key = decode(newest[i])
        assert key in stored, f"sampled {key}, which is not (or no longer) stored"
        if key in seen:
            continue
        seen.add(key)
        for name, value in expected_sample(*stored[key], buffer.n_steps, buffer.horizon).items():
            got = getattr(batch, name)[i].cpu().numpy()
            assert got.shape == value.shape, name
            np.testing.assert_allclose(got, value, rtol=1e-5, atol=1e-5, err_msg=f"{name} of {key}")
    assert seen == set(stored), "some stored transitions were never drawn"


@pytest.mark.parametrize("storage", STORAGES)
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n_envs=st.integers(1, 3),
    frame_stack=st.integers(1, 3),
    extra_capacity=st.integers(1, 30),
    n_steps=st.integers(1, 4),
    horizon=st.integers(1, 6),
    n_adds=st.integers(1, 50),
    max_len=st.integers(1, 12),
    padding=st.sampled_from(["repeat", "zeros", "distinct"]),
    handle_timeout=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_matches_reference(
    storage, n_envs, frame_stack, extra_capacity, n_steps, horizon, n_adds, max_len, padding, handle_timeout, seed
):
    capacity = horizon + frame_stack + extra_capacity
    buffer = make_buffer(
        n_envs,
        frame_stack,
        capacity,
        n_steps=n_steps,
        gamma=GAMMA,
        horizon=horizon,
        handle_timeout_termination=handle_timeout,
        storage=storage,
    )
    streams = Streams(n_envs, frame_stack, max_len, padding, handle_timeout, seed)
    for _ in range(n_adds):
        streams.step(buffer)
    check_against_reference(buffer, streams)


@pytest.mark.parametrize("storage", STORAGES)
def test_wraparound_never_leaks_overwritten_frames(storage):
    """Long run in a tiny ring: samples stay exact while episodes are overwritten many times over."""
    buffer = make_buffer(2, 3, 12, n_steps=3, gamma=GAMMA, horizon=4, storage=storage)
    streams = Streams(2, 3, 7, "distinct", True, seed=1)
    for _ in range(10):
        for _ in range(13):
            streams.step(buffer)
        check_against_reference(buffer, streams)


@pytest.mark.parametrize("use_memmap", [False, True])
def test_pickle_round_trip(tmp_path, use_memmap):
    memmap_dir = tmp_path / "frames" if use_memmap else None
    buffer = make_buffer(2, 3, 20, n_steps=2, gamma=GAMMA, horizon=3, memmap_dir=memmap_dir)
    streams = Streams(2, 3, 6, "distinct", True, seed=3)
    for _ in range(30):
        streams.step(buffer)
    loaded = pickle.loads(pickle.dumps(buffer, protocol=pickle.HIGHEST_PROTOCOL))
    assert isinstance(loaded._storage.frame_map, np.memmap) == use_memmap
    if use_memmap:
        assert memmap_dir.is_dir() and not any(memmap_dir.iterdir())  # unnamed files: nothing left behind
    assert_same_samples(buffer, loaded)
    for _ in range(25):  # both keep working identically, wrapping around, after the round trip
        streams.step(buffer, loaded)
    assert_same_samples(buffer, loaded)
    check_against_reference(loaded, streams)


@pytest.mark.parametrize("prefetch", [False, True])
def test_a_side_sampler_draws_its_own_batches_and_leaves_the_buffers_stream(prefetch):
    buffer = make_buffer(2, 3, 20, n_steps=2, gamma=GAMMA, horizon=3, prefetch=prefetch)
    streams = Streams(2, 3, 6, "distinct", True, seed=3)
    for _ in range(30):
        streams.step(buffer)
    buffer.sample(8)  # with prefetch, the next batch is now pending
    twin = pickle.loads(pickle.dumps(buffer, protocol=pickle.HIGHEST_PROTOCOL))
    side = buffer.side_sampler(seed=1)
    first, again = side.sample(64, buffer.device, None), buffer.side_sampler(seed=1).sample(64, buffer.device, None)
    np.testing.assert_array_equal(first.observations.numpy(), again.observations.numpy())  # seeded
    for _ in range(3):
        side.sample(16, buffer.device, None)
    assert_same_samples(twin, buffer)  # the buffer's own stream draws what it would have drawn


def assert_same_samples(first: SequenceReplayBuffer, second: SequenceReplayBuffer) -> None:
    """Both buffers draw from generators in the same state (a pickle carries the generator's state)."""
    expected = first.sample(64)
    got = second.sample(64)
    for name in expected._fields:
        if getattr(expected, name) is None:  # masks, when not stored
            assert getattr(got, name) is None, name
            continue
        np.testing.assert_array_equal(
            getattr(got, name).cpu().numpy(), getattr(expected, name).cpu().numpy(), err_msg=name
        )


def box(shape, dtype=np.uint8):
    return spaces.Box(0, 255, shape, dtype)


ACTIONS = spaces.Box(-1, 1, (ACTION_DIM,), np.float32)


@pytest.mark.parametrize(
    ("observation_space", "kwargs", "message"),
    [
        (box((6, 4, 4), np.float32), {}, "uint8 Box"),
        (box((6, 4)), {}, "uint8 Box"),
        (box((4, 4, 4)), {}, "got 4 channels"),
        (spaces.Discrete(3), {}, "got Discrete"),
        (box((6, 4, 4)), {"n_steps": 0}, "n_steps >= 1, got 0"),
        (box((6, 4, 4)), {"horizon": 0}, "horizon >= 1, got 0"),
        (box((6, 4, 4)), {"horizon": 40}, "got 40 // 1 = 40"),
        (box((6, 4, 4)), {"optimize_memory_usage": True}, "optimize_memory_usage=False"),
        (box((6, 4, 4)), {"gamma": 1.5}, "got 1.5"),
    ],
)
def test_bad_construction_is_refused(observation_space, kwargs, message):
    with pytest.raises(ValueError, match=message):
        SequenceReplayBuffer(40, observation_space, ACTIONS, **kwargs)


def test_bad_action_space_is_refused():
    with pytest.raises(ValueError, match="Box action space, got Discrete"):
        SequenceReplayBuffer(40, box((6, 4, 4)), spaces.Discrete(3))


def test_sampling_empty_buffer_is_refused():
    with pytest.raises(ValueError, match="at least one transition, got none"):
        make_buffer(1, 2, 20).sample(4)


def test_bad_add_is_refused():
    buffer = make_buffer(2, 2, 20)
    obs = np.zeros((2, 6, 4, 4), np.uint8)
    action, reward, done, infos = np.zeros((2, ACTION_DIM)), np.zeros(2), np.zeros(2, bool), [{}, {}]
    with pytest.raises(ValueError, match=r"obs of shape \(2, 6, 4, 4\), got \(1, 6, 4, 4\)"):
        buffer.add(obs[:1], obs, action, reward, done, infos)
    not_sliding = obs.copy()
    not_sliding[1, :3] = 1
    with pytest.raises(ValueError, match="slide by one frame"):
        buffer.add(obs, not_sliding, action, reward, done, infos)


def test_storage_is_about_one_frame_per_transition():
    """84x84 RGB, stack 3, 100-step episodes: each transition costs one frame plus a little metadata."""
    buffer = SequenceReplayBuffer(2000, box((9, 84, 84)), ACTIONS, device="cpu", n_steps=3)
    frame_bytes = 3 * 84 * 84
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (1, 9, 84, 84), dtype=np.uint8)
    for t in range(2500):
        next_obs = np.concatenate([obs[:, 3:], rng.integers(0, 256, (1, 3, 84, 84), dtype=np.uint8)], axis=1)
        done = np.array([t % 100 == 99])
        buffer.add(obs, next_obs, np.zeros((1, ACTION_DIM)), np.zeros(1), done, [{}])
        obs = rng.integers(0, 256, (1, 9, 84, 84), dtype=np.uint8) if done[0] else next_obs
    per_transition = buffer.nbytes / buffer.size()
    assert frame_bytes < per_transition <= 1.1 * frame_bytes
    assert buffer.nbytes < 2000 * frame_bytes * 1.01


def test_samples_follow_the_contract():
    buffer = make_buffer(2, 3, 30, n_steps=3, horizon=5)
    streams = Streams(2, 3, 9, "repeat", True, seed=0)
    for _ in range(20):
        streams.step(buffer)
    batch = buffer.sample(7)
    expected = {
        "observations": ((7, 9, 4, 4), th.uint8),
        "actions": ((7, ACTION_DIM), th.float32),
        "next_observations": ((7, 9, 4, 4), th.uint8),
        "dones": ((7, 1), th.float32),
        "rewards": ((7, 1), th.float32),
        "discounts": ((7, 1), th.float32),
        "future_actions": ((7, 5, ACTION_DIM), th.float32),
        "future_frames": ((7, 5, *FRAME), th.uint8),
        "future_rewards": ((7, 5), th.float32),
        "future_mask": ((7, 5), th.bool),
    }
    assert set(batch._fields) == {*expected, "masks"} and batch.masks is None  # masks only when stored
    for name, (shape, dtype) in expected.items():
        tensor = getattr(batch, name)
        assert (tuple(tensor.shape), tensor.dtype, tensor.device) == (shape, dtype, th.device("cpu")), name


def test_transitions_are_drawn_uniformly_across_envs():
    """Env 0 runs one-step episodes (3 frames of context each), env 1 long ones: each transition is equally likely."""
    buffer = make_buffer(2, 3, 400, horizon=2)
    streams = Streams(2, 3, 1, "distinct", True, seed=0)
    for _ in range(300):
        streams.length[1] = (1000, "term")  # env 1 never ends its episode
        streams.step(buffer)
    share = buffer._rings.has_step[0].sum() / buffer.size()  # env 0 holds 100 of the 400 transitions
    buffer.seed(0)
    drawn = buffer.sample(20000).observations[:, -3, 0, 0].numpy() == 1  # env index 0 is encoded as 1
    assert abs(drawn.mean() - share) < 4 * np.sqrt(share * (1 - share) / 20000)
    assert 0.2 < share < 0.3


class RewardScaler:
    """Stands in for a VecNormalize: SB3 buffers call ``normalize_reward`` on sampled rewards."""

    def __init__(self, norm_obs: bool):
        self.norm_obs = norm_obs

    def normalize_reward(self, reward: np.ndarray) -> np.ndarray:
        return 2 * reward


def test_sample_normalises_rewards_and_refuses_normalised_images():
    buffer = make_buffer(1, 2, 30, n_steps=3, gamma=GAMMA, horizon=4)
    streams = Streams(1, 2, 8, "repeat", True, seed=2)
    for _ in range(25):
        streams.step(buffer)
    buffer.seed(0)
    plain = buffer.sample(32)
    buffer.seed(0)
    scaled = buffer.sample(32, env=RewardScaler(norm_obs=False))
    assert th.allclose(scaled.rewards, 2 * plain.rewards) and th.allclose(
        scaled.future_rewards, 2 * plain.future_rewards
    )
    assert th.equal(scaled.observations, plain.observations)
    with pytest.raises(ValueError, match="norm_obs=False"):
        buffer.sample(4, env=RewardScaler(norm_obs=True))
