"""PPO-EF's cost against SB3's PPO on Atari with rl-zoo3's settings: one process, the two interleaved round by round.

    python benchmarks/on_policy.py --game Pong --rounds 5

Each round collects a rollout for each model (timed apart) and runs one epoch of its minibatch updates, the models
in turn (the order reversed every round); the table gives medians per rollout and per update, and a whole PPO
iteration (rollout + ``--epochs`` epochs) for each. PPO-EF runs with its defaults and with a ring of rollouts.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_atari_env
from stable_baselines3.common.vec_env import VecFrameStack

from sb3_ef import PPOEF


def build(algorithm: type, game: str, envs: int, n_steps: int, batch_size: int, **kwargs: int) -> PPO:
    env = VecFrameStack(make_atari_env(f"{game}NoFrameskip-v4", n_envs=envs, seed=0), 4)
    model = algorithm("CnnPolicy", env, n_steps=n_steps, batch_size=batch_size, n_epochs=1, seed=0, **kwargs)
    model._setup_learn(10**9)
    return model


def round_times(model: PPO) -> tuple[float, float]:
    """Seconds of one rollout and of one epoch of updates."""
    start = time.perf_counter()
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    collected = time.perf_counter()
    model.train()
    return collected - start, time.perf_counter() - collected


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--game", default="Pong")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--n-steps", type=int, default=128)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--epochs", type=int, default=4, help="epochs of a PPO iteration in the last column")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--ef-rollouts", type=int, default=4, help="the ring of the third model")
    args = parser.parse_args()
    import ale_py

    gym.register_envs(ale_py)
    th.set_num_threads(args.threads)
    sizes = (args.game, args.envs, args.n_steps, args.batch_size)
    models = {
        "PPO": build(PPO, *sizes),
        "PPO-EF": build(PPOEF, *sizes),
        f"PPO-EF, ef_rollouts={args.ef_rollouts}": build(PPOEF, *sizes, ef_rollouts=args.ef_rollouts),
    }
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in models}
    for index in range(args.rounds):
        for name in list(models)[:: 1 if index % 2 == 0 else -1]:
            times[name].append(round_times(models[name]))
    updates = args.envs * args.n_steps // args.batch_size
    print(f"{args.game}, {args.envs} envs x {args.n_steps} steps, batch {args.batch_size}, {args.threads} thread(s), "
          f"median of {args.rounds} rounds, load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"| model | rollout s | update ms | iteration s (rollout + {args.epochs} epochs) |")
    print("|---|---|---|---|")
    for name, rounds in times.items():
        rollout, epoch = np.median(np.array(rounds), axis=0)
        print(f"| {name} | {rollout:.2f} | {1000 * epoch / updates:.0f} | {rollout + args.epochs * epoch:.1f} |")


if __name__ == "__main__":
    main()
