"""Wall time of the README's "CPU try": DrQv2-EF on cartpole-swingup with small frames and networks.

Run on purpose (not a test): ``MUJOCO_GL=egl python benchmarks/cpu_try.py``. Trains exactly the README's snippet
(same arguments, progress bar off) and prints the wall time of ``learn`` and the number of updates.
"""

from __future__ import annotations

import time

from sb3_ef import DrQv2EF, make_env

#: The README's CPU try, argument for argument.
STEPS = 1_000
KWARGS = {
    "batch_size": 32,
    "buffer_size": 20_000,
    "learning_starts": 250,
    "babbling_steps": 250,
    "policy_kwargs": {
        "features_dim": 128,
        "agent_dim": 16,
        "net_arch": [128, 128],
        "ef_kwargs": {"decoder_channels": 16},
    },
}


def main() -> None:
    env = make_env("dmc/cartpole-swingup", size=64, fast_render=True)
    model = DrQv2EF("CnnPolicy", env, **KWARGS)
    start = time.perf_counter()
    model.learn(STEPS)
    minutes = (time.perf_counter() - start) / 60
    print(f"{STEPS} steps, {model._n_updates} updates: {minutes:.1f} min")


if __name__ == "__main__":
    main()
