"""SequenceReplayBuffer's storage devices, generator, reused outputs, prefetch, and the checks made before storing.

Streams of encoded frames come from test_buffers.py; CUDA kinds run where a GPU is present.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from test_buffers import ACTION_DIM, GAMMA, STORAGES, Streams, check_against_reference, make_buffer

from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples, available_host_memory


def as_numpy(batch: SequenceReplayBufferSamples) -> dict[str, np.ndarray]:
    return {name: value.cpu().numpy().copy() for name, value in batch._asdict().items() if value is not None}


def assert_batches_equal(got: dict[str, np.ndarray], expected: dict[str, np.ndarray]) -> None:
    for name, value in expected.items():
        np.testing.assert_allclose(got[name], value, rtol=1e-6, atol=1e-6, err_msg=name)


def filled(storage: str, seed: int = 0, adds: int = 40, **kwargs) -> tuple[SequenceReplayBuffer, Streams]:
    buffer = make_buffer(2, 3, 30, storage=storage, n_steps=3, gamma=GAMMA, horizon=5, **kwargs)
    streams = Streams(2, 3, 9, "distinct", True, seed=seed)
    for _ in range(adds):
        streams.step(buffer)
    return buffer, streams


def test_identical_samples_for_the_same_seed_across_storage_kinds():
    """Indices come from the buffer's generator on the host, so every storage kind draws the same batches."""
    kinds = [param.values[0] for param in STORAGES if "cuda" not in param.values[0] or th.cuda.is_available()]
    runs = {}
    for kind in kinds:
        buffer, _ = filled(kind)
        buffer.seed(7)
        runs[kind] = [as_numpy(buffer.sample(48)) for _ in range(3)]
    for batches in runs.values():
        for got, expected in zip(batches, runs["cpu"], strict=True):
            assert_batches_equal(got, expected)
    assert not np.array_equal(runs["cpu"][0]["observations"], runs["cpu"][1]["observations"])


@pytest.mark.parametrize("storage", STORAGES)
def test_two_seeded_runs_with_prefetch_give_the_same_batches(storage):
    """Adds and samples interleaved as in training; the second run also draws from NumPy's global generator (as
    env code does) and gets the same batches: the buffer's stream is its own."""
    runs = []
    for draw_global in (False, True):
        th.manual_seed(3)  # what SB3's set_random_seed does before the buffer is built
        buffer = make_buffer(2, 3, 30, storage=storage, n_steps=3, gamma=GAMMA, horizon=5, prefetch=True)
        streams = Streams(2, 3, 9, "distinct", True, seed=0)
        batches = []
        for step in range(60):
            streams.step(buffer)
            if draw_global:
                np.random.random(5)
            if step >= 10:
                batches.append(as_numpy(buffer.sample(16)))
        runs.append(batches)
    for got, expected in zip(*runs, strict=True):
        assert_batches_equal(got, expected)


def test_a_different_torch_seed_gives_other_batches():
    batches = []
    for seed in (3, 4):
        th.manual_seed(seed)
        buffer, _ = filled("cpu")
        batches.append(buffer.sample(32).observations.clone())
    assert not th.equal(*batches)


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("prefetch", [False, True])
def test_a_batch_stays_valid_until_the_second_next_sample(storage, prefetch):
    buffer, _ = filled(storage, prefetch=prefetch)
    first = buffer.sample(32)
    kept = as_numpy(first)
    buffer.sample(32)
    assert_batches_equal(as_numpy(first), kept)


def test_a_prefetched_batch_was_drawn_at_the_previous_hand_out():
    """The documented staleness: a prefetched batch misses the steps added after the previous sample() returned."""
    buffer = make_buffer(1, 3, 30, n_steps=1, horizon=1, prefetch=True)
    streams = Streams(1, 3, 1000, "distinct", True, seed=0)
    streams.step(buffer)
    assert (buffer.sample(64).observations[:, -1, 0, 0] == 8).all()  # only step 0 (pixel 0 + 8) is stored
    streams.step(buffer)
    stale = buffer.sample(64).observations[:, -1, 0, 0]
    fresh = buffer.sample(64).observations[:, -1, 0, 0]
    assert (stale == 8).all() and (fresh == 9).any()


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("prefetch", [False, True])
def test_save_and_load_continue_the_stream(storage, prefetch):
    """A pickled buffer (a prefetched batch included) draws what the original draws, and keeps adding exactly."""
    buffer, streams = filled(storage, prefetch=prefetch)
    buffer.sample(24)
    loaded = pickle.loads(pickle.dumps(buffer, protocol=pickle.HIGHEST_PROTOCOL))
    for _ in range(3):
        assert_batches_equal(as_numpy(loaded.sample(24)), as_numpy(buffer.sample(24)))
    for _ in range(25):
        streams.step(buffer, loaded)
    assert_batches_equal(as_numpy(loaded.sample(24)), as_numpy(buffer.sample(24)))
    check_against_reference(loaded, streams)


