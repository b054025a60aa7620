"""bfloat16 mixed precision (``precision="bf16"``) against float32 and against the authors' own float32 updates.

In one process, on the CPU, with 1 and 2 torch threads and batches of 64 and 256 (``--threads``, ``--batch-sizes``):

- ``updates``: one update of DrQ-v2 and DrQv2-EF (84x84 frames, the paper's networks) and of TD-MPC2 (64x64), in
  float32, in bf16, and the authors' float32 update on the same batches: the transcriptions that pin sb3-ef's updates
  in the tests (``RefAgent`` of tests/drqv2/test_drqv2_reference.py, at the paper's sizes; ``RefTDMPC2`` of
  tests/helpers/tdmpc2_reference.py, vectorised Q-ensemble as the authors'). The three are interleaved, one update
  each per round, and the medians of ``--repeats`` rounds reported (after one untimed round). sb3-ef's updates include
  their random shift; the authors' are given the shifted batch.
- ``plan``: one TD-MPC2 action (MPPI, 6 iterations of 512 samples, horizon 3) for one env, sb3-ef's planner in
  float32 and bf16 and the authors' ``_plan``; its FLOP (matrix maths, counted by ``torch.utils.flop_counter``) and
  GFLOP/s, against a GEMM of the planner's main shape (512 x 512 by 512) in the same precision on the same threads.
- ``hosts``: ``train(1)`` of SEAR, CURL and SAC-EF, TD3-EF and TQC-EF (SB3's NatureCNN on 84x84 frames, CURL's
  encoder on 84x84 crops; at the first thread count and batch size), in float32, in bf16, and in bf16 without the
  channels-last convolutions bf16 adds (SEAR's decoders, the SB3 hosts' and CURL's encoders and EF decoders),
  interleaved.
- ``loop``: agent steps/s of DrQv2-EF's whole ``learn`` loop (acting, rendering, buffer, an update every 2 steps; at
  the first thread count and batch size) on dmc/cartpole-balance at 84x84, float32 and bf16 in interleaved segments.

The machine is shared: every figure is a median of interleaved repeats, and the load average is printed before and
after. The defaults take about 10 minutes on 2 cores; ``--full`` repeats more (7 rounds, longer loop segments) and
runs every section at every thread count.

    MUJOCO_GL=egl python benchmarks/precision.py --out /tmp/precision
    MUJOCO_GL=egl python benchmarks/precision.py --sections plan --threads 1 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch as th
from torch.utils.flop_counter import FlopCounterMode

from sb3_ef.common.precision import PRECISIONS, autocast
from sb3_ef.curl import CURL
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs import make_env
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.sb3_hosts import SACEF, TD3EF, TQCEF
from sb3_ef.sear import SEAR
from sb3_ef.tdmpc2 import TDMPC2
from sb3_ef.tdmpc2.sequence import SHIFT_PAD, training_sequence

WARMUP_STEPS = 300  # random-action steps that fill the buffer the batches are drawn from
VARIANTS = ("authors", *PRECISIONS)


def transcriptions() -> tuple[Any, Callable[[TDMPC2], Any]]:
    """The tests' transcriptions of the authors' updates, imported in this one place (the repository's root put on the
    path): DrQ-v2's reference test module and TD-MPC2's ``reference_of``."""
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.insert(0, root)
    from tests.drqv2 import test_drqv2_reference
    from tests.helpers.tdmpc2_reference import reference_of

    return test_drqv2_reference, reference_of


def drqv2_reference(model: DrQv2) -> Any:
    """The authors' DrQ-v2 agent (examples/drqv2_ef_single_file.py's ``DrQv2EFAgent``, with ``model``'s weights),
    built by the reference test's ``reference_of`` with its tiny sizes set to the model's (84x84 frames, 1024-wide
    heads, trunk 50, the EF sizes)."""
    reference, _ = transcriptions()
    from examples.drqv2_ef_single_file import Config

    policy, ef_kwargs = model.policy, getattr(model.policy, "ef_kwargs", {})
    reference.FRAME, reference.FEATURES = model.observation_space.shape[-1], policy.encoder.features_dim
    reference.AGENT = getattr(policy, "agent_dim", 32)
    reference.CONFIG = Config(
        learning_rate=model.lr_schedule(1), features_dim=reference.FEATURES, trunk_dim=policy.trunk_dim,
        agent_dim=reference.AGENT, horizon=getattr(model, "ef_horizon", 10),
        rollout_hidden_dims=tuple(ef_kwargs.get("rollout_hidden_dims", (512, 512))),
        decoder_channels=ef_kwargs.get("decoder_channels", 64),
    )  # fmt: skip
    return reference.reference_of(model)


def drqv2_shifted(model: DrQv2, sampled: Any) -> tuple[Any, ...]:
    """The arguments of the reference's ``update``: the batch shifted as sb3-ef's update shifts it."""
    from examples.drqv2_ef_single_file import Batch as ReferenceBatch

    observations, next_observations, targets = model._augment(sampled)
    ef = {} if targets is None else {
        "ef_step": int(targets.steps[0]), "ef_frames": targets.target, "ef_actions": targets.actions,
        "ef_valid": targets.valid,
    }  # fmt: skip
    batch = ReferenceBatch(
        observations, sampled.actions, sampled.rewards, sampled.discounts, sampled.dones, next_observations,
        **{"ef_step": 1, "ef_frames": None, "ef_actions": None, "ef_valid": None, **ef},
    )  # fmt: skip
    return batch, 0


def tdmpc2_reference(model: TDMPC2) -> Any:
    """The authors' TD-MPC2 agent (``RefTDMPC2``, with ``model``'s weights)."""
    return transcriptions()[1](model)


def tdmpc2_shifted(model: TDMPC2, sampled: Any) -> tuple[Any, ...]:
    """The arguments of ``RefTDMPC2.update``: the window shifted as sb3-ef's update shifts it, time-major."""
    sequence = training_sequence(sampled, model.horizon, partial(model._augment_observations, pad=SHIFT_PAD))
    return th.cat([sequence.first[None], sequence.following]), sequence.actions, sequence.rewards.unsqueeze(-1)


