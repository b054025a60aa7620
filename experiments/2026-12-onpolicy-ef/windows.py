"""EF's windows on an on-policy host: cut from the current rollout only, or from a ring of the last rollouts?

PPO-EF babbling on Breakout (random actions; a babbling rollout's ``train()`` steps EF alone) with ``ef_rollouts``
1 and R, the same number of EF updates either way; EF's error is measured on held-out windows of other random
rollouts, for every k in 1..H.

    python experiments/2026-12-onpolicy-ef/windows.py --rollouts 12 --ring 4 --seeds 0 1
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_atari_env
from stable_baselines3.common.vec_env import VecFrameStack

from sb3_ef import PPOEF
from sb3_ef.common.buffers.rollout_windows import RolloutWindows

HORIZON = 10


def babbling_model(seed: int, envs: int, ef_rollouts: int) -> PPOEF:
    env = VecFrameStack(make_atari_env("BreakoutNoFrameskip-v4", n_envs=envs, seed=seed), 4)
    model = PPOEF(
        "CnnPolicy", env, n_steps=128, batch_size=128, n_epochs=4, learning_rate=2.5e-4, ef_horizon=HORIZON,
        ef_rollouts=ef_rollouts, babbling_steps=10**9, seed=seed,
    )  # fmt: skip
    model._setup_learn(10**9)
    return model


def collect(model: PPOEF) -> None:
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)


@th.no_grad()
def held_out_error(model: PPOEF, windows: RolloutWindows) -> list[float]:
    """EF's loss (squared error summed over the frame) of every held-out window, for each k = 1..H."""
    window = windows(np.arange(windows.size))
    features = model.encode(window.observations)
    model.ef.eval()
    errors = []
    for k in range(1, HORIZON + 1):
        steps = th.full((windows.size,), k)
        target, valid = window.future_frames[:, k - 1], window.future_mask[:, k - 1]
        errors.append(float(model.ef.loss(features, window.future_actions, steps, target, valid)))
    model.ef.train()
    return errors


def run(ef_rollouts: int, rollouts: int, seed: int, envs: int, held_out: RolloutWindows) -> dict:
    th.manual_seed(seed)
    model = babbling_model(seed, envs, ef_rollouts)
    timings, valid = [], []
    for _ in range(rollouts):
        collect(model)
        start = time.perf_counter()
        model.train()  # n_epochs x (rollout / batch_size) EF updates
        timings.append(time.perf_counter() - start)
        ring = model._ef_ring.windows(model._last_obs, model._last_episode_starts, 1, HORIZON)
        valid.append(float(ring(np.arange(ring.size)).future_mask.float().mean()))
    error = held_out_error(model, held_out)
    model.env.close()
    return {"ef_rollouts": ef_rollouts, "held_out_error_by_k": [round(e, 3) for e in error],
            "mean_error": round(float(np.mean(error)), 3), "valid_fraction": round(float(np.mean(valid)), 3),
            "seconds_per_rollout": round(float(np.median(timings)), 1)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rollouts", type=int, default=12)
    parser.add_argument("--ring", type=int, default=4)
    parser.add_argument("--envs", type=int, default=4)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = parser.parse_args()
    th.set_num_threads(1)
    import ale_py

    gym.register_envs(ale_py)
    for seed in args.seeds:
        other = babbling_model(seed + 1000, args.envs, 1)
        collect(other)
        held_out = other._rollout_windows()
        other.env.close()
        for ef_rollouts in (1, args.ring):
            print(json.dumps({"seed": seed, **run(ef_rollouts, args.rollouts, seed, args.envs, held_out)}), flush=True)


if __name__ == "__main__":
    main()
