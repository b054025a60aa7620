"""Which of ``fast_render``'s settings changes what the agent sees, and what each one costs, on the paper's tasks.

Run on purpose (not a test): ``MUJOCO_GL=egl python benchmarks/render_settings.py --renders 5``. For every task of
``zoo_configs/`` (12 DMC, 16 Meta-World) it renders the first frame after ``reset(seed=0)`` at 84x84 with MuJoCo's
default settings and with each of ``fast_render``'s settings turned off alone (shadows, reflections, multisampling)
and all together, and prints a Markdown table: the mean absolute difference from the default frame in grey levels
(0-255, mean over pixels of the channel mean) and the wall time of one render.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import mujoco
import numpy as np

from sb3_ef.envs import make_env
from sb3_ef.envs.tasks import DMC_PAPER_TASKS, METAWORLD_PAPER_TASKS

#: Each setting: (quality changes on the model, scene flags turned off).
SETTINGS: dict[str, tuple[dict[str, int], tuple[int, ...]]] = {
    "default": ({}, ()),
    "no shadows": ({"shadowsize": 0}, (mujoco.mjtRndFlag.mjRND_SHADOW,)),
    "no reflections": ({}, (mujoco.mjtRndFlag.mjRND_REFLECTION,)),
    "no multisampling": ({"offsamples": 0}, ()),
    "fast_render (all)": (
        {"shadowsize": 0, "offsamples": 0},
        (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION),
    ),
}


def render(model: mujoco.MjModel, data: mujoco.MjData, camera: int, size: int, setting: str, renders: int):
    """The frame of ``data`` under ``setting`` and the median wall time (ms) of ``renders`` renders."""
    quality, flags = SETTINGS[setting]
    model = copy.deepcopy(model)
    for name, value in quality.items():
        setattr(model.vis.quality, name, value)
    renderer = mujoco.Renderer(model, size, size)
    try:
        for flag in flags:
            renderer.scene.flags[flag] = False
        renderer.update_scene(data, camera=camera)
        frame = renderer.render().astype(np.float64)  # the first render compiles shaders: not timed
        times = []
        for _ in range(renders):
            start = time.perf_counter()
            renderer.update_scene(data, camera=camera)
            renderer.render()
            times.append(1000 * (time.perf_counter() - start))
    finally:
        renderer.close()
    return frame, statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--renders", type=int, default=5, help="timed renders per task and setting")
    parser.add_argument("--size", type=int, default=84)
    args = parser.parse_args()
    names = [f"dmc/{task}" for task in DMC_PAPER_TASKS] + [f"metaworld/{task}" for task in METAWORLD_PAPER_TASKS]
    print("| task | " + " | ".join(f"{setting}: grey levels / ms" for setting in SETTINGS) + " |")
    print("|---" * (len(SETTINGS) + 1) + "|")
    for name in names:
        env = make_env(name, size=args.size, seed=0)
        try:
            env.reset(seed=0)
            model, data = env.unwrapped._physics()
            results = {setting: render(model, data, env.unwrapped.camera, args.size, setting, args.renders)
                       for setting in SETTINGS}  # fmt: skip
        finally:
            env.close()
        default = results["default"][0].mean(axis=-1)
        cells = [
            f"{np.abs(frame.mean(axis=-1) - default).mean():.1f} / {milliseconds:.0f}"
            for frame, milliseconds in results.values()
        ]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