class Batch(NamedTuple):
    sampled: Any  # the replay batch sb3-ef's update is given
    shifted: tuple[Any, ...]  # the authors' update's arguments: the same batch, shifted


#: name: (class, frame size, extra arguments, the authors' agent, its update's arguments).
UPDATES: dict[str, tuple[type, int, dict[str, Any], Callable[[Any], Any], Callable[[Any, Any], tuple]]] = {
    "DrQ-v2": (DrQv2, 84, {}, drqv2_reference, drqv2_shifted),
    "DrQv2-EF": (DrQv2EF, 84, {"babbling_steps": 0}, drqv2_reference, drqv2_shifted),
    "TD-MPC2": (TDMPC2, 64, {"seed_burst": False}, tdmpc2_reference, tdmpc2_shifted),
}


def build(name: str, precision: str, batch_size: int) -> Any:
    algorithm, size, kwargs, _, _ = UPDATES[name]
    env = ToyAgentEnv(size=size, max_episode_steps=100)
    return algorithm(
        "CnnPolicy", env, batch_size=batch_size, buffer_size=WARMUP_STEPS, learning_starts=10**9, seed=0,
        device="cpu", precision=precision, **kwargs,
    )  # fmt: skip


def our_update(model: Any, batch: Any) -> None:
    """One update as ``train()`` runs it (in the model's precision)."""
    with autocast(model.precision, model.device):
        model._update(batch.sampled)


def median_ms(times: list[float]) -> float:
    return round(1000 * statistics.median(times), 1)


def measure_updates(name: str, threads: int, batch_size: int, repeats: int) -> dict[str, Any]:
    th.set_num_threads(threads)
    models = {precision: build(name, precision, batch_size) for precision in PRECISIONS}
    models["fp32"].learn(WARMUP_STEPS)  # random actions fill the buffer; the bf16 model updates on the same batches
    _, _, _, reference, shifted = UPDATES[name]
    agent = reference(models["fp32"])
    calls = {"authors": lambda batch: agent.update(*batch.shifted)}
    calls.update({precision: partial(our_update, model) for precision, model in models.items()})
    times: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
    for round_index in range(repeats + 1):
        sampled = models["fp32"].replay_buffer.sample(batch_size)
        batch = Batch(sampled, shifted(models["fp32"], sampled))
        for variant in VARIANTS:
            start = time.perf_counter()
            calls[variant](batch)
            if round_index > 0:  # the first round warms up (allocator, oneDNN's kernels)
                times[variant].append(time.perf_counter() - start)
    ms = {variant: median_ms(times[variant]) for variant in VARIANTS}
    row = {"update": name, "threads": threads, "batch": batch_size, **{f"{v}_ms": ms[v] for v in VARIANTS}}
    row.update(
        fp32_vs_authors=round(ms["authors"] / ms["fp32"], 2),
        bf16_vs_authors=round(ms["authors"] / ms["bf16"], 2),
        bf16_vs_fp32=round(ms["fp32"] / ms["bf16"], 2),
    )
    return row


