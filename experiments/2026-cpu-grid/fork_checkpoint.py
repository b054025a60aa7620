"""Train a benchmark-grid run's settings with changes (variants) next to the unchanged control, over seeds.

An intervention test for a stalled run. With a checkpoint: from the same weights, replay buffer and step, does the
run leave the stall sooner with ``beta=0`` (EF's gradient off) than with its own settings? Each continuation (a
*fork*) loads the checkpoint afresh, sets the variant's values as attributes, reseeds everything random
(``set_random_seed`` and the replay buffer's sampler) with its fork seed, and trains ``--steps`` more agent steps.
Without a checkpoint, each fork is a new model built from the run's settings, its seed (model and env) the fork
seed, so the control of seed k repeats the grid's seed-k run, and the variant's values are set on it as
attributes before it trains (so ``beta=0`` is allowed, which the constructor refuses). Forks are evaluated as the
grid evaluates (deterministic actions, evaluation env seed + 10000) and, with ``--diagnose``, measured by
``ef_gradients.py`` (state dependence of actor and critic, gradient norms). A fork is evaluated once, after the
update of its last step, where the grid's ``EvalCallback`` evaluates just before that update: a stuck policy
scores the same, a moving one a little differently (DrQ-v2 seed 2 on cartpole-balance: 178 at 2k steps as a
fork, 157 in the grid run).

    python fork_checkpoint.py cpu_grid.yml drqv2_ef/dmc-cartpole-balance-v0_s1 \\
        --checkpoint CHECKPOINT.zip --variant beta=0 --steps 2000 --seeds 0 1 [--eval-episodes 5]
    python fork_checkpoint.py cpu_grid.yml drqv2_ef/dmc-cartpole-balance-v0_s0 \\
        --variant beta=0 --variant babbling_steps=0 --steps 2000 --seeds 0 1 2 --diagnose

Prints one JSON line per fork: the variant's settings ({} for the control), the fork seed, the steps, the
evaluation return and the diagnostics.
"""

from __future__ import annotations

import argparse
import ast
import json
from typing import Any

import torch as th
from ef_gradients import diagnose_model  # this folder is on sys.path when a script of it runs
from stable_baselines3.common.evaluation import evaluate_policy

from sb3_ef.common.checkpoints import checkpoint_for, load_checkpoint
from sb3_ef.grid.grid import RunSpec, constructor_kwargs, load_grid
from sb3_ef.grid.run import build_env, build_eval_env
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
    spec: RunSpec,
    checkpoint: str | None,
    settings: dict[str, Any],
    seed: int,
    steps: int,
    eval_episodes: int,
    diagnose: bool = False,
) -> dict[str, Any]:
    """One fork (module docstring): train ``steps`` agent steps, evaluate, and diagnose if asked."""
    algo_class = algorithm_classes()[spec.algo]
    if checkpoint is None:
        env_seed = seed
        hyperparams = constructor_kwargs(dict(spec.hyperparams))
        model = algo_class(env=build_env(spec, seed=seed), seed=seed, device="cpu", **hyperparams)
    else:
        env_seed = spec.seed
        model = load_checkpoint(algo_class, checkpoint_for(checkpoint), build_env(spec, seed=spec.seed), device="cpu")
        model.set_random_seed(seed)
        model.replay_buffer.seed(seed)
    for name, value in settings.items():
        if not hasattr(model, name):
            raise SystemExit(f"{algo_class.__name__} has no attribute {name!r} to set")
        setattr(model, name, value)
    start = model.num_timesteps
    model.learn(steps, reset_num_timesteps=checkpoint is None)
    eval_env = build_eval_env(spec, env_seed)
    returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes, return_episode_rewards=True)
    eval_env.close()
    result = {
        "settings": settings,
        "fork_seed": seed,
        "from_step": start,
        "step": model.num_timesteps,
        "return": round(float(sum(returns) / len(returns)), 1),
    }
    if diagnose:
        result.update({key: round(value, 4) for key, value in diagnose_model(model, 64, seed=0).items()})
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", help="the grid file the run belongs to")
    parser.add_argument("run_id", help="e.g. drqv2_ef/dmc-cartpole-balance-v0_s1")
    parser.add_argument("--checkpoint", help="a checkpoint's model .zip (replay buffer, random states beside it)")
    parser.add_argument(
        "--variant",
        type=parse_setting,
        nargs="+",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="one variant's changed settings (repeat the flag for more variants)",
    )
    parser.add_argument("--steps", type=int, default=2000, help="agent steps of each fork")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="one fork per seed and variant")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument(
        "--skip-control",
        action="store_true",
        help="only the variants (the control is the grid run itself, evaluated one update earlier)",
    )
    parser.add_argument("--diagnose", action="store_true", help="add ef_gradients.py's figures (DrQ-v2 hosts)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)
    spec = find_run(args.grid, args.run_id)
    variants = ([] if args.skip_control else [{}]) + [dict(variant) for variant in args.variant]
    if not variants:
        parser.error("--skip-control needs at least one --variant")
    for seed in args.seeds:
        for settings in variants:
            result = fork(spec, args.checkpoint, settings, seed, args.steps, args.eval_episodes, args.diagnose)
            print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
