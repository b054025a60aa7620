"""EF's windows on an on-policy host: cut from the current rollout only, or from a ring of the last rollouts?

PPO-EF babbling on Breakout (random actions, EF trained alone: PPOEF's babbling rollouts) with the same number of EF
updates either way; EF's error is measured on held-out windows of other random rollouts, for every k in 1..H.

    python experiments/2026-12-onpolicy-ef/windows.py --rollouts 12 --ring 4
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
from sb3_ef.common.buffers.rollout_windows import RolloutWindows, encode_actions


def rollout_arrays(model: PPOEF) -> dict[str, np.ndarray]:
    """Collect one babbling rollout; its observations, encoded actions, episode starts and the observation after."""
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    buffer = model.rollout_buffer
    return {
        "observations": buffer.observations.astype(np.uint8),
        "actions": encode_actions(th.as_tensor(buffer.actions), model.action_space).numpy(),
        "episode_starts": buffer.episode_starts.copy(),
        "last_observations": np.asarray(model._last_obs).copy(),
        "last_episode_starts": np.asarray(model._last_episode_starts).copy(),
    }


def ring_windows(rollouts: list[dict[str, np.ndarray]], model: PPOEF) -> RolloutWindows:
    """The windows of consecutive rollouts concatenated along the steps (a ring: frames kept once per rollout)."""
    return RolloutWindows(
        np.concatenate([r["observations"] for r in rollouts]),
        th.as_tensor(np.concatenate([r["actions"] for r in rollouts])),
        np.concatenate([r["episode_starts"] for r in rollouts]),
        rollouts[-1]["last_observations"],
        rollouts[-1]["last_episode_starts"],
        model.frame_shape[0],
        model.ef_horizon,
    )


@th.no_grad()
def held_out_error(model: PPOEF, windows: RolloutWindows, count: int) -> list[float]:
    """EF's loss (squared error summed over the frame) of the held-out windows, for each k = 1..H."""
    indices = np.arange(count)
    window = windows(indices)
    features = model.encode(window.observations)
    errors = []
    model.ef.eval()
    for k in range(1, model.ef_horizon + 1):
        steps = th.full((count,), k)
        valid = window.future_mask[:, k - 1]
        target = window.future_frames[:, k - 1]
        errors.append(float(model.ef.loss(features, window.future_actions, steps, target, valid)))
    model.ef.train()
    return errors


def run(ring: int, rollouts: int, seed: int, envs: int, held_out: dict) -> dict:
    th.manual_seed(seed)
    env = VecFrameStack(make_atari_env("BreakoutNoFrameskip-v4", n_envs=envs, seed=seed), 4)
    model = PPOEF(
        "CnnPolicy", env, n_steps=128, batch_size=128, n_epochs=4, learning_rate=2.5e-4, ef_horizon=10,
        babbling_steps=10**9, seed=seed,
    )  # fmt: skip
    model._setup_learn(10**9)
    gathered: list[dict[str, np.ndarray]] = []
    valid, timings = [], []
    for _ in range(rollouts):
        gathered = [*gathered[1 - ring :], rollout_arrays(model)] if ring > 1 else [rollout_arrays(model)]
        windows = ring_windows(gathered, model)
        size = len(gathered) * model.n_steps * envs
        valid.append(float(windows(np.arange(size)).future_mask.float().mean()))
        start = time.perf_counter()
        if ring == 1:
            model.train()  # the shipped update: n_epochs passes over the rollout in minibatches
        else:
            for _ in range(model.n_epochs * (model.n_steps * envs // model.batch_size)):
                _, ef_loss, _ = model._ef_loss(windows(np.random.randint(size, size=model.batch_size)))
                model._step(None, ef_loss)
        timings.append(time.perf_counter() - start)
    windows = RolloutWindows(**held_out, frame_channels=1, horizon=10)
    error = held_out_error(model, windows, 512)
    env.close()
    return {"ring": ring, "held_out_error_by_k": error, "mean_error": float(np.mean(error)),
            "valid_fraction": float(np.mean(valid)), "seconds_per_rollout": float(np.median(timings))}  # fmt: skip


def held_out_rollout(seed: int, envs: int) -> dict:
    env = VecFrameStack(make_atari_env("BreakoutNoFrameskip-v4", n_envs=envs, seed=seed + 1000), 4)
    model = PPOEF("CnnPolicy", env, n_steps=128, batch_size=128, ef_horizon=10, babbling_steps=10**9, seed=seed + 1000)
    model._setup_learn(10**9)
    arrays = rollout_arrays(model)
    env.close()
    arrays["actions"] = th.as_tensor(arrays["actions"])
    return arrays


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
        held_out = held_out_rollout(seed, args.envs)
        for ring in (1, args.ring):
            print(json.dumps({"seed": seed, **run(ring, args.rollouts, seed, args.envs, held_out)}), flush=True)


if __name__ == "__main__":
    main()
