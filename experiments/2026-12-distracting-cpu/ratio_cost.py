"""What ``train/aux_grad_ratio`` costs a DrQv2EF update: the time of one update computing it and of one not.

A DrQv2EF at the study's sizes (64x64 frames, batch 64, features 512, agent features 16) fills its buffer, then
updates alternate between computing the ratio and not (``aux_grad_ratio_due`` replaced for the measurement), so that
the machine's load falls on both alike. Printed: the median seconds per update of each, the extra time of an update
that computes the ratio, and that extra time spread over the ``AUX_GRAD_RATIO_EVERY`` updates it stands for.

    MUJOCO_GL=egl python experiments/2026-12-distracting-cpu/ratio_cost.py
"""

from __future__ import annotations

import argparse
import statistics
import time
from unittest import mock

import torch as th

from sb3_ef import DrQv2EF, make_env
from sb3_ef.auxiliary.host import AUX_GRAD_RATIO_EVERY


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--targets", nargs="+", default=["pixel", "latent"])
    parser.add_argument("--updates", type=int, default=30, help="updates of each kind")
    parser.add_argument("--fill", type=int, default=300)
    args = parser.parse_args()
    th.set_num_threads(1)
    print("target\twith ratio (s)\twithout (s)\textra per computed ratio\textra per update, amortised")
    for target in args.targets:
        env = make_env("dmc/cartpole-balance-v0", seed=0, size=64, fast_render=True)
        model = DrQv2EF(
            "CnnPolicy", env, buffer_size=args.fill + 10, batch_size=64, learning_starts=args.fill, seed=0,
            policy_kwargs={"features_dim": 512, "agent_dim": 16, "ef_kwargs": {"target": target}},
        )  # fmt: skip
        model.learn(args.fill + 1)
        model.policy.set_training_mode(True)
        times: dict[bool, list[float]] = {True: [], False: []}
        for update in range(2 * args.updates):
            due = update % 2 == 0
            batch = model.replay_buffer.sample(64)
            with mock.patch("sb3_ef.drqv2.drqv2.aux_grad_ratio_due", lambda n_updates, due=due: due):
                start = time.perf_counter()
                logs = model._update(batch)
                times[due].append(time.perf_counter() - start)
            assert ("aux_grad_ratio" in logs) == due
        with_ratio, without = statistics.median(times[True]), statistics.median(times[False])
        extra = with_ratio - without
        print(
            f"{target}\t{with_ratio:.3f}\t{without:.3f}\t{extra:.3f} s ({100 * extra / without:.0f}%)\t"
            f"{extra / AUX_GRAD_RATIO_EVERY * 1000:.1f} ms ({100 * extra / without / AUX_GRAD_RATIO_EVERY:.2f}%)",
            flush=True,
        )
        env.close()


if __name__ == "__main__":
    main()
