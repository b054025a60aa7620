"""Replay buffer benchmark: bytes per stored transition and sample() / add() speed.

Compares SequenceReplayBuffer (frames stored once, n-step transition + EF window per sample) with SB3's
ReplayBuffer, its optimize_memory_usage variant and its NStepReplayBuffer, all filled with the same stream of
random 84x84 RGB frames stacked 3 deep.

    python benchmarks/buffer.py --transitions 20000
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer

from sb3_ef.common.buffers import SequenceReplayBuffer


def fill(buffer: ReplayBuffer, transitions: int, episode_length: int, size: int, frame_stack: int) -> float:
    """Add a stream of random-frame episodes; return the seconds spent inside add()."""
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (episode_length + frame_stack, 3, size, size), dtype=np.uint8)  # reused pixels

    def stack(t: int) -> np.ndarray:
        return frames[t : t + frame_stack].reshape(1, 3 * frame_stack, size, size)

    action = np.zeros((1, 6), dtype=np.float32)
    seconds = 0.0
    for step in range(transitions):
        t = step % episode_length
        done = np.array([t == episode_length - 1])
        infos = [{"TimeLimit.truncated": bool(done[0])}]
        reward = np.array([rng.normal()], dtype=np.float32)
        obs, next_obs = stack(t), stack(t + 1)
        start = time.perf_counter()
        buffer.add(obs, next_obs, action, reward, done, infos)
        seconds += time.perf_counter() - start
    return seconds


def stored_bytes(buffer: ReplayBuffer) -> int:
    if isinstance(buffer, SequenceReplayBuffer):
        return buffer.nbytes
    arrays = [buffer.observations, buffer.actions, buffer.rewards, buffer.dones, buffer.timeouts]
    if not buffer.optimize_memory_usage:
        arrays.append(buffer.next_observations)
    return sum(array.nbytes for array in arrays)


def time_sampling(buffer: ReplayBuffer, batch_size: int, repeats: int) -> float:
    """Median milliseconds per sample() call."""
    buffer.sample(batch_size)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        buffer.sample(batch_size)
        times.append(time.perf_counter() - start)
    return 1000 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--transitions", type=int, default=20000, help="buffer capacity, filled exactly once")
    parser.add_argument("--episode-length", type=int, default=250, help="agent steps per episode (Meta-World: 250)")
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--frame-stack", type=int, default=3)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--n-steps", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    th.set_num_threads(1)

    obs_space = spaces.Box(0, 255, (3 * args.frame_stack, args.size, args.size), np.uint8)
    action_space = spaces.Box(-1, 1, (6,), np.float32)
    sequence_kwargs = {"n_steps": args.n_steps, "horizon": args.horizon, "device": "cpu"}
    memmap_dir = tempfile.TemporaryDirectory()
    candidates: dict[str, Callable[[], ReplayBuffer]] = {
        "SequenceReplayBuffer": lambda: SequenceReplayBuffer(
            args.transitions, obs_space, action_space, **sequence_kwargs
        ),
        "SequenceReplayBuffer (memmap)": lambda: SequenceReplayBuffer(
            args.transitions, obs_space, action_space, memmap_dir=memmap_dir.name, **sequence_kwargs
        ),
        "SB3 ReplayBuffer": lambda: ReplayBuffer(args.transitions, obs_space, action_space, device="cpu"),
        "SB3 ReplayBuffer (optimize_memory_usage)": lambda: ReplayBuffer(
            args.transitions,
            obs_space,
            action_space,
            device="cpu",
            optimize_memory_usage=True,
            handle_timeout_termination=False,
        ),
        "SB3 NStepReplayBuffer": lambda: NStepReplayBuffer(
            args.transitions, obs_space, action_space, device="cpu", n_steps=args.n_steps
        ),
    }
    frame_bytes = 3 * args.size * args.size
    print(
        f"{args.transitions} transitions, episodes of {args.episode_length}, {args.size}x{args.size}, "
        f"stack {args.frame_stack}, batch {args.batch_size}, horizon {args.horizon}, n_steps {args.n_steps}"
    )
    print("| buffer | bytes / stored transition | x one frame | add() us | sample() ms | samples / s |")
    print("|---|---|---|---|---|---|")
    for name, make in candidates.items():
        buffer = make()
        add_seconds = fill(buffer, args.transitions, args.episode_length, args.size, args.frame_stack)
        stored = buffer.size()
        per_transition = stored_bytes(buffer) / stored
        sample_ms = time_sampling(buffer, args.batch_size, args.repeats)
        print(
            f"| {name} | {per_transition:,.0f} | {per_transition / frame_bytes:.2f} | "
            f"{1e6 * add_seconds / args.transitions:.0f} | {sample_ms:.1f} | "
            f"{1000 * args.batch_size / sample_ms:,.0f} |"
        )
        del buffer


if __name__ == "__main__":
    main()
