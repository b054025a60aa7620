"""Can the study's DrQ-v2 and pixel DrQv2-EF runs be reused beside a rerun made with newer code? Train each a few
hundred steps with the grid's settings (distracting_grid.yml, the distracted task; learning starts earlier so that
there are updates), then print a fingerprint: a SHA-256 of every policy weight, the return of one deterministic
evaluation episode. Run it once with each version of the code on the path; equal
lines mean the code gives those runs the same numbers, bit for bit.

    git archive <commit> sb3_ef zoo_configs | tar -x -C /tmp/before     # the code the runs were made with
    cd /tmp && PYTHONPATH=/tmp/before MUJOCO_GL=egl python /work/main/experiments/2026-12-distracting-cpu/reuse_check.py
    # again with PYTHONPATH pointing at the newer code; the backgrounds folder must exist (make_backgrounds.py)
"""

from __future__ import annotations

import argparse
import hashlib
import os

import torch as th
import yaml

import sb3_ef

HERE = os.path.dirname(os.path.abspath(__file__))
CLASSES = {"drqv2": "DrQv2", "drqv2_ef": "DrQv2EF"}


def grid_settings() -> tuple[dict, dict]:
    """The distracted block's env_kwargs and the hyperparameters of each algorithm, from distracting_grid.yml."""
    with open(os.path.join(HERE, "distracting_grid.yml")) as file:
        grid = yaml.safe_load(file)
    block = grid["grids"][0]
    env_kwargs = {**block["env_kwargs"], "background_dir": os.path.join(HERE, "backgrounds")}
    return env_kwargs, {key: block["algorithms"][key]["hyperparams"] for key in CLASSES}


def fingerprint(algo: str, hyperparams: dict, env_kwargs: dict, steps: int, learning_starts: int, seed: int) -> str:
    """One line: the algorithm, the SHA-256 of its policy weights after ``steps``, one evaluation return."""
    arguments = {**hyperparams, "learning_starts": learning_starts}
    arguments["policy_kwargs"] = eval(arguments["policy_kwargs"], {"dict": dict})  # zoo syntax: "dict(...)"
    env = sb3_ef.make_env("dmc-distracting/cartpole-balance-v0", seed=seed, **env_kwargs)
    model = getattr(sb3_ef, CLASSES[algo])("CnnPolicy", env, seed=seed, device="cpu", **arguments)
    model.learn(steps)
    digest = hashlib.sha256()
    for name, tensor in sorted(model.policy.state_dict().items()):
        digest.update(name.encode() + tensor.detach().cpu().contiguous().numpy().tobytes())
    eval_env = sb3_ef.make_env("dmc-distracting/cartpole-balance-v0", seed=seed + 1000, **env_kwargs)
    obs, _ = eval_env.reset(seed=seed + 1000)
    total, done = 0.0, False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, _ = eval_env.step(action)
        total += float(reward)
        done = terminated or truncated
    return f"{algo}\tweights {digest.hexdigest()[:16]}\teval return {total:.6f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--learning-starts", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)
    env_kwargs, hyperparams = grid_settings()
    print(f"sb3_ef from {os.path.dirname(sb3_ef.__file__)}")
    for algo, values in hyperparams.items():
        print(fingerprint(algo, values, env_kwargs, args.steps, args.learning_starts, args.seed), flush=True)


if __name__ == "__main__":
    main()
