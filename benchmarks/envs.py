"""Agent steps per second of the pixel environments, with and without ``fast_render``.

Run on purpose (not a test): ``MUJOCO_GL=egl python benchmarks/envs.py --steps 100``. Prints a Markdown table:
agent steps/s (one render per agent step, action repeat 2), the process CPU time per agent step (less sensitive to
other load on a shared machine than wall time), and the wall time of one ``agent_mask()`` call.
"""

from __future__ import annotations

import argparse
import time

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS))
    parser.add_argument("--steps", type=int, default=100, help="timed agent steps per env and setting")
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--action-repeat", type=int, default=2)
    parser.add_argument("--masks", type=int, default=20, help="timed agent_mask() calls")
    args = parser.parse_args()
    print("| env | steps/s default | steps/s fast_render | CPU ms/step default | CPU ms/step fast_render | mask ms |")
    print("|---|---|---|---|---|---|")
    for name in args.envs:
        default, default_cpu, mask_ms = measure(name, False, args.steps, args.size, args.action_repeat, args.masks)
        fast, fast_cpu, _ = measure(name, True, args.steps, args.size, args.action_repeat, args.masks)
        row = f"| {name} | {default:.1f} | {fast:.1f} | {default_cpu:.1f} | {fast_cpu:.1f} | {mask_ms:.1f} |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
