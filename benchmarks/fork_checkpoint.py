"""Continue one checkpoint of a benchmark-grid run under changed settings, a few times each, and evaluate.

An intervention test for a stalled run: from the same weights, replay buffer and step, does the run leave the
stall sooner with ``beta=0`` (EF's gradient off) than with its own settings? Each continuation (a *fork*) loads the
checkpoint afresh, reseeds everything random (``set_random_seed`` and the replay buffer's sampler) with its fork seed,
trains ``--steps`` more agent steps and is evaluated like the grid evaluates (deterministic actions, the run's
evaluation env seed). The run's own settings are always forked too, as the control.

    python benchmarks/fork_checkpoint.py benchmarks/cpu_grid.yml drqv2_ef/dmc-cartpole-balance-v0_s1 \\
        CHECKPOINT.zip --set beta=0 --steps 2000 --seeds 0 1 2 [--eval-episodes 5]

Prints one JSON line per fork: the changed settings, the fork seed, the step reached and the evaluation return.
"""

from __future__ import annotations

import argparse
import ast
import json
from typing import Any

import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.benchmark.grid import RunSpec, load_grid
from sb3_ef.benchmark.run import EVAL_SEED_OFFSET, build_env
from sb3_ef.common.checkpoints import checkpoint_for, load_checkpoint
from sb3_ef.zoo.registration import algorithm_classes


def parse_setting(text: str) -> tuple[str, Any]:
    """``name=value`` with a Python literal value (``beta=0``, ``beta=1e-3``)."""
    name, separator, value = text.partition("=")
    if not separator or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"Expected NAME=VALUE (e.g. beta=0), got {text!r}")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError) as error:
        raise argparse.ArgumentTypeError(f"{text!r}: the value must be a Python literal") from error


def find_run(grid: str, run_id: str) -> RunSpec:
    """The run ``run_id`` of the grid file ``grid``."""
    runs = {spec.run_id: spec for spec in load_grid(grid)}
    if run_id not in runs:
        raise SystemExit(f"{grid} has no run {run_id!r}; its runs: {', '.join(sorted(runs))}")
    return runs[run_id]


def fork(
    spec: RunSpec, model_path: str, settings: dict[str, Any], seed: int, steps: int, eval_episodes: int
) -> dict[str, Any]:
    """Load the checkpoint, apply ``settings`` as attributes, reseed with ``seed``, train ``steps`` and evaluate."""
    algo_class = algorithm_classes()[spec.algo]
    model = load_checkpoint(algo_class, checkpoint_for(model_path), build_env(spec, seed=spec.seed), device="cpu")
    for name, value in settings.items():
        if not hasattr(model, name):
            raise SystemExit(f"{algo_class.__name__} has no attribute {name!r} to set")
        setattr(model, name, value)
    model.set_random_seed(seed)
    model.replay_buffer.seed(seed)
    start = model.num_timesteps
    model.learn(steps, reset_num_timesteps=False)
    eval_env = DummyVecEnv([lambda: Monitor(build_env(spec, seed=spec.seed + EVAL_SEED_OFFSET))])
    eval_env.seed(spec.seed + EVAL_SEED_OFFSET)
    returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes, return_episode_rewards=True)
    eval_env.close()
    return {
        "settings": settings,
        "fork_seed": seed,
        "from_step": start,
        "step": model.num_timesteps,
        "return": round(float(sum(returns) / len(returns)), 1),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", help="the grid file the run belongs to")
    parser.add_argument("run_id", help="e.g. drqv2_ef/dmc-cartpole-balance-v0_s1")
    parser.add_argument("checkpoint", help="the checkpoint's model .zip (replay buffer and random states beside it)")
    parser.add_argument("--set", type=parse_setting, action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--steps", type=int, default=2000, help="agent steps of each fork")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="one fork per seed and variant")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    spec = find_run(args.grid, args.run_id)
    variants = [{}] + ([dict(args.set)] if args.set else [])
    for seed in args.seeds:
        for settings in variants:
            print(json.dumps(fork(spec, args.checkpoint, settings, seed, args.steps, args.eval_episodes)), flush=True)


if __name__ == "__main__":
    main()
