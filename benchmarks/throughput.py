"""Training throughput of the Ego-Foresight algorithms against their plain versions, and of the paper's other
baselines against their hosts (SEAR against DrQ-v2, CURL against SAC) and against DrQ-v2 (Dreamer-v3), in the same
run.

For each pair (baseline, algorithm) and each setting it measures, after a warm-up that fills the buffer:
- env steps/s of the whole training loop (acting, env step with rendering, buffer, updates at the algorithm's
  ``train_freq``), as the paper's throughput table does;
- updates/s of ``train()`` alone (one gradient step at the setting's batch size).
Baseline and algorithm runs are interleaved ``--repeats`` times and the medians are reported, with wall-clock rates
and rates per CPU-second of this process (the latter are less sensitive to other processes on a shared machine).

Dreamer-v3 (sheeprl's, ``pip install -e .[dreamerv3]``) trains in sheeprl's own loop at its own settings (the S
model, 64x64 frames, batch 16 x 64, replay ratio 0.5 gradient steps per env step): its env steps/s are those of
``--repeats`` consecutive segments of ``dreamer_loop_steps`` steps of one sheeprl run after its warm-up (not interleaved
with the baseline's), and it has no ``train()`` of its own to time (its updates/s are ``-``). The paper's throughput
table has it at 41 env steps/s against DrQ-v2's 155 (0.26), and CURL at 44 (0.28 of DrQ-v2's).

Usage (headless rendering needs EGL)::

    MUJOCO_GL=egl python benchmarks/throughput.py --setting all --threads 1
    MUJOCO_GL=egl python benchmarks/throughput.py --setting cpu-64 --threads 1 --pair SEAR CURL
    MUJOCO_GL=egl python benchmarks/throughput.py --setting cpu-small --pair CURL Dreamer-v3   # the paper's ratios

To add a pair, append a :class:`Pair` to ``PAIRS``; both classes must accept
``policy, env, batch_size, buffer_size, learning_starts, seed`` (Dreamer-v3's own settings are
:data:`DREAMER_KWARGS`).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch as th
from stable_baselines3 import SAC

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.curl import CURL, CURLEncoder
from sb3_ef.dreamerv3 import DreamerV3
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs import make_env
from sb3_ef.sear import SEAR
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

ENV_NAME = "dmc/cartpole-swingup"


@dataclass(frozen=True)
class Pair:
    """A baseline and the algorithm compared with it. ``input_size(size)`` is the encoders' input size at a setting's
    ``size``; ``kwargs(input)`` gives the (baseline, algorithm) constructor arguments for it; ``render(input)`` the
    rendered frame size; ``env_kwargs`` go to the algorithm's env only (``make_env``'s)."""

    name: str
    baseline: type
    algorithm: type
    kwargs: Callable[[int], tuple[dict[str, Any], dict[str, Any]]]
    input_size: Callable[[int], int] = lambda size: size
    render: Callable[[int], int] = lambda size: size
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    is_ef: bool = False


def _curl_kwargs(size: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """SAC with CURL's encoder, acting and learning on the centre crop of whole frames, against CURL (the same
    encoder on random crops, plus its contrastive step); both at the CURL paper's networks."""
    sac_policy = {
        "features_extractor_class": CURLEncoder,
        "features_extractor_kwargs": {"crop_size": size},
        "normalize_images": False,
        "net_arch": [1024, 1024],
    }
    shared = {"learning_rate": 1e-3, "ent_coef": "auto_0.1", "target_update_interval": 2}
    sac = {**shared, "policy_kwargs": sac_policy, "replay_buffer_class": SequenceReplayBuffer}
    return sac, {**shared, "crop_size": size, "policy_kwargs": {"net_arch": [1024, 1024]}}