def test_a_pickle_naming_cuda_storage_loads_without_cuda():
    """What a GPU-trained buffer pickles (device and storage both CUDA) loads on this machine into host memory."""
    if th.cuda.is_available():
        pytest.skip("checks the load on a machine without CUDA; tests/common/test_buffers_storage.py covers GPUs")
    buffer, streams = filled("cpu")
    buffer.storage_request = th.device("cuda")
    buffer._device = th.device("cuda")
    with pytest.warns(UserWarning, match="needs CUDA: frames stay in host memory"):
        loaded = pickle.loads(pickle.dumps(buffer))
    assert loaded.storage_device == th.device("cpu") and loaded.device == th.device("cpu")
    check_against_reference(loaded, streams)


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")
def test_gpu_storage_pickle_loads_in_a_process_without_cuda(tmp_path):
    buffer, _ = filled("cuda")
    buffer.seed(5)
    expected = as_numpy(buffer.sample(16))
    buffer.seed(5)
    path = tmp_path / "buffer.pkl"
    path.write_bytes(pickle.dumps(buffer))
    np.save(tmp_path / "expected.npy", expected["observations"])
    script = (
        "import pickle, sys, numpy as np, torch as th\n"
        f"buffer = pickle.loads(open({str(path)!r}, 'rb').read())\n"
        "assert not th.cuda.is_available() and buffer.storage_device.type == 'cpu'\n"
        f"assert np.array_equal(buffer.sample(16).observations.numpy(), np.load({str(tmp_path / 'expected.npy')!r}))\n"
    )
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": ""}
    subprocess.run([sys.executable, "-W", "ignore", "-c", script], check=True, env=env)


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")
def test_auto_storage_follows_the_training_device_after_load():
    """SB3 sets ``device`` after load_replay_buffer: an "auto" buffer saved on a CPU moves to the GPU."""
    buffer, streams = filled("cpu", storage_device="auto")
    loaded = pickle.loads(pickle.dumps(buffer))
    loaded.device = "cuda"
    assert loaded.storage_device.type == "cuda" and loaded.sample(8).observations.device.type == "cuda"
    check_against_reference(loaded, streams)


def test_auto_storage_on_a_cpu_is_host_memory():
    buffer = make_buffer(1, 3, 30, storage_device="auto")
    assert buffer.storage_device == th.device("cpu")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"storage_device": "tpu-ish"}, "storage_device 'auto', 'cpu', 'cuda' or a torch.device, got 'tpu-ish'"),
        pytest.param(
            {"storage_device": "cuda"},
            "needs CUDA, which is not available",
            marks=pytest.mark.skipif(th.cuda.is_available(), reason="CUDA is available here"),
        ),
        pytest.param(
            {"storage_device": "cuda", "memmap_dir": tempfile.gettempdir()},
            "memmap_dir expects storage_device 'cpu' or 'auto', got 'cuda'",
            marks=pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device"),
        ),
    ],
)
def test_bad_storage_is_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_buffer(1, 3, 30, **kwargs)


def step_arrays(buffer: SequenceReplayBuffer, obs_dtype=np.uint8):
    obs = np.zeros((2, 9, 4, 4), obs_dtype)
    return obs, obs.copy(), np.zeros((2, ACTION_DIM), np.float32), np.ones(2, np.float32), np.zeros(2, bool)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("reward", np.nan, "finite rewards, got nan for env 1 at step 2"),
        ("reward", np.inf, "finite rewards, got inf for env 1 at step 2"),
        ("action", -np.inf, r"finite actions, got \[\s*0\. -inf\] for env 1 at step 2"),
        ("obs", np.nan, "finite obs, got nan for env 1 at step 2"),
    ],
)
def test_non_finite_steps_are_refused_and_nothing_is_stored(field, value, message):
    buffer = make_buffer(2, 3, 30)
    for _ in range(2):
        buffer.add(*step_arrays(buffer), [{}, {}])
    buffer.seed(0)
    before = as_numpy(buffer.sample(8))
    obs, next_obs, action, reward, done = step_arrays(buffer, np.float32 if field == "obs" else np.uint8)
    {"reward": reward, "action": action[:, 1:], "obs": obs[:, :1, 0, 0]}[field][1] = value
    with pytest.raises(ValueError, match=message):
        buffer.add(obs, next_obs, action, reward, done, [{}, {}])
    assert buffer.size() == 4
    buffer.seed(0)
    assert_batches_equal(as_numpy(buffer.sample(8)), before)


def test_a_refused_stack_stores_nothing_for_any_env():
    buffer = make_buffer(2, 3, 30)
    obs, next_obs, action, reward, done = step_arrays(buffer)
    next_obs[1, 0] = 1  # env 1's stack does not slide; env 0's step is fine but must not be stored either
    with pytest.raises(ValueError, match="slide by one frame"):
        buffer.add(obs, next_obs, action, reward, done, [{}, {}])
    assert buffer.size() == 0 and (buffer._rings.head == -1).all()