def gemm_gflops(shape: tuple[int, int, int], dtype: th.dtype, repeats: int) -> float:
    """GFLOP/s of an ``(m, k) @ (k, n)`` product in ``dtype``, the median of ``repeats`` timed calls of 5 products."""
    m, k, n = shape
    a, b = th.randn(m, k, dtype=dtype), th.randn(k, n, dtype=dtype)
    a @ b
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(5):
            a @ b
        times.append((time.perf_counter() - start) / 5)
    return 2 * m * k * n / statistics.median(times) / 1e9


def measure_plan(threads: int, repeats: int) -> dict[str, Any]:
    """One action of TD-MPC2's planner (the paper's settings) for one env: ms, FLOP, GFLOP/s against a GEMM."""
    th.set_num_threads(threads)
    models = {precision: build("TD-MPC2", precision, 64) for precision in PRECISIONS}
    models["fp32"].learn(WARMUP_STEPS)
    observation = models["fp32"].replay_buffer.sample(1).observations
    agent = tdmpc2_reference(models["fp32"])
    plans: dict[str, th.Tensor | None] = dict.fromkeys(PRECISIONS)

    def ours(precision: str) -> None:
        plans[precision] = models[precision].policy.plan(observation, plans[precision], deterministic=False)[1]

    calls = {"authors": partial(agent.plan, observation), **{p: partial(ours, p) for p in PRECISIONS}}
    with FlopCounterMode(display=False) as counter:
        calls["fp32"]()
    flop = counter.get_total_flops()
    times: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
    for round_index in range(repeats + 1):
        for variant in VARIANTS:
            start = time.perf_counter()
            calls[variant]()
            if round_index > 0:
                times[variant].append(time.perf_counter() - start)
    ms = {variant: median_ms(times[variant]) for variant in VARIANTS}
    planner, model = models["fp32"].policy.planner, models["fp32"].world_model
    shape = (planner.num_samples, model.latent_dim + model.action_dim, model.dynamics[0][0].out_features)
    dtypes = {"fp32": th.float32, "bf16": th.bfloat16}
    gemm = {precision: gemm_gflops(shape, dtypes[precision], repeats) for precision in PRECISIONS}
    row: dict[str, Any] = {"threads": threads, "gflop_per_action": round(flop / 1e9, 2), "gemm_shape": list(shape)}
    for variant in VARIANTS:
        row[f"{variant}_ms"] = ms[variant]
    for precision in PRECISIONS:
        achieved = flop / (ms[precision] / 1000) / 1e9
        row[f"{precision}_gflops"] = round(achieved, 1)
        row[f"{precision}_gemm_gflops"] = round(gemm[precision], 1)
        row[f"{precision}_of_gemm"] = round(achieved / gemm[precision], 2)
    row.update(bf16_vs_authors=round(ms["authors"] / ms["bf16"], 2), bf16_vs_fp32=round(ms["fp32"] / ms["bf16"], 2))
    return row


def channels_last_modules(model: Any) -> list[Any]:
    """The convolutions bf16 keeps channels-last where float32 does not: SEAR's decoders; the SB3 hosts' and CURL's
    actor, critic, target and auxiliary module."""
    if isinstance(model, SEAR):
        return [model.auxiliary]
    return [model.actor, model.critic, model.critic_target, model.auxiliary_module]


#: The other hosts: name: (class, rendered frame size, extra arguments).
HOSTS: dict[str, tuple[type, int, dict[str, Any]]] = {
    "SEAR": (SEAR, 84, {}),
    "CURL": (CURL, 100, {}),
    "SACEF": (SACEF, 84, {"babbling_steps": 0}),
    "TD3EF": (TD3EF, 84, {"babbling_steps": 0}),
    "TQCEF": (TQCEF, 84, {"babbling_steps": 0}),
}