PAIRS: list[Pair] = [
    Pair("DrQ-v2", DrQv2, DrQv2EF, lambda size: ({}, {}), is_ef=True),
    # The warm-up's burst of updates is not measured; TD-MPC2's conv stack is built for 64x64.
    Pair("TD-MPC2", TDMPC2, TDMPC2EF, lambda size: ({"seed_burst": False},) * 2, lambda size: 64, is_ef=True),
    Pair("SEAR", DrQv2, SEAR, lambda size: ({}, {}), env_kwargs={"agent_masks": True}),
    # CURL renders 100x100 frames for 84x84 crops: the same ratio at other sizes.
    Pair("CURL", SAC, CURL, _curl_kwargs, render=lambda size: round(size * 100 / 84)),
    # Dreamer-v3 at its own 64x64 frames (the setting's size stays DrQ-v2's), timed by measure_dreamer.
    Pair("Dreamer-v3", DrQv2, DreamerV3, lambda size: ({}, {}), render=lambda size: 64),
]
#: Dreamer-v3's settings in the throughput runs: the authors' DMC-vision recipe (zoo_configs/dreamerv3.yml).
DREAMER_KWARGS: dict[str, Any] = {"model_size": "S", "batch_size": 16, "sequence_length": 64, "replay_ratio": 0.5}


@dataclass(frozen=True)
class Setting:
    """Image size, batch size and how much to run (``dreamer_loop_steps``: Dreamer-v3's timed segments, shorter on
    a CPU, where each of its gradient steps at 16 x 64 takes seconds)."""

    size: int
    batch_size: int
    warmup_steps: int
    loop_steps: int
    updates: int
    dreamer_loop_steps: int = 8


SETTINGS = {
    "paper": Setting(size=84, batch_size=256, warmup_steps=300, loop_steps=20, updates=4, dreamer_loop_steps=100),
    "cpu-small": Setting(size=84, batch_size=32, warmup_steps=300, loop_steps=60, updates=20),
    "cpu-64": Setting(size=64, batch_size=32, warmup_steps=300, loop_steps=40, updates=10),
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


def build(algorithm: type, setting: Setting, kwargs: dict[str, Any], env_kwargs: dict[str, Any] | None = None):
    """A model on a fast-rendering cartpole, its buffer filled with warm-up steps and its first updates done."""
    env = make_env(ENV_NAME, size=setting.size, fast_render=True, seed=0, **(env_kwargs or {}))
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


def one_repeat(model: Any, setting: Setting) -> tuple[float, float, float, float]:
    """One measurement of an SB3-style model: the training loop, then ``train()`` alone (wall and CPU rates)."""
    loop_wall, loop_cpu = timed(lambda: model.learn(setting.loop_steps, reset_num_timesteps=False))
    train_wall, train_cpu = timed(lambda: model.train(setting.updates, setting.batch_size))
    return (
        setting.loop_steps / loop_wall,
        setting.loop_steps / loop_cpu,
        setting.updates / train_wall,
        setting.updates / train_cpu,
    )


def medians(rows: Sequence[tuple[float, ...]]) -> Rates:
    """The median of each rate over the repeats."""
    steps, steps_cpu, updates, updates_cpu = (statistics.median(column) for column in zip(*rows, strict=True))
    return Rates(steps, steps_cpu, updates, updates_cpu)


def measure_pair(pair: Pair, setting: Setting, ef_kwargs: dict[str, Any], repeats: int) -> dict[str, Rates]:
    """Interleaved baseline / algorithm measurements at the setting's encoder input size; returns the median rates of
    each (keys ``plain`` and ``ef``). Babbling is off in an EF model: it skips the actor, which is not the steady
    state; ``ef_kwargs`` apply to EF models only."""
    if pair.algorithm is DreamerV3:
        return measure_dreamer(pair, setting, repeats)
    size = pair.input_size(setting.size)
    baseline_kwargs, algorithm_kwargs = pair.kwargs(size)
    if pair.is_ef:
        algorithm_kwargs = {**algorithm_kwargs, "babbling_steps": 0, **ef_kwargs}
    rendered = dataclasses.replace(setting, size=pair.render(size))
    models = {
        "plain": build(pair.baseline, rendered, baseline_kwargs),
        "ef": build(pair.algorithm, rendered, algorithm_kwargs, pair.env_kwargs),
    }
    samples: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in models}
    try:
        for _ in range(repeats):
            for name, model in models.items():
                samples[name].append(one_repeat(model, setting))
    finally:
        for model in models.values():
            model.env.close()
    return {name: medians(rows) for name, rows in samples.items()}


