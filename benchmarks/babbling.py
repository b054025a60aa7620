"""When does adaptive motor babbling end, and what does EF predict there compared with a fixed babbling stage?

For each task and seed, DrQv2-EF babbles for a fixed ``--fixed-steps`` steps (standing in for the default stage at
reduced settings) while EF's agent-pixel error ratio (EF's error over copying the last frame, on held-out babbling
episodes of a second env, :func:`sb3_ef.ef.babbling.foresight_error_ratio`) is measured every ``--eval-freq`` steps.
The adaptive stage's end is the step at which ``MotorBabblingCallback("adaptive", ...)`` with the same settings
ends: the library's :class:`~sb3_ef.ef.babbling.Plateau` rule applied to the same scores, from ``--min-steps`` on.
Up to that step the adaptive run is the fixed run (same seed, same babbling draws; scoring draws nothing from the
training generators), so one run gives both. Reported per run: the adaptive end step, the ratio there and at the
fixed end, and the wall time of the babbling steps the adaptive stage saves; also where the rule would end on the
same ratio over all pixels (``frame_score_end``).

    MUJOCO_GL=egl OMP_NUM_THREADS=1 nice -n 19 python benchmarks/babbling.py --out babbling.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_ef import DrQv2EF
from sb3_ef.ef.babbling import BabblingState, Plateau, foresight_error_ratio, record_held_out_windows
from sb3_ef.envs import make_env


class Scores(BaseCallback):
    """EF's held-out error ratios (agent pixels, all pixels) every ``eval_freq`` steps from ``learning_starts`` on,
    with the wall time."""

    def __init__(self, held_out, eval_freq: int):
        super().__init__()
        self.held_out, self.eval_freq = held_out, eval_freq
        self.scores: list[tuple[int, float, float]] = []  # step, agent ratio, seconds since the start of training
        self.frame_scores: list[tuple[int, float, float]] = []  # step, all-pixel ratio, seconds
        self.start = 0.0

    def _on_training_start(self) -> None:
        self.start = time.perf_counter()

    def _on_rollout_start(self) -> None:
        step = self.num_timesteps
        if step < self.model.learning_starts or step % self.eval_freq or step in {s for s, *_ in self.scores}:
            return
        seconds = time.perf_counter() - self.start
        self.scores.append((step, foresight_error_ratio(self.model, self.held_out), seconds))
        self.frame_scores.append((step, foresight_error_ratio(self.model, self.held_out, agent_pixels=False), seconds))

    def _on_step(self) -> bool:
        return True


def adaptive_end(scores: list[tuple[int, float, float]], args: argparse.Namespace) -> tuple[int, str]:
    """The step at which adaptive babbling with these scores ends, and why: the callback's rule (it ends at the
    first step at or after min_steps at which the scores, as of the last evaluation, have plateaued)."""
    plateau = Plateau(args.patience, args.min_delta)
    for index, (step, score, _) in enumerate(scores):
        plateau.update(score)
        following = scores[index + 1][0] if index + 1 < len(scores) else args.fixed_steps
        first = max(step, args.min_steps)
        if plateau.plateaued and first < min(following, args.fixed_steps):
            return first, "plateau"
    return args.fixed_steps, "max_steps"


def run(task: str, seed: int, args: argparse.Namespace) -> dict:
    env_kwargs = {"size": args.size, "fast_render": True}
    env, eval_env = make_env(task, seed=seed, **env_kwargs), make_env(task, seed=10_000 + seed, **env_kwargs)
    model = DrQv2EF(
        "CnnPolicy", env, buffer_size=args.fixed_steps + 100, batch_size=args.batch_size,
        learning_starts=args.learning_starts, babbling_steps=args.fixed_steps, seed=seed,
        policy_kwargs={"net_arch": [256, 256]},
    )  # fmt: skip
    # The held-out episodes the callback would record (its generator: spawned from the model's seed).
    held_out = record_held_out_windows(
        eval_env, model.ef.horizon, args.holdout_steps, args.holdout_windows,
        np.random.default_rng(BabblingState.seeded(seed).holdout_seed), "sign",
    )  # fmt: skip
    scores = Scores(held_out, args.eval_freq)
    model.learn(args.fixed_steps + 1, callback=scores)  # the rollout at fixed_steps scores the last babbling update
    end, reason = adaptive_end(scores.scores, args)
    frame_end, frame_reason = adaptive_end(scores.frame_scores, args)
    by_step = {step: (score, seconds) for step, score, seconds in scores.scores}
    at_end = by_step[max(step for step in by_step if step <= end)]  # min_steps is a multiple of eval_freq
    at_fixed = by_step[args.fixed_steps]
    return {
        "task": task, "seed": seed, "adaptive_end": end, "reason": reason,
        "ratio_at_adaptive_end": at_end[0], "ratio_at_fixed_end": at_fixed[0],
        "seconds_at_adaptive_end": at_end[1], "seconds_at_fixed_end": at_fixed[1],
        "seconds_saved": at_fixed[1] - at_end[1], "scores": scores.scores,
        "frame_score_end": frame_end, "frame_score_reason": frame_reason, "frame_scores": scores.frame_scores,
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["dmc/reacher-easy", "metaworld/hammer"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--learning-starts", type=int, default=100)
    parser.add_argument("--fixed-steps", type=int, default=500)
    parser.add_argument("--min-steps", type=int, default=200)
    parser.add_argument("--patience", type=int, default=3)
    parser.add_argument("--min-delta", type=float, default=0.01)
    parser.add_argument("--eval-freq", type=int, default=50)
    parser.add_argument("--holdout-steps", type=int, default=100)
    parser.add_argument("--holdout-windows", type=int, default=16)
    parser.add_argument("--out", default="babbling.jsonl")
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()}", flush=True)
    with open(args.out, "a") as file:
        for task in args.tasks:
            for seed in args.seeds:
                result = run(task, seed, args)
                file.write(json.dumps({**result, "settings": vars(args)}) + "\n")
                file.flush()
                print({key: value for key, value in result.items() if not key.endswith("scores")}, flush=True)
    print(f"# load at the end {os.getloadavg()}", flush=True)


if __name__ == "__main__":
    main()