BIG = spaces.Box(0, 255, (9, 84, 84), np.uint8)
ACTIONS = spaces.Box(-1, 1, (ACTION_DIM,), np.float32)


def first_step() -> tuple:
    """One add() of a single env with BIG frames."""
    obs = np.zeros((1, *BIG.shape), np.uint8)
    return obs, obs.copy(), np.zeros((1, ACTION_DIM), np.float32), np.zeros(1, np.float32), np.zeros(1, bool), [{}]


def test_a_buffer_larger_than_the_ram_is_refused_at_the_first_add_before_storing():
    """10M frames at 84x84 (212 GB): construction reserves nothing; the first add() names the size, what is
    available and the ways out, and stores nothing."""
    buffer = SequenceReplayBuffer(10_000_000, BIG, ACTIONS, device="cpu")
    with pytest.raises(MemoryError, match=r"needs 211\.\d\d GB .* but only \d+\.\d\d GB of RAM") as error:
        buffer.add(*first_step())
    assert "a smaller buffer_size" in str(error.value) and "memmap_dir=<a folder on a disk with 211.7" in str(
        error.value
    )
    assert buffer.size() == 0 and (buffer._rings.head == -1).all()
    with pytest.raises(MemoryError):  # refused again, not half-allocated
        buffer.add(*first_step())


def test_a_memmap_larger_than_the_disk_is_refused_at_the_first_add(tmp_path):
    buffer = SequenceReplayBuffer(10**9, BIG, ACTIONS, device="cpu", memmap_dir=tmp_path)
    with pytest.raises(MemoryError, match=f"GB of disk space in memmap_dir={tmp_path} are available"):
        buffer.add(*first_step())
    assert buffer.size() == 0


def resident_bytes() -> int:
    """This process's resident memory (``VmRSS`` in /proc/self/status)."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmRSS:"))


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads resident memory from Linux's /proc")
def test_host_storage_commits_ram_only_as_frames_are_written():
    """A 2.1 GB host buffer (100k frames at 3x84x84) adds far less than its size to RSS when built and at its first
    add(), which allocates it: the OS commits pages as frames are written."""
    before = resident_bytes()
    buffer = SequenceReplayBuffer(100_000, BIG, ACTIONS, device="cpu", storage_device="cpu")
    after_construction = resident_bytes()
    if (available_host_memory() or 0) < 2 * buffer.nbytes:
        pytest.skip("the first add() needs the buffer's size in available RAM, with room to spare")
    buffer.add(*first_step())
    after_first_add = resident_bytes()
    assert buffer.size() == 1 and buffer.sample(2).observations.shape == (2, *BIG.shape)
    assert after_construction - before < 0.02 * buffer.nbytes
    assert after_first_add - before < 0.02 * buffer.nbytes


def test_an_empty_buffer_pickles_without_storage():
    buffer = SequenceReplayBuffer(100_000, BIG, ACTIONS, device="cpu", storage_device="cpu")
    data = pickle.dumps(buffer)
    # Spaces and bookkeeping take 0.42 MB; the step arrays would add 1.3 MB, the frames 2.1 GB.
    assert len(data) < 1_000_000
    loaded = pickle.loads(data)
    with pytest.raises(ValueError, match="at least one transition, got none"):
        loaded.sample(4)
    loaded.device = "cpu"
    loaded.reset()
    assert loaded.nbytes == buffer.nbytes and loaded.storage_device == th.device("cpu")


@pytest.mark.parametrize("storage", STORAGES)
def test_an_empty_buffer_is_allocated_at_its_first_add_after_any_round_trip(storage):
    """Every path that meets the storage before the first add(): sample, reset, device, nbytes, pickling."""
    buffer = make_buffer(2, 3, 30, storage=storage, n_steps=3, gamma=GAMMA, horizon=5)
    with pytest.raises(ValueError, match="at least one transition, got none"):
        buffer.sample(4)
    buffer.reset()
    buffer.device = buffer.device
    loaded = pickle.loads(pickle.dumps(buffer))
    assert loaded.nbytes == buffer.nbytes and loaded.storage_device == buffer.storage_device
    streams = Streams(2, 3, 9, "distinct", True, seed=0)
    for _ in range(40):
        streams.step(loaded)
    check_against_reference(loaded, streams)
    assert loaded._storage.device == buffer.storage_device


def test_a_pickle_in_an_unknown_format_is_refused_clearly():
    """A pickle with its frames as a list of arrays under ``_frames`` and no generator (a format not read)."""
    buffer, _ = filled("cpu")
    state = buffer.__getstate__()
    state["_frames"] = state.pop("_stored")["frames"]
    del state["_pending_draw"], state["_rng"]
    with pytest.raises(ValueError, match="frames are stored under '_stored', got one without"):
        SequenceReplayBuffer.__new__(SequenceReplayBuffer).__setstate__(state)
