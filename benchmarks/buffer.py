"""Replay buffer benchmark: bytes per stored transition, sample() / add() speed, and prefetch.

Three parts, each its own flag (``--compare-sb3`` and ``--prefetch`` when no part is named):

- ``--compare-sb3``: SequenceReplayBuffer (frames stored once, n-step transition + EF window per sample) against
  SB3's ReplayBuffer, its optimize_memory_usage variant and its NStepReplayBuffer, all filled with the same stream of
  random 84x84 RGB frames stacked 3 deep.
- ``--baseline PATH``: ``sample()`` of this package's buffer against another SequenceReplayBuffer, same stream, same
  batch size, interleaved in one run. PATH is a module file that defines ``SequenceReplayBuffer`` (a one-file
  ``sb3_ef/common/buffers.py``) or the root of another sb3-ef source tree.
- ``--prefetch``: an update loop (add one step, sample, run the DrQ-v2 encoder forward and backward on part of the
  batch) with and without prefetch; reports the share of the loop spent waiting in ``sample()``.

    python benchmarks/buffer.py --transitions 20000 --compare-sb3
    python benchmarks/buffer.py --transitions 50000 --baseline ../sb3-ef-other --prefetch --update-batch 4
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.drqv2.policies import DrQv2Encoder


class Stream:
    """Random-frame episodes of fixed length, stacked oldest first; one env."""

    def __init__(self, episode_length: int, size: int, frame_stack: int, action_dim: int = 6):
        self.rng = np.random.default_rng(0)
        self.frames = self.rng.integers(0, 256, (episode_length + frame_stack, 3, size, size), dtype=np.uint8)
        self.episode_length, self.frame_stack, self.size = episode_length, frame_stack, size
        self.action = np.zeros((1, action_dim), dtype=np.float32)
        self.step_index = 0

    def stack(self, t: int) -> np.ndarray:
        return self.frames[t : t + self.frame_stack].reshape(1, 3 * self.frame_stack, self.size, self.size)

    def add_to(self, *buffers: ReplayBuffer) -> list[float]:
        """Add the next step to every buffer; return the seconds each spent inside add()."""
        t = self.step_index % self.episode_length
        self.step_index += 1
        done = np.array([t == self.episode_length - 1])
        infos = [{"TimeLimit.truncated": bool(done[0])}]
        reward = np.array([self.rng.normal()], dtype=np.float32)
        obs, next_obs = self.stack(t), self.stack(t + 1)
        seconds = []
        for buffer in buffers:
            start = time.perf_counter()
            buffer.add(obs, next_obs, self.action, reward, done, infos)
            seconds.append(time.perf_counter() - start)
        return seconds


def stored_bytes(buffer: ReplayBuffer) -> int:
    if isinstance(buffer, SequenceReplayBuffer):
        return buffer.nbytes
    arrays = [buffer.observations, buffer.actions, buffer.rewards, buffer.dones, buffer.timeouts]
    if not buffer.optimize_memory_usage:
        arrays.append(buffer.next_observations)
    return sum(array.nbytes for array in arrays)


def time_sampling(buffer: ReplayBuffer, batch_size: int, repeats: int) -> list[float]:
    """Milliseconds of each of ``repeats`` sample() calls (after one untimed call)."""
    buffer.sample(batch_size)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        buffer.sample(batch_size)
        times.append(1000 * (time.perf_counter() - start))
    return times


def compare_sb3(args: argparse.Namespace, obs_space: spaces.Box, action_space: spaces.Box) -> None:
    sequence_kwargs = {"n_steps": args.n_steps, "horizon": args.horizon, "device": "cpu", "storage_device": "cpu"}
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
    print("| buffer | bytes / stored transition | x one frame | add() us | sample() ms | samples / s |")
    print("|---|---|---|---|---|---|")
    for name, make in candidates.items():
        buffer = make()
        stream = Stream(args.episode_length, args.size, args.frame_stack)
        add_seconds = sum(stream.add_to(buffer)[0] for _ in range(args.transitions))
        per_transition = stored_bytes(buffer) / buffer.size()
        sample_ms = statistics.median(time_sampling(buffer, args.batch_size, args.repeats))
        print(
            f"| {name} | {per_transition:,.0f} | {per_transition / frame_bytes:.2f} | "
            f"{1e6 * add_seconds / args.transitions:.0f} | {sample_ms:.1f} | "
            f"{1000 * args.batch_size / sample_ms:,.0f} |",
            flush=True,
        )
        del buffer


def load_baseline(path: Path) -> type:
    """``SequenceReplayBuffer`` from a module file, or from the sb3-ef source tree rooted at ``path``.

    A tree's ``sb3_ef`` is imported under its own name with this package's modules set aside, then set aside in
    turn: the class keeps its module's globals, so both buffers live side by side in this process."""
    if path.is_file():
        spec = importlib.util.spec_from_file_location("baseline_buffers", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module.SequenceReplayBuffer
    if not (path / "sb3_ef" / "common").is_dir():
        raise SystemExit(f"--baseline expects a module file or an sb3-ef source tree, got {path}")

    def ours(name: str) -> bool:
        return name == "sb3_ef" or name.startswith("sb3_ef.")

    current = {name: module for name, module in sys.modules.items() if ours(name)}
    for name in current:
        del sys.modules[name]
    sys.path.insert(0, str(path))
    try:
        return importlib.import_module("sb3_ef.common.buffers").SequenceReplayBuffer
    finally:
        sys.path.remove(str(path))
        for name in [name for name in sys.modules if ours(name)]:
            del sys.modules[name]
        sys.modules.update(current)


def compare_baseline(args: argparse.Namespace, obs_space: spaces.Box, action_space: spaces.Box) -> None:
    """Interleaved sample() timings of the baseline buffer and this package's, filled with the same stream."""
    kwargs = {"n_steps": args.n_steps, "horizon": args.horizon, "device": "cpu", "storage_device": "cpu"}
    baseline_class = load_baseline(args.baseline)
    buffers = {
        "baseline": baseline_class(args.transitions, obs_space, action_space, **kwargs),
        "this package": SequenceReplayBuffer(args.transitions, obs_space, action_space, **kwargs),
    }
    stream = Stream(args.episode_length, args.size, args.frame_stack)
    add_seconds = np.sum([stream.add_to(*buffers.values()) for _ in range(args.transitions)], axis=0)
    times: dict[str, list[float]] = {name: [] for name in buffers}
    for _ in range(args.rounds):
        for name, buffer in buffers.items():
            times[name] += time_sampling(buffer, args.batch_size, args.repeats)
    median = {name: statistics.median(values) for name, values in times.items()}
    print(f"baseline: SequenceReplayBuffer from {args.baseline} ({baseline_class.__module__})")
    print(f"| buffer | sample({args.batch_size}) ms median | quartiles | ratio to the baseline | add() us, mean |")
    print("|---|---|---|---|---|")
    for (name, values), seconds in zip(times.items(), add_seconds, strict=True):
        q = statistics.quantiles(values, n=4)
        ratio = median[name] / median["baseline"]
        add_us = 1e6 * seconds / args.transitions
        print(f"| {name} | {median[name]:.2f} | {q[0]:.2f}-{q[2]:.2f} | {ratio:.3f} | {add_us:.0f} |")


def prefetch_loop(args: argparse.Namespace, obs_space: spaces.Box, action_space: spaces.Box) -> None:
    """Share of an update loop spent waiting for data, with and without prefetch, interleaved."""
    encoder = DrQv2Encoder(obs_space)
    optimizer = th.optim.Adam(encoder.parameters())
    buffers = {
        prefetch: SequenceReplayBuffer(
            args.transitions,
            obs_space,
            action_space,
            device="cpu",
            storage_device="cpu",
            n_steps=args.n_steps,
            horizon=args.horizon,
            prefetch=prefetch,
        )
        for prefetch in (False, True)
    }
    stream = Stream(args.episode_length, args.size, args.frame_stack)
    for _ in range(args.transitions):
        stream.add_to(*buffers.values())

    def update(batch) -> None:
        observations = batch.observations[: args.update_batch].float() / 255 - 0.5
        loss = encoder(observations).square().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    shares: dict[bool, list[float]] = {False: [], True: []}
    update_ms: dict[bool, list[float]] = {False: [], True: []}
    loop_ms: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.rounds):
        for prefetch, buffer in buffers.items():
            waited = total = 0.0
            for _ in range(args.repeats):
                start = time.perf_counter()
                stream.add_to(buffer)
                batch = buffer.sample(args.batch_size)
                waited += time.perf_counter() - start
                update(batch)
                total += time.perf_counter() - start
            shares[prefetch].append(waited / total)
            update_ms[prefetch].append(1000 * (total - waited) / args.repeats)
            loop_ms[prefetch].append(1000 * total / args.repeats)
    print(
        f"| prefetch | waiting for data (add + sample), median share of the loop | update ms (encoder fwd+bwd on "
        f"{args.update_batch} of the {args.batch_size}) | loop ms per iteration |"
    )
    print("|---|---|---|---|")
    for prefetch in (False, True):
        print(
            f"| {'on' if prefetch else 'off'} | {100 * statistics.median(shares[prefetch]):.1f}% | "
            f"{statistics.median(update_ms[prefetch]):.0f} | {statistics.median(loop_ms[prefetch]):.0f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--transitions", type=int, default=20000, help="buffer capacity, filled exactly once")
    parser.add_argument("--episode-length", type=int, default=250, help="agent steps per episode (Meta-World: 250)")
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--frame-stack", type=int, default=3)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--n-steps", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=30, help="timed calls per round")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the baseline and prefetch parts")
    parser.add_argument("--baseline", type=Path, help="a buffer module file or sb3-ef source tree to time against")
    parser.add_argument("--update-batch", type=int, default=32, help="samples the --prefetch loop's update encodes")
    parser.add_argument("--compare-sb3", action="store_true")
    parser.add_argument("--prefetch", action="store_true")
    args = parser.parse_args()
    parts = [name for name in ("compare_sb3", "prefetch") if getattr(args, name)]
    if args.baseline is not None:
        parts.insert(1, "compare_baseline")
    th.set_num_threads(1)

    obs_space = spaces.Box(0, 255, (3 * args.frame_stack, args.size, args.size), np.uint8)
    action_space = spaces.Box(-1, 1, (6,), np.float32)
    print(
        f"{args.transitions} transitions, episodes of {args.episode_length}, {args.size}x{args.size}, "
        f"stack {args.frame_stack}, batch {args.batch_size}, horizon {args.horizon}, n_steps {args.n_steps}; "
        f"1 torch thread; load average before: {os.getloadavg()[0]:.1f}"
    )
    for part in parts or ["compare_sb3", "prefetch"]:
        print()
        {"compare_sb3": compare_sb3, "compare_baseline": compare_baseline, "prefetch": prefetch_loop}[part](
            args, obs_space, action_space
        )
    print(f"\nload average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
