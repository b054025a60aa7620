"""Ego-Foresight speed: one EF loss forward + backward (rollout, decoder, loss) for the paper's two settings.

DrQv2-EF: h of 2048 features, 84x84 frames; TD-MPC2-EF: h of 512 features, 64x64 frames; agent_dim 32, H = 10.
Compares ``EgoForesight.loss`` (roll out max(k) steps, decode one frame per sample) with the naive way (decode
all H predicted frames, then pick frame k), and times an open-loop prediction of 2H frames (analysis).

    python benchmarks/ef_speed.py --batch-sizes 32 --repeats 3
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import torch as th

from sb3_ef.ef import EgoForesight

SETTINGS = {"DrQv2-EF 84x84": (2048, 84), "TD-MPC2-EF 64x64": (512, 64)}
ACTION_DIM, HORIZON = 6, 10


def seconds_per_call(function: Callable[[], object], repeats: int) -> str:
    """Median wall and process CPU seconds of ``function`` over ``repeats`` calls, after one warm-up call.

    The CPU time (all threads of this process) is less disturbed than the wall time on a shared machine.
    """
    function()
    wall, cpu = [], []
    for _ in range(repeats):
        start_wall, start_cpu = time.perf_counter(), time.process_time()
        function()
        wall.append(time.perf_counter() - start_wall)
        cpu.append(time.process_time() - start_cpu)
    return f"{sorted(wall)[repeats // 2]:.3f} ({sorted(cpu)[repeats // 2]:.3f})"


def loss_step(ef: EgoForesight, batch: int, naive: bool = False) -> Callable[[], None]:
    """A closure drawing k and running one EF loss forward + backward on fixed random features and frames."""
    size = ef.frame_shape[1]
    h = th.randn(batch, ef.feature_dim, requires_grad=True)
    actions = th.rand(batch, HORIZON, ACTION_DIM) * 2 - 1
    target = th.randint(0, 256, (batch, 3, size, size), dtype=th.uint8)
    mask = th.ones(batch, HORIZON, dtype=th.bool)

    def run() -> None:
        ef.zero_grad(set_to_none=True)
        steps = ef.draw_steps(mask)
        if naive:
            predicted = ef.predict(h, actions)[th.arange(batch), steps - 1]
            (predicted - target / 255).pow(2).flatten(1).sum(1).mean().backward()
        else:
            ef.loss(h, actions, steps, target).backward()

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[32])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=th.get_num_threads())
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    th.manual_seed(0)
    print(f"torch {th.__version__}, {args.threads} threads, median of {args.repeats} calls: wall s (CPU s)")
    print("| setting | batch | loss fwd+bwd, EgoForesight.loss | naive: decode all H | predict 2H frames, no grad |")
    print("|---|---|---|---|---|")
    for name, (feature_dim, size) in SETTINGS.items():
        ef = EgoForesight(feature_dim, ACTION_DIM, (3, size, size), horizon=HORIZON)
        for batch in args.batch_sizes:
            ours = seconds_per_call(loss_step(ef, batch), args.repeats)
            naive = seconds_per_call(loss_step(ef, batch, naive=True), args.repeats)
            h, actions = th.randn(batch, feature_dim), th.rand(batch, 2 * HORIZON, ACTION_DIM) * 2 - 1
            with th.no_grad():
                predict = seconds_per_call(lambda ef=ef, h=h, actions=actions: ef.predict(h, actions), args.repeats)
            print(f"| {name} | {batch} | {ours} | {naive} | {predict} |")


if __name__ == "__main__":
    main()