def measure_host(name: str, threads: int, batch_size: int, repeats: int) -> dict[str, Any]:
    """``train(1)`` of a host in float32, in bf16, and in bf16 without its channels-last convolutions, interleaved."""
    th.set_num_threads(threads)
    algorithm, size, kwargs = HOSTS[name]
    models = {}
    for variant, precision in (("fp32", "fp32"), ("bf16", "bf16"), ("bf16_contiguous", "bf16")):
        env = ToyAgentEnv(size=size, max_episode_steps=100, agent_masks=algorithm is SEAR)
        models[variant] = algorithm(
            "CnnPolicy", env, batch_size=batch_size, buffer_size=WARMUP_STEPS, learning_starts=WARMUP_STEPS - 10,
            seed=0, device="cpu", precision=precision, **kwargs,
        )  # fmt: skip
        if variant == "bf16_contiguous":
            for module in channels_last_modules(models[variant]):
                module.to(memory_format=th.contiguous_format)
        models[variant].learn(WARMUP_STEPS)  # the buffer filled, the first updates run
    times: dict[str, list[float]] = {variant: [] for variant in models}
    for _ in range(repeats):
        for variant, model in models.items():
            start = time.perf_counter()
            model.train(1, batch_size)
            times[variant].append(time.perf_counter() - start)
    ms = {variant: median_ms(values) for variant, values in times.items()}
    return {
        "host": name, "threads": threads, "batch": batch_size, **{f"{v}_ms": value for v, value in ms.items()},
        "bf16_vs_fp32": round(ms["fp32"] / ms["bf16"], 2),
        "channels_last_in_bf16": round(ms["bf16_contiguous"] / ms["bf16"], 2),
    }  # fmt: skip


def measure_loop(threads: int, batch_size: int, steps: int, segments: int) -> dict[str, Any]:
    """Agent steps/s of DrQv2-EF's ``learn`` on a rendered DMC task, float32 and bf16 in interleaved segments."""
    th.set_num_threads(threads)
    models = {}
    for precision in PRECISIONS:
        env = make_env("dmc/cartpole-balance", size=84, seed=0)
        models[precision] = DrQv2EF(
            "CnnPolicy", env, batch_size=batch_size, buffer_size=10_000, learning_starts=WARMUP_STEPS,
            babbling_steps=0, seed=0, device="cpu", precision=precision,
        )  # fmt: skip
        models[precision].learn(WARMUP_STEPS + 2 * 2)  # the buffer filled, two updates run
    rates: dict[str, list[float]] = {precision: [] for precision in PRECISIONS}
    for _ in range(segments):
        for precision, model in models.items():
            start = time.perf_counter()
            model.learn(steps, reset_num_timesteps=False)
            rates[precision].append(steps / (time.perf_counter() - start))
    for model in models.values():
        model.env.close()
    medians = {precision: statistics.median(rates[precision]) for precision in PRECISIONS}
    return {
        "threads": threads, "batch": batch_size, "steps_per_segment": steps,
        **{f"{precision}_steps_per_s": round(rate, 2) for precision, rate in medians.items()},
        "bf16_vs_fp32": round(medians["bf16"] / medians["fp32"], 2),
    }  # fmt: skip


def machine() -> str:
    """The CPU's model name, cores and bfloat16 instructions, and torch's version."""
    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    names = [line.split(":", 1)[1].strip() for line in info.splitlines() if line.startswith("model name")]
    bf16 = "AVX512-BF16" if "avx512_bf16" in info else "no AVX512-BF16"
    model = names[0] if names else platform.processor()
    return f"{model} ({os.cpu_count()} cores, {bf16}), torch {th.__version__}"


