"""``python -m sb3_ef.zoo.enjoy``: rl-zoo3's ``enjoy`` for sb3-ef models, without a full-size replay buffer.

rl-zoo3's enjoy shrinks the replay buffer only for the off-policy algorithms it knows by name; loading one of ours
would otherwise rebuild the saved buffer size (e.g. 1M stacked pixel observations). During ``enjoy`` our keys in
``ALGOS`` are therefore served by :class:`InferenceLoader`, which loads with ``buffer_size`` set to
:data:`INFERENCE_BUFFER_SIZE`. Takes exactly rl-zoo3's enjoy arguments; ``sb3_ef`` is added to ``--gym-packages``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rl_zoo3 import utils
from stable_baselines3.common.base_class import BaseAlgorithm

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef.zoo.registration import algorithm_classes, register_algorithms
from sb3_ef.zoo.train import run_with_argv, with_gym_package

#: Replay-buffer capacity (frames) of a model loaded to act: more than any sampling window needs
#: (horizon + frame stack), a few MB at 84x84 instead of the training capacity.
INFERENCE_BUFFER_SIZE = 256


class InferenceLoader:
    """Stands in for an algorithm class in rl-zoo3's ``ALGOS``: ``load`` builds a tiny replay buffer."""

    def __init__(self, algo_class: type[BaseAlgorithm]):
        self.algo_class = algo_class

    def load(self, path: str, **kwargs: Any) -> BaseAlgorithm:
        """``algo_class.load(path, **kwargs)`` with ``buffer_size`` forced to :data:`INFERENCE_BUFFER_SIZE`."""
        kwargs["buffer_size"] = INFERENCE_BUFFER_SIZE
        return self.algo_class.load(path, **kwargs)


def main(argv: Sequence[str] | None = None) -> None:
    """Run a trained sb3-ef agent with rl-zoo3's enjoy; ``argv`` defaults to the command line."""
    from rl_zoo3.enjoy import enjoy

    register_algorithms()
    classes = algorithm_classes()
    for key, algo_class in classes.items():
        utils.ALGOS[key] = InferenceLoader(algo_class)  # type: ignore[assignment]
    try:
        run_with_argv(enjoy, with_gym_package(list(sys.argv[1:] if argv is None else argv)))
    finally:
        utils.ALGOS.update(classes)


if __name__ == "__main__":
    main()
