"""``python -m sb3_ef.zoo.enjoy``: rl-zoo3's ``enjoy`` for sb3-ef models, without a full-size replay buffer."""

from __future__ import annotations

import glob
import os
import sys
from collections.abc import Sequence
from typing import Any

from rl_zoo3 import utils
from stable_baselines3.common.base_class import BaseAlgorithm

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef.zoo.options import check_enjoy_argv
from sb3_ef.zoo.registration import algorithm_classes, register_algorithms
from sb3_ef.zoo.train import own_loop_main, run_with_argv, with_gym_package

#: Replay-buffer capacity (frames) of a model loaded to act: more than any sampling window, a few MB at 84x84.
INFERENCE_BUFFER_SIZE = 256


class InferenceLoader:
    """Stands in for an algorithm class in rl-zoo3's ``ALGOS``: ``load`` builds a tiny replay buffer."""

    def __init__(self, algo_class: type[BaseAlgorithm]):
        self.algo_class = algo_class

    def load(self, path: str, **kwargs: Any) -> BaseAlgorithm:
        kwargs["buffer_size"] = INFERENCE_BUFFER_SIZE
        return self.algo_class.load(path, **kwargs)


def check_run_folder(folder: str, algo: str, env: str, exp_id: int) -> None:
    """Refuse an ``--exp-id`` (0: the latest) that names no run, naming the runs there are."""
    if exp_id < 0 or "rl-trained-agents" in folder:
        return
    env_name = utils.EnvironmentName(env)
    paths = glob.glob(os.path.join(folder, algo, f"{env_name}_*"))
    runs = [os.path.basename(path) for path in paths if os.path.isdir(path)]
    runs.sort(key=lambda name: int(name.rsplit("_", 1)[1]) if name.rsplit("_", 1)[1].isdigit() else -1)
    if (exp_id > 0 and f"{env_name}_{exp_id}" in runs) or (exp_id == 0 and runs):
        return
    wanted = f"run of {env_name}" if exp_id == 0 else f"run {env_name}_{exp_id}"
    found = (
        f"runs there: {', '.join(runs)}" if runs else "no run of this env there (train first, or pass -f LOG_FOLDER)"
    )
    raise ValueError(f"No {wanted} under {os.path.join(folder, algo)}: {found}")


def main(argv: Sequence[str] | None = None) -> None:
    """Run a trained sb3-ef agent with rl-zoo3's enjoy; ``argv`` defaults to the command line."""
    from rl_zoo3.enjoy import enjoy

    argv = list(sys.argv[1:] if argv is None else argv)
    if "-h" not in argv and "--help" not in argv:
        args = check_enjoy_argv(argv)
        check_run_folder(
            args.folder or "rl-trained-agents", args.algo or "ppo", args.env or "CartPole-v1", args.exp_id or 0
        )
        own_loop = own_loop_main(argv, "enjoy")
        if own_loop is not None:
            own_loop(argv)
            return
    register_algorithms()
    classes = algorithm_classes()
    for key, algo_class in classes.items():
        utils.ALGOS[key] = InferenceLoader(algo_class)  # type: ignore[assignment]
    try:
        run_with_argv(enjoy, with_gym_package(argv), "sb3-ef enjoy")
    finally:
        utils.ALGOS.update(classes)


if __name__ == "__main__":
    main()
