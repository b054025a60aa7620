"""One GPU benchmark: DrQ-v2, DrQv2-EF, SEAR (84x84), TD-MPC2, TDMPC2-EF (64x64), CURL (84x84 crops of 100x100
renders) and Dreamer-v3 (sheeprl's, 64x64; ``pip install -e .[dreamerv3]``) at the paper's settings.

For each algorithm, eager and compiled (the torch.compile mode given by ``--compile-mode``: ``default``, or e.g.
``reduce-overhead`` for CUDA graphs; CURL, whose update is its authors' eager one, has no compiled mode), on
``dmc/cartpole-swingup`` with real rendering (``fast_render``; SEAR's env also renders agent masks), batch 256 and a
1M-frame replay buffer with ``storage_device="auto"`` (in device memory where it fits):

- ``sample ms``: median of ``SequenceReplayBuffer.sample(256)`` calls, synchronised;
- ``updates/s``: ``train()`` alone, one gradient step at a time;
- ``env steps/s``: the whole training loop (acting, env step with rendering, buffer, updates at the algorithm's
  ``train_freq``), after warm-up;
- ``peak GB``: the device's peak allocated memory during the run (buffer included).

Dreamer-v3 trains in sheeprl's loop at its own settings (the S model, batch 16 sequences x 64 steps, replay ratio
0.5 gradient steps per env step, its replay buffer memory-mapped on disk): its ``env steps/s`` are those of
``loop_steps`` steps of that loop after a warm-up (``warmup_steps`` random steps, then ``loop_steps`` of training),
and it has no sample or ``train()`` timing; it runs eager (sheeprl's own ``algo.compile`` is not measured here).

``--precision bf16`` runs every algorithm in bfloat16 mixed precision (its ``precision`` argument, docs/precision.md).

Writes JSON and a Markdown table (``--out PATH`` gives ``PATH.json`` and ``PATH.md``). Eager runs go first; a run
that would start past ``--budget-s`` is recorded as skipped, so the script ends in time (under 8 minutes on one
H200 with the defaults). ``--device cpu --smoke`` runs every code path on a CPU with tiny sizes, in under 2 minutes
(its timings mean nothing; its compiled runs use torch.compile's ``aot_eager`` backend: the same graph capture,
without Inductor's minutes of C++ code generation on a CPU).

    MUJOCO_GL=egl python benchmarks/gpu.py --out /tmp/gpu
    MUJOCO_GL=egl python benchmarks/gpu.py --precision bf16 --out /tmp/gpu-bf16
    MUJOCO_GL=egl python benchmarks/gpu.py --device cpu --smoke --out /tmp/gpu-smoke
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import statistics
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch as th

from sb3_ef.common.precision import PRECISIONS
from sb3_ef.curl import CURL
from sb3_ef.dreamerv3 import DreamerV3
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs import make_env
from sb3_ef.sear import SEAR
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

ENV_NAME = "dmc/cartpole-swingup"
ALGORITHMS: dict[str, tuple[type, int]] = {  # name: (class, rendered frame size)
    "DrQv2": (DrQv2, 84),
    "DrQv2EF": (DrQv2EF, 84),
    "SEAR": (SEAR, 84),
    "TDMPC2": (TDMPC2, 64),
    "TDMPC2EF": (TDMPC2EF, 64),
    "CURL": (CURL, 100),
    "DreamerV3": (DreamerV3, 64),
}
# What an algorithm needs beyond the others: SEAR's env renders agent masks, CURL crops 84x84 windows.
ENV_KWARGS: dict[str, dict[str, Any]] = {"SEAR": {"agent_masks": True}}
ALGORITHM_KWARGS: dict[str, dict[str, Any]] = {"CURL": {"crop_size": 84}}
# Algorithms without a ``compile`` argument (SB3's own updates; sheeprl's loop).
EAGER_ONLY = frozenset({"CURL", "DreamerV3"})
# (baseline, algorithm) pairs of the ratio table: EF against its host, and the paper's other baselines against
# DrQ-v2 (its throughput table: SEAR 88 and CURL 44 against DrQ-v2's 155 env steps/s).
RATIOS = (("DrQv2", "DrQv2EF"), ("TDMPC2", "TDMPC2EF"), ("DrQv2", "SEAR"), ("DrQv2", "CURL"), ("DrQv2", "DreamerV3"))
#: Dreamer-v3's settings: the authors' DMC-vision recipe (zoo_configs/dreamerv3.yml); the smoke run's model is tiny.
DREAMER_KWARGS: dict[str, Any] = {"model_size": "S", "batch_size": 16, "sequence_length": 64, "replay_ratio": 0.5}
SMOKE_DREAMER_KWARGS: dict[str, Any] = {
    "model_size": "XS",
    "batch_size": 4,
    "sequence_length": 8,
    "sheeprl_overrides": {"algo.dense_units": 16, "algo.world_model.recurrent_model.recurrent_state_size": 16},
}


@dataclass(frozen=True)
class Sizes:
    """How much each run does."""

    buffer_size: int
    batch_size: int
    warmup_steps: int  # random-action steps that fill the buffer before learning starts
    warmup_updates: int  # untimed updates (allocator, cuDNN autotuning, compilation)
    sample_repeats: int
    updates: int
    loop_steps: int


PAPER = Sizes(
    buffer_size=1_000_000,
    batch_size=256,
    warmup_steps=1000,
    warmup_updates=5,
    sample_repeats=50,
    updates=40,
    loop_steps=200,
)
SMOKE = Sizes(
    buffer_size=2000, batch_size=8, warmup_steps=30, warmup_updates=1, sample_repeats=3, updates=2, loop_steps=4
)
# Small networks for the smoke run only: the code paths are the same, the CPU time is not.
SMOKE_POLICY: dict[str, dict[str, Any]] = {
    "DrQv2": {"net_arch": [32], "trunk_dim": 16, "features_dim": 64},
    "SEAR": {"net_arch": [32], "trunk_dim": 16, "features_dim": 64},
    "CURL": {"net_arch": [32], "features_extractor_kwargs": {"features_dim": 16}},
    "TDMPC2": {
        "num_channels": 4,
        "mlp_dim": 32,
        "num_q": 2,
        "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 2},
    },
}
SMOKE_EF_POLICY = {"agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}


@dataclass
class Result:
    algorithm: str
    compiled: bool
    frame_size: int
    status: str = "ok"
    storage_device: str = ""
    buffer_gb: float | None = None
    sample_ms: float | None = None
    updates_per_s: float | None = None
    env_steps_per_s: float | None = None
    peak_memory_gb: float | None = None
    seconds: float | None = None


def synchronize(device: th.device) -> None:
    if device.type == "cuda":
        th.cuda.synchronize(device)


def build(name: str, compiled: bool | str | dict, device: th.device, sizes: Sizes, smoke: bool, precision: str):
    """The model on a fast-rendering cartpole, its 1M-frame (smoke: small) buffer in ``auto`` storage."""
    algorithm, frame_size = ALGORITHMS[name]
    env = make_env(ENV_NAME, size=frame_size, fast_render=True, seed=0, **ENV_KWARGS.get(name, {}))
    kwargs: dict[str, Any] = {
        **ALGORITHM_KWARGS.get(name, {}),
        "batch_size": sizes.batch_size,
        "buffer_size": sizes.buffer_size,
        "learning_starts": sizes.warmup_steps,
        "seed": 0,
        "device": device,
        "precision": precision,
        "replay_buffer_kwargs": {"storage_device": "auto"},
    }
    uses_ef = name.endswith("EF")
    if uses_ef:
        kwargs["babbling_steps"] = 0  # babbling skips the actor: not the steady state
    if smoke:
        kwargs["policy_kwargs"] = {**SMOKE_POLICY[name.removesuffix("EF")], **(SMOKE_EF_POLICY if uses_ef else {})}
    if compiled:
        kwargs["compile"] = compiled
    try:
        return algorithm("CnnPolicy", env, **kwargs)
    except BaseException:
        env.close()
        raise


def measure(
    name: str, compiled: bool | str | dict, device: th.device, sizes: Sizes, smoke: bool, precision: str = "fp32"
) -> Result:
    """Build, warm up and time one algorithm (``compiled``: the algorithm's ``compile`` argument); errors become the
    result's status, so later runs still happen."""
    result = Result(name, bool(compiled), ALGORITHMS[name][1])
    if compiled and name in EAGER_ONLY:
        result.status = "skipped (no compiled mode)"
        return result
    started = time.perf_counter()
    if device.type == "cuda":
        th.cuda.reset_peak_memory_stats(device)
    if name == "DreamerV3":
        measure_dreamer(result, device, sizes, smoke, precision)
        result.seconds = round(time.perf_counter() - started, 1)
        return result
    model = buffer = None
    try:
        model = build(name, compiled, device, sizes, smoke, precision)
        buffer = model.replay_buffer
        result.storage_device = str(buffer.storage_device)
        result.buffer_gb = round(buffer.nbytes / 1e9, 3)
        model.learn(sizes.warmup_steps)  # random actions fill the buffer
        model.train(sizes.warmup_updates, sizes.batch_size)

        times = []
        for _ in range(sizes.sample_repeats):
            synchronize(device)
            start = time.perf_counter()
            buffer.sample(sizes.batch_size)
            synchronize(device)
            times.append(1000 * (time.perf_counter() - start))
        result.sample_ms = round(statistics.median(times), 3)

        synchronize(device)
        start = time.perf_counter()
        for _ in range(sizes.updates):
            model.train(1, sizes.batch_size)
        synchronize(device)
        result.updates_per_s = round(sizes.updates / (time.perf_counter() - start), 2)

        start = time.perf_counter()
        model.learn(sizes.loop_steps, reset_num_timesteps=False)
        synchronize(device)
        result.env_steps_per_s = round(sizes.loop_steps / (time.perf_counter() - start), 2)
    except Exception as error:  # one failing run must not cost the others
        result.status = f"error: {type(error).__name__}: {error}"
        traceback.print_exc()
    finally:
        if device.type == "cuda":
            result.peak_memory_gb = round(th.cuda.max_memory_allocated(device) / 1e9, 2)
        if model is not None:
            model.env.close()
        del model, buffer  # free the device buffer before the next run measures free memory
        gc.collect()
        if device.type == "cuda":
            th.cuda.empty_cache()
    result.seconds = round(time.perf_counter() - started, 1)
    return result


def measure_dreamer(result: Result, device: th.device, sizes: Sizes, smoke: bool, precision: str) -> None:
    """Dreamer-v3's env steps/s over ``loop_steps`` steps of sheeprl's loop, after ``warmup_steps`` random steps and
    ``loop_steps`` steps of training (untimed); errors become the result's status."""
    from dreamer_timing import timed_training  # beside this file

    env = make_env(ENV_NAME, size=result.frame_size, frame_stack=1, fast_render=True, seed=0)
    result.storage_device = "disk (memmap)"
    every = sizes.loop_steps
    first = -(-sizes.warmup_steps // every) * every + every  # the first mark after a whole segment of training
    try:
        with tempfile.TemporaryDirectory(prefix="gpu_dreamerv3_") as folder:
            model = DreamerV3(
                "CnnPolicy", env, buffer_size=sizes.buffer_size, learning_starts=sizes.warmup_steps, work_dir=folder,
                seed=0, device=str(device), precision=precision,
                **(SMOKE_DREAMER_KWARGS if smoke else DREAMER_KWARGS),
            )  # fmt: skip
            marks = {mark.step: mark for mark in timed_training(model, first + every, every)}
            start, end = marks[first], marks[first + every]
            result.env_steps_per_s = round(every / (end.wall_s - start.wall_s), 2)
    except Exception as error:  # one failing run must not cost the others
        result.status = f"error: {type(error).__name__}: {error}"
        traceback.print_exc()
    finally:
        env.close()
        if device.type == "cuda":
            result.peak_memory_gb = round(th.cuda.max_memory_allocated(device) / 1e9, 2)
            th.cuda.empty_cache()


def ratio(results: list[Result], plain: str, ef: str, compiled: bool, field: str) -> str:
    values = {r.algorithm: getattr(r, field) for r in results if r.compiled == compiled and r.status == "ok"}
    return f"{values[ef] / values[plain]:.2f}" if values.get(plain) and values.get(ef) else "-"


def markdown(results: list[Result], header: str) -> str:
    def cell(value: float | None) -> str:
        return "-" if value is None else f"{value:g}"

    lines = [
        header,
        "",
        "| algorithm | frames | mode | status | storage | buffer GB | sample ms | updates/s | env steps/s "
        "| peak GB | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.algorithm} | {r.frame_size}x{r.frame_size} | {'compiled' if r.compiled else 'eager'} | {r.status} "
            f"| {r.storage_device or '-'} | {cell(r.buffer_gb)} | {cell(r.sample_ms)} | {cell(r.updates_per_s)} "
            f"| {cell(r.env_steps_per_s)} | {cell(r.peak_memory_gb)} | {cell(r.seconds)} |"
        )
    lines += [
        "",
        "| algorithm / baseline | mode | updates/s ratio | env steps/s ratio |",
        "|---|---|---|---|",
    ]
    for baseline, algorithm in RATIOS:
        for compiled in (False, True):
            lines.append(
                f"| {algorithm} / {baseline} | {'compiled' if compiled else 'eager'} | "
                f"{ratio(results, baseline, algorithm, compiled, 'updates_per_s')} | "
                f"{ratio(results, baseline, algorithm, compiled, 'env_steps_per_s')} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--smoke", action="store_true", help="tiny sizes: checks the code paths, times nothing")
    parser.add_argument("--out", type=Path, default=Path("gpu-benchmark"), help="writes OUT.json and OUT.md")
    parser.add_argument("--algorithms", nargs="+", choices=list(ALGORITHMS), default=list(ALGORITHMS))
    parser.add_argument("--modes", nargs="+", choices=["eager", "compiled"], default=["eager", "compiled"])
    parser.add_argument(
        "--compile-mode", default="default", help="torch.compile mode of the compiled runs (default, reduce-overhead)"
    )
    parser.add_argument("--precision", choices=PRECISIONS, default="fp32", help="every algorithm's precision")
    parser.add_argument("--budget-s", type=float, default=330.0, help="no run starts after this many seconds")
    args = parser.parse_args(argv)
    device = th.device(args.device)
    sizes = SMOKE if args.smoke else PAPER
    if device.type == "cuda":
        th.backends.cudnn.benchmark = True
        machine = (
            f"{th.cuda.get_device_name(device)}, {th.cuda.get_device_properties(device).total_memory / 1e9:.0f} GB"
        )
    else:
        machine = f"CPU ({os.cpu_count()} cores, {th.get_num_threads()} torch threads)"
    header = (
        f"{ENV_NAME}, fast_render, batch {sizes.batch_size}, buffer {sizes.buffer_size} frames (storage auto), "
        f"precision {args.precision}; "
        f"{machine}; torch {th.__version__}, Python {platform.python_version()}; "
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')}"
    )
    if args.smoke:
        header += "; SMOKE RUN: sizes are tiny, timings mean nothing"
    print(header, flush=True)
    started = time.perf_counter()
    results = []
    for mode in args.modes:
        for name in args.algorithms:
            if time.perf_counter() - started > args.budget_s:
                results.append(Result(name, mode == "compiled", ALGORITHMS[name][1], status="skipped (time budget)"))
                continue
            compiled = mode == "compiled" and ({"backend": "aot_eager"} if args.smoke else args.compile_mode)
            results.append(measure(name, compiled, device, sizes, args.smoke, args.precision))
            print(json.dumps(asdict(results[-1])), flush=True)
    table = markdown(results, header)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(
        json.dumps({"header": header, "results": [asdict(r) for r in results]}, indent=2)
    )
    args.out.with_suffix(".md").write_text(table)
    print(table)
    print(f"total {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
