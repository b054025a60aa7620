"""Training throughput of the Ego-Foresight algorithms against their plain versions, in the same run.

For each pair (plain, EF) and each setting it measures, after a warm-up that fills the buffer:
- env steps/s of the whole training loop (acting, env step with rendering, buffer, updates at the algorithm's
  ``train_freq``), as the paper's throughput table does;
- updates/s of ``train()`` alone (one gradient step at the setting's batch size).
Plain and EF runs are interleaved ``--repeats`` times and the medians are reported, with wall-clock rates and rates
per CPU-second of this process (the latter are less sensitive to other processes on a shared machine).

Usage (headless rendering needs EGL)::

    MUJOCO_GL=egl python benchmarks/throughput.py --setting all --threads 1

To add a pair, append ``(name, plain class, EF class, algorithm kwargs)`` to ``PAIRS``; both classes must accept
``policy, env, batch_size, buffer_size, learning_starts, seed`` and the EF class ``babbling_steps``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch as th

from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs import make_env
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

ENV_NAME = "dmc/cartpole-swingup"

# (name, plain class, EF class, algorithm kwargs shared by both).
PAIRS: list[tuple[str, type, type, dict[str, Any]]] = [
    ("DrQ-v2", DrQv2, DrQv2EF, {}),
    ("TD-MPC2", TDMPC2, TDMPC2EF, {"seed_burst": False}),  # the warm-up's burst of updates is not measured
]
# Pairs whose encoder takes another frame size than the setting's (TD-MPC2's conv stack is built for 64x64).
FRAME_SIZES = {"TD-MPC2": 64}


@dataclass(frozen=True)
class Setting:
    """Image size, batch size and how much to run."""

    size: int
    batch_size: int
    warmup_steps: int
    loop_steps: int
    updates: int


SETTINGS = {
    "paper": Setting(size=84, batch_size=256, warmup_steps=300, loop_steps=20, updates=4),
    "cpu-small": Setting(size=84, batch_size=32, warmup_steps=300, loop_steps=60, updates=20),
}


@dataclass
class Rates:
    """Median rates over the repeats: wall-clock and per CPU-second of this process."""

    steps_per_s: float
    steps_per_cpu_s: float
    updates_per_s: float
    updates_per_cpu_s: float


def timed(function: Callable[[], object]) -> tuple[float, float]:
    """Wall-clock and process CPU seconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def build(algorithm: type, setting: Setting, kwargs: dict[str, Any]):
    """A model on a fast-rendering cartpole, its buffer filled with warm-up steps and its first updates done."""
    env = make_env(ENV_NAME, size=setting.size, fast_render=True, seed=0)
    model = algorithm(
        "CnnPolicy",
        env,
        batch_size=setting.batch_size,
        buffer_size=10 * setting.warmup_steps,
        learning_starts=setting.warmup_steps,
        seed=0,
        **kwargs,
    )
    model.learn(setting.warmup_steps + 4)  # warm-up actions, then a couple of updates (allocator, oneDNN caches)
    return model


def measure_pair(
    plain: type, ef: type, setting: Setting, kwargs: dict[str, Any], ef_kwargs: dict[str, Any], repeats: int
) -> dict[str, Rates]:
    """Interleaved plain / EF measurements; returns the median rates of each. Babbling is off in the EF model:
    it skips the actor, which is not the steady state."""
    models = {
        "plain": build(plain, setting, kwargs),
        "ef": build(ef, setting, {**kwargs, "babbling_steps": 0, **ef_kwargs}),
    }
    samples: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in models}
    try:
        for _ in range(repeats):
            for name, model in models.items():
                loop_wall, loop_cpu = timed(lambda m=model: m.learn(setting.loop_steps, reset_num_timesteps=False))
                train_wall, train_cpu = timed(lambda m=model: m.train(setting.updates, setting.batch_size))
                samples[name].append(
                    (
                        setting.loop_steps / loop_wall,
                        setting.loop_steps / loop_cpu,
                        setting.updates / train_wall,
                        setting.updates / train_cpu,
                    )
                )
    finally:
        for model in models.values():
            model.env.close()
    return {
        name: Rates(*(statistics.median(column) for column in zip(*rows, strict=True)))
        for name, rows in samples.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--setting", choices=[*SETTINGS, "all"], default="all")
    parser.add_argument("--pair", choices=[name for name, *_ in PAIRS] + ["all"], default="all")
    parser.add_argument("--repeats", type=int, default=3)
    # One thread by default: on a shared, loaded 2-core machine two threads wait on each other at every barrier.
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument(
        "--decode-batch-size",
        type=int,
        default=None,
        help="EgoForesight's decode_batch_size for the EF model (changes the method; default: decode the whole batch)",
    )
    args = parser.parse_args()
    ef_kwargs = {}
    if args.decode_batch_size is not None:
        ef_kwargs = {"policy_kwargs": {"ef_kwargs": {"decode_batch_size": args.decode_batch_size}}}
    th.set_num_threads(args.threads)

    settings = SETTINGS if args.setting == "all" else {args.setting: SETTINGS[args.setting]}
    pairs = [pair for pair in PAIRS if args.pair in ("all", pair[0])]
    device = "CUDA " + th.cuda.get_device_name() if th.cuda.is_available() else f"CPU, {args.threads} torch threads"
    decoded = "whole batch" if args.decode_batch_size is None else f"{args.decode_batch_size} samples"
    print(f"{ENV_NAME}, fast_render, {device}; EF decodes {decoded}; load average before: {os.getloadavg()[0]:.1f}")
    print(
        "| setting | pair | env steps/s plain | env steps/s EF | EF/plain | updates/s plain | updates/s EF | EF/plain "
        "| EF/plain per CPU-s (steps, updates) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for setting_name, setting in settings.items():
        for name, plain, ef, kwargs in pairs:
            pair_setting = dataclasses.replace(setting, size=FRAME_SIZES.get(name, setting.size))
            rates = measure_pair(plain, ef, pair_setting, kwargs, ef_kwargs, args.repeats)
            p, e = rates["plain"], rates["ef"]
            print(
                f"| {setting_name} ({pair_setting.size}x{pair_setting.size}, batch {setting.batch_size}) | {name} "
                f"| {p.steps_per_s:.2f} | {e.steps_per_s:.2f} | {e.steps_per_s / p.steps_per_s:.2f} "
                f"| {p.updates_per_s:.2f} | {e.updates_per_s:.2f} | {e.updates_per_s / p.updates_per_s:.2f} "
                f"| {e.steps_per_cpu_s / p.steps_per_cpu_s:.2f}, {e.updates_per_cpu_s / p.updates_per_cpu_s:.2f} |",
                flush=True,
            )
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