def measure_dreamer(pair: Pair, setting: Setting, repeats: int) -> dict[str, Rates]:
    """The baseline's ``repeats`` measurements at the setting, then one sheeprl run of Dreamer-v3 at its own
    settings (:data:`DREAMER_KWARGS`, 64x64 frames, the warm-up's random steps first), timed over ``repeats``
    segments of ``dreamer_loop_steps`` steps that start after the warm-up. Dreamer-v3's updates/s are NaN (it has
    no ``train()`` of its own)."""
    from dreamer_timing import timed_training  # beside this file

    baseline = build(pair.baseline, setting, pair.kwargs(setting.size)[0])
    try:
        rows = [one_repeat(baseline, setting) for _ in range(repeats)]
    finally:
        baseline.env.close()
    every = setting.dreamer_loop_steps
    first = -(-setting.warmup_steps // every) * every + every  # the first mark after a whole segment of training
    env = make_env(ENV_NAME, size=pair.render(setting.size), frame_stack=1, fast_render=True, seed=0)
    try:
        with tempfile.TemporaryDirectory(prefix="throughput_dreamerv3_") as folder:
            model = DreamerV3(
                "CnnPolicy", env, buffer_size=10 * setting.warmup_steps, learning_starts=setting.warmup_steps,
                work_dir=folder, seed=0, **DREAMER_KWARGS,
            )  # fmt: skip
            marks = [mark for mark in timed_training(model, first + repeats * every, every) if mark.step >= first]
    finally:
        env.close()
    segments = [
        ((end.step - start.step) / (end.wall_s - start.wall_s), (end.step - start.step) / (end.cpu_s - start.cpu_s))
        for start, end in itertools.pairwise(marks)
    ]
    nan = float("nan")
    return {"plain": medians(rows), "ef": medians([(*segment, nan, nan) for segment in segments])}


def frames_label(pair: Pair, setting: Setting) -> str:
    """The frames (and, for Dreamer-v3, its own settings) of a row of the table."""
    size = pair.input_size(setting.size)
    if pair.algorithm is DreamerV3:
        return f"{size}x{size}; DreamerV3 {pair.render(size)}x{pair.render(size)}, batch 16 x 64, replay ratio 0.5"
    rendered = pair.render(size)
    return f"{size}x{size}" if size == rendered else f"{size}x{size} crops of {rendered}x{rendered}"


def rate(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--setting", choices=[*SETTINGS, "all"], default="all")
    parser.add_argument("--pair", nargs="+", choices=[pair.name for pair in PAIRS] + ["all"], default=["all"])
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
    pairs = [pair for pair in PAIRS if "all" in args.pair or pair.name in args.pair]
    device = "CUDA " + th.cuda.get_device_name() if th.cuda.is_available() else f"CPU, {args.threads} torch threads"
    decoded = "whole batch" if args.decode_batch_size is None else f"{args.decode_batch_size} samples"
    print(f"{ENV_NAME}, fast_render, {device}; EF decodes {decoded}; load average before: {os.getloadavg()[0]:.1f}")
    print(
        "| setting | pair (algorithm / baseline) | env steps/s baseline | env steps/s algorithm | ratio "
        "| updates/s baseline | updates/s algorithm | ratio | ratio per CPU-s (steps, updates) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for setting_name, setting in settings.items():
        for pair in pairs:
            rates = measure_pair(pair, setting, ef_kwargs, args.repeats)
            p, e = rates["plain"], rates["ef"]
            label = f"{pair.algorithm.__name__} / {pair.baseline.__name__}"
            print(
                f"| {setting_name} ({frames_label(pair, setting)}, batch {setting.batch_size}) | {label} "
                f"| {p.steps_per_s:.2f} | {e.steps_per_s:.2f} | {e.steps_per_s / p.steps_per_s:.2f} "
                f"| {p.updates_per_s:.2f} | {rate(e.updates_per_s)} | {rate(e.updates_per_s / p.updates_per_s)} "
                f"| {e.steps_per_cpu_s / p.steps_per_cpu_s:.2f}, {rate(e.updates_per_cpu_s / p.updates_per_cpu_s)} |",
                flush=True,
            )
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