#: Each section's table: its columns, and each row's cells from a measured row.
TABLES: dict[str, tuple[str, Callable[[dict[str, Any]], str]]] = {
    "updates": (
        "update | threads | batch | authors ms | fp32 ms | bf16 ms | fp32 vs authors | bf16 vs authors | bf16 vs fp32",
        lambda r: (
            f"{r['update']} | {r['threads']} | {r['batch']} | {r['authors_ms']} | {r['fp32_ms']} | {r['bf16_ms']} "
            f"| {r['fp32_vs_authors']:.2f}x | {r['bf16_vs_authors']:.2f}x | {r['bf16_vs_fp32']:.2f}x"
        ),
    ),
    "plan": (
        "TD-MPC2 plan, threads | GFLOP/action | authors ms | fp32 ms | bf16 ms | bf16 vs authors | bf16 vs fp32 "
        "| fp32 GFLOP/s (GEMM's, share) | bf16 GFLOP/s (GEMM's, share)",
        lambda r: (
            f"{r['threads']} | {r['gflop_per_action']} | {r['authors_ms']} | {r['fp32_ms']} | {r['bf16_ms']} "
            f"| {r['bf16_vs_authors']:.2f}x | {r['bf16_vs_fp32']:.2f}x "
            f"| {r['fp32_gflops']} ({r['fp32_gemm_gflops']}, {r['fp32_of_gemm']:.0%}) "
            f"| {r['bf16_gflops']} ({r['bf16_gemm_gflops']}, {r['bf16_of_gemm']:.0%})"
        ),
    ),
    "hosts": (
        "host | threads | batch | fp32 ms | bf16 ms | bf16 without channels-last ms | bf16 vs fp32 "
        "| channels-last in bf16",
        lambda r: (
            f"{r['host']} | {r['threads']} | {r['batch']} | {r['fp32_ms']} | {r['bf16_ms']} "
            f"| {r['bf16_contiguous_ms']} | {r['bf16_vs_fp32']:.2f}x | {r['channels_last_in_bf16']:.2f}x"
        ),
    ),
    "loop": (
        "DrQv2-EF learn loop, threads | batch | agent steps/s fp32 | agent steps/s bf16 | bf16 vs fp32",
        lambda r: (
            f"{r['threads']} | {r['batch']} | {r['fp32_steps_per_s']} | {r['bf16_steps_per_s']} "
            f"| {r['bf16_vs_fp32']:.2f}x"
        ),
    ),
}


def markdown(results: dict[str, list[dict[str, Any]]], header: str) -> str:
    lines = [header]
    for section, rows in results.items():
        columns, cells = TABLES[section]
        lines += ["", f"| {columns} |", "|---" * (columns.count("|") + 1) + "|", *(f"| {cells(r)} |" for r in rows)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sections", nargs="+", choices=list(TABLES), default=list(TABLES))
    parser.add_argument("--updates", nargs="+", choices=list(UPDATES), default=list(UPDATES))
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=[64, 256])
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds (after one untimed round)")
    parser.add_argument("--loop-steps", type=int, default=20, help="agent steps per timed segment of the learn loop")
    parser.add_argument("--full", action="store_true", help="7 rounds, loop segments of 100 steps, every section")
    parser.add_argument("--out", type=Path, help="writes OUT.json and OUT.md")
    args = parser.parse_args(argv)
    if args.full:
        args.repeats, args.loop_steps = max(args.repeats, 7), max(args.loop_steps, 100)
    warnings.filterwarnings("ignore", message="learning_starts=")  # the warm-ups fill buffers without updates
    np.random.seed(0)
    header = f"{machine()}; load average before: {os.getloadavg()[0]:.1f}"
    print(header, flush=True)
    started = time.perf_counter()
    results: dict[str, list[dict[str, Any]]] = {section: [] for section in args.sections}

    def record(section: str, row: dict[str, Any]) -> None:
        results[section].append(row)
        print(json.dumps(row), flush=True)

    for threads in args.threads:
        if "updates" in args.sections:
            for batch_size in args.batch_sizes:
                for name in args.updates:
                    record("updates", measure_updates(name, threads, batch_size, args.repeats))
        if "plan" in args.sections:
            record("plan", measure_plan(threads, args.repeats))
        # The slower sections at the first thread count and batch size only (``--full``: at every thread count).
        if threads == args.threads[0] or args.full:
            for name in HOSTS if "hosts" in args.sections else ():
                record("hosts", measure_host(name, threads, args.batch_sizes[0], args.repeats))
            if "loop" in args.sections:
                record("loop", measure_loop(threads, args.batch_sizes[0], args.loop_steps, args.repeats))
    header += f", after: {os.getloadavg()[0]:.1f}; {time.perf_counter() - started:.0f} s"
    table = markdown(results, header)
    print(table)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".json").write_text(json.dumps({"header": header, "results": results}, indent=2))
        args.out.with_suffix(".md").write_text(table)


if __name__ == "__main__":
    main()
