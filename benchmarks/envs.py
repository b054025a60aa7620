"""Agent steps per second of the pixel environments, with and without ``fast_render``, and with several envs at once.

Run on purpose (not a test): ``MUJOCO_GL=egl python benchmarks/envs.py --steps 100``. Prints a Markdown table:
agent steps/s (one render per agent step, action repeat 2), the process CPU time per agent step (less sensitive to
other load on a shared machine than wall time), and the wall time of one ``agent_mask()`` call.

``--vec-envs 1 2`` instead times SB3 vectorised envs (``fast_render`` unless ``--default-render``): one env in
the process (``DummyVecEnv``) and N envs in subprocesses (``SubprocVecEnv``, each rendering with its own EGL
context), in agent steps/s summed over the envs, the settings interleaved ``--rounds`` times (medians).
"""

from __future__ import annotations

import argparse
import statistics
import time
from functools import partial

import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from sb3_ef.envs import make_env

DEFAULT_ENVS = (
    "dmc/cartpole-swingup",
    "dmc/reacher-easy",
    "dmc/walker-walk",
    "metaworld/door-open",
    "metaworld/hammer",
)


def measure(
    name: str, fast_render: bool, steps: int, size: int, action_repeat: int, masks: int
) -> tuple[float, float, float]:
    """Return (agent steps/s, CPU ms per agent step) over ``steps`` random-action steps, and wall ms per mask."""
    env = make_env(name, size=size, action_repeat=action_repeat, fast_render=fast_render, seed=0)
    try:
        env.action_space.seed(0)
        env.reset()
        env.step(env.action_space.sample())  # first render compiles shaders: keep it out of the timing
        start, cpu_start = time.perf_counter(), time.process_time()
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        steps_per_second = steps / (time.perf_counter() - start)
        cpu_ms = 1000 * (time.process_time() - cpu_start) / steps
        start = time.perf_counter()
        for _ in range(masks):
            env.agent_mask()
        mask_ms = 1000 * (time.perf_counter() - start) / masks
    finally:
        env.close()
    return steps_per_second, cpu_ms, mask_ms


def vec_steps_per_second(env: VecEnv, steps: int) -> float:
    """Agent steps per second summed over the envs, over ``steps`` random-action steps of all of them."""
    rng = np.random.default_rng(0)
    low, high = env.action_space.low, env.action_space.high
    env.reset()
    env.step(rng.uniform(low, high, (env.num_envs, *low.shape)))  # first renders compile shaders
    start = time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(low, high, (env.num_envs, *low.shape)))  # VecEnvs reset finished envs themselves
    return env.num_envs * steps / (time.perf_counter() - start)


def compare_vec_envs(
    name: str, counts: list[int], steps: int, size: int, action_repeat: int, rounds: int, fast_render: bool
) -> None:
    makers = [
        partial(make_env, name, size=size, action_repeat=action_repeat, fast_render=fast_render, seed=seed)
        for seed in range(max(counts))
    ]
    settings = {("in process", 1): lambda: DummyVecEnv(makers[:1])}
    settings.update(
        {("subprocesses", n): partial(SubprocVecEnv, makers[:n], start_method="forkserver") for n in counts}
    )
    envs = {key: make() for key, make in settings.items()}
    rates: dict[tuple[str, int], list[float]] = {key: [] for key in envs}
    try:
        for _ in range(rounds):
            for key, env in envs.items():
                rates[key].append(vec_steps_per_second(env, steps))
    finally:
        for env in envs.values():
            env.close()
    single = statistics.median(rates[("in process", 1)])
    render = "fast_render" if fast_render else "default render"
    print("| env | render | envs | where | agent steps/s (all envs) | x one env in process |")
    print("|---|---|---|---|---|---|")
    for (where, n), values in rates.items():
        rate = statistics.median(values)
        print(f"| {name} | {render} | {n} | {where} | {rate:.1f} | {rate / single:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS))
    parser.add_argument("--steps", type=int, default=100, help="timed agent steps per env and setting")
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--action-repeat", type=int, default=2)
    parser.add_argument("--masks", type=int, default=20, help="timed agent_mask() calls")
    parser.add_argument("--vec-envs", type=int, nargs="+", help="time vectorised envs of these sizes instead")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of --vec-envs")
    parser.add_argument("--default-render", action="store_true", help="--vec-envs without fast_render")
    args = parser.parse_args()
    if args.vec_envs:
        for name in args.envs:
            compare_vec_envs(
                name, args.vec_envs, args.steps, args.size, args.action_repeat, args.rounds, not args.default_render
            )
        return
    print("| env | steps/s default | steps/s fast_render | CPU ms/step default | CPU ms/step fast_render | mask ms |")
    print("|---|---|---|---|---|---|")
    for name in args.envs:
        default, default_cpu, mask_ms = measure(name, False, args.steps, args.size, args.action_repeat, args.masks)
        fast, fast_cpu, _ = measure(name, True, args.steps, args.size, args.action_repeat, args.masks)
        row = f"| {name} | {default:.1f} | {fast:.1f} | {default_cpu:.1f} | {fast_cpu:.1f} | {mask_ms:.1f} |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
