"""Register sb3-ef's algorithms with rl-zoo3 in place (``ALGOS``, samplers, config names), without forking it."""

from __future__ import annotations

import importlib
from functools import partial
from typing import Any

from rl_zoo3 import exp_manager, hyperparams_opt, utils

from sb3_ef import registry
from sb3_ef.zoo.config import ZOO_ALGORITHMS
from sb3_ef.zoo.hyperparams_opt import CONVERTERS, SAMPLERS


def algorithm_classes() -> dict[str, type]:
    """rl-zoo3 key -> algorithm class, for the registry's algorithms that rl-zoo3 trains (imported now)."""
    return {key: registry.entry(key).algorithm_class for key in ZOO_ALGORITHMS}


def config_namespace() -> dict[str, Any]:
    """Names a zoo config string may use: those the buffers and the library's algorithm packages export
    (``SequenceReplayBuffer``; ``DrQv2Encoder`` for frames under 36x36)."""
    packages = ["sb3_ef.common.buffers", *(item.module for item in registry.ALGORITHMS.values() if not item.workbench)]
    modules = [importlib.import_module(package) for package in dict.fromkeys(packages)]
    return {name: getattr(module, name) for module in modules for name in module.__all__}


def register_algorithms(base_policy_kwargs: dict[str, Any] | None = None) -> None:
    """Add the algorithms of :func:`algorithm_classes` to rl-zoo3, with their Optuna samplers and converters.

    :param base_policy_kwargs: the entry's ``policy_kwargs``, which the samplers merge ``agent_dim`` into.
    """
    utils.ALGOS.update(algorithm_classes())
    for key, sampler in SAMPLERS.items():
        hyperparams_opt.HYPERPARAMS_SAMPLER[key] = partial(sampler, base_policy_kwargs=base_policy_kwargs)
        hyperparams_opt.HYPERPARAMS_CONVERTER[key] = partial(CONVERTERS[key], base_policy_kwargs=base_policy_kwargs)
    for module in (exp_manager, utils):
        vars(module).update(config_namespace())
